"""The CLI reference page, written from `clods-bench`'s own argument parser (never copied by hand).

Each command's usage (at 80 columns) and its arguments as `--help` lists them: the invocation (`-o OUT, --out OUT`,
`--mode {a,b}`) and the help text with `%(default)s` expanded, nothing added. The arguments are a raw HTML table, so
`<placeholders>` are escaped and shown as typed and a flag name never breaks across lines (docs/stylesheets).
"""

from __future__ import annotations

import argparse
import html
import re
from typing import Iterator

HEADER = """# CLI reference

Generated from the argument parser of `clods-bench` when the site is built, so it lists exactly the
commands and options of the installed version; `clods-bench COMMAND --help` prints the same text.
Every command also takes `-h`/`--help`; every computing command also accepts the options of its section;
`--set KEY=VALUE` may be repeated.
"""


USAGE_WIDTH = 80
"""Columns of the usage blocks (a terminal's usual width; argparse would otherwise follow the terminal that builds the
site)."""


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


def _formatter(parser: argparse.ArgumentParser) -> argparse.HelpFormatter:
    """The parser's own help formatter at a fixed width (argparse would otherwise follow the terminal that builds the site)."""
    return parser.formatter_class(prog=parser.prog, width=USAGE_WIDTH)


def listed_actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The arguments `--help` lists with a help text, in its order, less `-h/--help` and the subcommand list (the page
    links the subcommands instead)."""
    positionals = [a for a in parser._actions if not a.option_strings]  # noqa: SLF001
    optionals = [a for a in parser._actions if a.option_strings]  # noqa: SLF001
    return [a for a in positionals + optionals
            if a.help != argparse.SUPPRESS and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]  # noqa: SLF001  # fmt: skip


def option_entries(parser: argparse.ArgumentParser) -> list[tuple[str, str]]:
    """(invocation, help) of each listed argument exactly as `parser.format_help()` writes them: `-o OUT, --out OUT`,
    `--mode {a,b}`, the help with `%(default)s` and the like expanded; nothing added."""
    fmt = _formatter(parser)
    return [(fmt._format_action_invocation(a), fmt._expand_help(a) if a.help else "") for a in listed_actions(parser)]  # noqa: SLF001


_CODE = re.compile(r"`([^`]+)`")
_PIECES = re.compile(r"(, |,|\s+|\{|\})")


def help_html(text: str) -> str:
    """A help text as HTML: `<`, `>` and `&` escaped, `code` in backticks as code spans (the help's own markup)."""
    parts = _CODE.split(" ".join(text.split()))
    return "".join(f"<code>{html.escape(p, quote=False)}</code>" if i % 2 else html.escape(p, quote=False) for i, p in enumerate(parts))


def invocation_html(invocation: str) -> str:
    """An invocation as one code span whose flag names, metavars and choices never break inside; a line may break
    between option strings and after the commas of a `{choice,...}` list."""
    out = []
    for piece in _PIECES.split(invocation):
        if not piece:
            continue
        if piece == ",":
            out.append(",<wbr>")
        elif _PIECES.fullmatch(piece):
            out.append(html.escape(piece, quote=False))
        else:
            out.append(f'<span class="nw">{html.escape(piece, quote=False)}</span>')
    return f"<code>{''.join(out)}</code>"


def options_table(parser: argparse.ArgumentParser) -> list[str]:
    """The arguments of one command as an HTML table (raw HTML, so no markdown rule can touch the text)."""
    entries = option_entries(parser)
    if not entries:
        return []
    rows = [f"<tr><td>{invocation_html(inv)}</td><td>{help_html(text)}</td></tr>" for inv, text in entries]
    return ['<table class="cli-options">', "<thead><tr><th>argument</th><th>meaning</th></tr></thead>", "<tbody>", *rows, "</tbody>", "</table>"]


def _section(command: str, parser: argparse.ArgumentParser, help_text: str, level: int) -> list[str]:
    lines = [f"{'#' * level} {command}", ""]
    description = parser.description or help_text
    if description:
        lines += [help_html(description[0].upper() + description[1:]), ""]
    fmt = _formatter(parser)
    fmt.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)  # noqa: SLF001
    first, *rest = fmt.format_help().replace("usage: ", "", 1).strip().splitlines()
    usage = "\n".join([first, *(line.removeprefix(" " * len("usage: ")) for line in rest)])  # continuation lines line up
    lines += ["```text", usage, "```", ""]
    table = options_table(parser)
    if table:
        lines += [*table, ""]
    children = subcommands(parser)
    if children:
        links = (f'<span class="nw">[`{name}`](#{_slug(f"{command} {name}")})</span>' for name, _, _ in children)
        lines += ["Subcommands: " + ", ".join(links) + ".", ""]
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
