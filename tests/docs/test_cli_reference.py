"""The CLI reference page is the parser: every command's arguments on the page are exactly what its `--help` lists."""

from __future__ import annotations

import argparse
import html
import re

import pytest

from clods_bench.cli import build_parser
from clods_bench.docsgen.cli_reference import cli_reference, walk
from tests.docs.pages import heading_ids

ROW = re.compile(r"<tr><td>(.*?)</td><td>(.*?)</td></tr>")
TAG = re.compile(r"<[^>]+>")


def _text(cell: str, code: str = "`") -> str:
    """A table cell's HTML back to the text a terminal shows: code spans in backticks (none for the invocation, one
    code span as a whole), tags dropped, entities decoded."""
    return html.unescape(TAG.sub("", re.sub(r"<code>(.*?)</code>", rf"{code}\1{code}", cell)))


def page_sections(page: str) -> dict[str, list[tuple[str, str]]]:
    """Per command heading of the page, the (invocation, help) rows of its arguments table, as plain text."""
    out: dict[str, list[tuple[str, str]]] = {}
    current = None
    for line in page.splitlines():
        if line.startswith("#"):
            current = line.lstrip("#").strip()
            out[current] = []
        elif current and (m := ROW.fullmatch(line)):
            out[current].append((_text(m.group(1), code=""), _text(m.group(2))))
    return out


def help_entries(parser: argparse.ArgumentParser) -> list[tuple[str, str]]:
    """(invocation, help) of each argument as `parser.format_help()` prints it, read back from that text (a wide
    terminal, so no help text wraps); less `-h/--help` and the subcommand list."""
    formatter = parser.formatter_class
    parser.formatter_class = lambda prog: formatter(prog, width=100_000, max_help_position=100_000)
    try:
        text = parser.format_help()
    finally:
        parser.formatter_class = formatter
    subcommands = {a.metavar or "{" + ",".join(a.choices) + "}" for a in parser._actions if isinstance(a, argparse._SubParsersAction)}  # noqa: SLF001
    entries, section = [], False
    for line in text.splitlines():
        if line.endswith(":") and not line.startswith(" "):
            section = True
            continue
        if not section or not line.startswith("  ") or line.startswith("    "):
            continue  # the description, or the subcommands' own lines under the subcommand list
        invocation, _, help_text = line.strip().partition("  ")
        if invocation in ("-h, --help", *subcommands):
            continue
        entries.append((invocation, " ".join(help_text.split())))
    return entries


def _commands() -> list[tuple[str, argparse.ArgumentParser]]:
    parser = build_parser()
    return [("clods-bench", parser), *((c, p) for c, p, _ in walk(parser, "clods-bench"))]


def test_every_command_is_on_the_page_with_exactly_the_arguments_its_help_lists() -> None:
    commands = _commands()
    page = cli_reference(commands[0][1])
    ids, sections = heading_ids(page), page_sections(page)
    for command, parser in commands:
        assert command.replace(" ", "-") in ids, command
        expected = help_entries(parser)
        assert expected or not sections[command], command
        assert sections[command] == expected, command


def test_every_option_of_every_command_says_what_it_does() -> None:
    """An option without help shows as its bare name on the page and in `--help`; each one says what it takes."""
    bare = [f"{command} {action.option_strings[-1]}" for command, parser in _commands() for action in parser._actions  # noqa: SLF001
            if action.option_strings and action.help is None]  # fmt: skip
    assert bare == []


def test_placeholders_are_escaped_and_flags_never_break() -> None:
    page = cli_reference(build_parser())
    assert "(default: results/&lt;preset&gt;)" in page  # `reproduce --out`'s help, shown as typed
    for line in page.splitlines():
        if line.startswith("<tr>"):
            help_cell = ROW.fullmatch(line).group(2)
            assert "<" not in TAG.sub("", help_cell), line  # every other `<` is escaped
    assert '<span class="nw">--no-deterministic</span>' in page
    assert "(default `" not in page  # nothing added to the help texts


def test_a_small_parser_gives_the_expected_page() -> None:
    parser = argparse.ArgumentParser(prog="tool", description="does things")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("go", help="go somewhere")
    p.add_argument("where", help="a <place>")
    p.add_argument("-s", "--speed", type=int, default=3, help="steps per second (default %(default)s)")
    p.add_argument("--mode", choices=("a", "b"), default="a", help="how, `a` or `b`")
    p.add_argument("--quiet", action="store_true", help=argparse.SUPPRESS)
    page = cli_reference(parser)
    assert "## tool\n\nDoes things\n" in page
    assert 'Subcommands: <span class="nw">[`go`](#tool-go)</span>.' in page
    assert "## tool go\n\nGo somewhere\n\n```text\ntool go [-h] [-s SPEED] [--mode {a,b}] where\n```" in page
    assert '<tr><td><code><span class="nw">where</span></code></td><td>a &lt;place&gt;</td></tr>' in page
    assert ('<tr><td><code><span class="nw">-s</span> <span class="nw">SPEED</span>, <span class="nw">--speed</span> '
            '<span class="nw">SPEED</span></code></td><td>steps per second (default 3)</td></tr>') in page  # fmt: skip
    assert ('<tr><td><code><span class="nw">--mode</span> {<span class="nw">a</span>,<wbr><span class="nw">b</span>}</code></td>'
            "<td>how, <code>a</code> or <code>b</code></td></tr>") in page  # fmt: skip
    assert "--quiet" not in page
    assert page_sections(page)["tool go"] == help_entries(p)


@pytest.mark.parametrize("text", ["x  y", "a <b> & c"])
def test_help_texts_read_back_as_typed(text: str) -> None:
    parser = argparse.ArgumentParser(prog="t")
    parser.add_argument("--flag", help=text)
    assert page_sections(cli_reference(parser))["t"] == help_entries(parser) == [("--flag FLAG", " ".join(text.split()))]
