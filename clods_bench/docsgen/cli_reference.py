"""The CLI reference page, written from `clods-bench`'s own argument parser (never copied by hand)."""

from __future__ import annotations

import argparse
from typing import Iterator

HEADER = """# CLI reference

Generated from the argument parser of `clods-bench` when the site is built, so it lists exactly the
commands and options of the installed version; `clods-bench COMMAND --help` prints the same text.
Every computing command also accepts the options of its section; `--set KEY=VALUE` may be repeated.
"""


USAGE_WIDTH = 100
"""Columns of the usage blocks (argparse would otherwise follow the terminal that builds the site)."""


def subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser, str]]:
    """(name, parser, one-line help) of each subcommand of `parser`, in the order they were added."""
    out = []
    for action in parser._actions:  # noqa: SLF001 - argparse keeps its actions here; there is no public accessor
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            helps = {a.dest: a.help or "" for a in action._choices_actions}  # noqa: SLF001
            out += [(name, sub, helps.get(name, "")) for name, sub in action.choices.items()]
    return out


def walk(parser: argparse.ArgumentParser, prefix: str) -> Iterator[tuple[str, argparse.ArgumentParser, str]]:
    """Every command below `parser` (depth first), as (full command, parser, one-line help)."""
    for name, sub, help_text in subcommands(parser):
        full = f"{prefix} {name}"
        yield full, sub, help_text
        yield from walk(sub, full)


def _cell(text: str) -> str:
    """Text safe inside a markdown table cell."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _shown(value: object) -> str:
    """A default as a user types it: paths and lists of paths as plain words."""
    if isinstance(value, (list, tuple)):
        return " ".join(str(v) for v in value)
    return str(value)


def _option_rows(parser: argparse.ArgumentParser) -> list[str]:
    rows = []
    for action in parser._actions:  # noqa: SLF001
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):  # noqa: SLF001
            continue
        if action.option_strings:
            names = ", ".join(f"`{s}`" for s in action.option_strings)
            if action.nargs != 0 and action.metavar is not None:
                names += f" `{action.metavar}`"
            elif action.nargs != 0 and action.choices is None and not isinstance(action, argparse.BooleanOptionalAction):
                names += f" `{action.dest.upper()}`"
        else:
            names = f"`{action.metavar or action.dest}`"
        details = []
        if action.choices is not None and not isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            details.append("one of " + ", ".join(f"`{c}`" for c in action.choices))
        if action.nargs in ("+", "*"):
            details.append("several values")
        if action.required and action.option_strings:
            details.append("required")
        help_text = action.help or ""
        default = action.default
        if default not in (None, False, [], argparse.SUPPRESS) and "default" not in help_text.lower():
            details.append(f"default `{_shown(default)}`")
        extra = f"({'; '.join(details)})" if details else ""
        rows.append(f"| {names} | {_cell(f'{help_text} {extra}')} |")
    return rows


def _section(command: str, parser: argparse.ArgumentParser, help_text: str, level: int) -> list[str]:
    lines = [f"{'#' * level} {command}", ""]
    description = parser.description or help_text
    if description:
        lines += [description[0].upper() + description[1:], ""]
    width = argparse.HelpFormatter(parser.prog, width=USAGE_WIDTH)  # the terminal's width must not change the page
    width.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)  # noqa: SLF001
    usage = width.format_help().replace("usage: ", "", 1).strip()
    lines += ["```text", usage, "```", ""]
    rows = _option_rows(parser)
    if rows:
        lines += ["| argument | meaning |", "| --- | --- |", *rows, ""]
    children = subcommands(parser)
    if children:
        lines += ["Subcommands: " + ", ".join(f"[`{name}`](#{_slug(f'{command} {name}')})" for name, _, _ in children) + ".", ""]
    return lines


def _slug(heading: str) -> str:
    """The anchor MkDocs gives a heading of plain words and hyphens ('clods-bench data generate' -> 'clods-bench-data-generate')."""
    from markdown.extensions.toc import slugify

    return slugify(heading, "-")


def cli_reference(parser: argparse.ArgumentParser | None = None) -> str:
    """The whole page: the top-level command, then every subcommand with its usage and options."""
    if parser is None:
        from clods_bench.cli import build_parser

        parser = build_parser()
    prog = parser.prog
    lines = [HEADER, *_section(prog, parser, parser.description or "", 2)]
    for command, sub, help_text in walk(parser, prog):
        lines += _section(command, sub, help_text, 2 if command.count(" ") == 1 else 3)
    return "\n".join(lines).rstrip() + "\n"
