"""The CLI reference page is the parser: every command and option of `clods-bench` is on it, in the parser's words."""

from __future__ import annotations

import argparse

from clods_bench.cli import build_parser
from clods_bench.docsgen.cli_reference import cli_reference, walk
from tests.docs.pages import heading_ids


def test_every_command_and_option_of_the_parser_is_on_the_page() -> None:
    parser = build_parser()
    page = cli_reference(parser)
    ids = heading_ids(page)
    for command, sub, _ in [("clods-bench", parser, ""), *walk(parser, "clods-bench")]:
        assert command.replace(" ", "-") in ids, command
        for action in sub._actions:  # noqa: SLF001
            for option in action.option_strings:
                if option not in ("-h", "--help"):
                    assert f"`{option}`" in page, f"{command}: {option}"
            if action.help and not isinstance(action, (argparse._SubParsersAction, argparse._HelpAction)):  # noqa: SLF001
                assert " ".join(action.help.split()).replace("|", "\\|") in page, f"{command}: help of {action.dest}"


def test_a_small_parser_gives_the_expected_page() -> None:
    parser = argparse.ArgumentParser(prog="tool", description="does things")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("go", help="go somewhere")
    p.add_argument("where", help="a place")
    p.add_argument("--speed", type=int, default=3, help="steps per second")
    p.add_argument("--mode", choices=("a", "b"), default="a", help="how")
    page = cli_reference(parser)
    assert "## tool\n\nDoes things\n" in page
    assert "Subcommands: [`go`](#tool-go)." in page
    assert "## tool go\n\nGo somewhere\n\n```text\ntool go [-h] [--speed SPEED] [--mode {a,b}] where\n```" in page
    assert "| `where` | a place |" in page
    assert "| `--speed` `SPEED` | steps per second (default `3`) |" in page
    assert "| `--mode` | how (one of `a`, `b`; default `a`) |" in page
    assert "| `--debug` | show tracebacks |" in page
