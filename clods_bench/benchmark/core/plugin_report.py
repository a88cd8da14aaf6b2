"""How the command line shows plugin problems: one 'warning:' line per failed plugin and per deprecated form in use,
and the sections of `clods-bench list` that name them."""

from __future__ import annotations

import contextlib
import os
import warnings
from typing import Any, Iterator

from rich.console import Console
from rich.markup import escape

from clods_bench.api_version import API_VERSION, PluginAPIDeprecationWarning
from clods_bench.benchmark.core.registry import STRICT_ENV, PluginLoadWarning, Registry


@contextlib.contextmanager
def plugin_options(strict: bool, console: Console) -> Iterator[None]:
    """For one command: plugin warnings shown as plain lines (`show_plugin_warnings`), and with `strict` any plugin
    failure an error (through STRICT_ENV, so that worker processes inherit it). Both are undone afterwards."""
    before = os.environ.get(STRICT_ENV)
    with warnings.catch_warnings():
        show_plugin_warnings(console)
        if strict:
            os.environ[STRICT_ENV] = "1"
        try:
            yield
        finally:
            if before is None:
                os.environ.pop(STRICT_ENV, None)
            else:
                os.environ[STRICT_ENV] = before


def show_plugin_warnings(console: Console) -> None:
    """Print plugin load failures and deprecations as one plain line each on `console` (other warnings as before).

    Deprecations are shown although Python hides DeprecationWarnings outside `__main__`: the plugin's user is the one
    who sees them, and the message says what its author should write instead.
    """
    warnings.filterwarnings("default", category=PluginAPIDeprecationWarning)
    previous = warnings.showwarning

    def show(message: Any, category: type[Warning], filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
        if issubclass(category, PluginLoadWarning):
            console.print(f"[bold yellow]warning:[/bold yellow] {escape(str(message))}", highlight=False)
        elif issubclass(category, PluginAPIDeprecationWarning):
            console.print(f"[bold yellow]deprecated:[/bold yellow] {escape(str(message))}", highlight=False)
        else:
            previous(message, category, filename, lineno, file, line)

    warnings.showwarning = show


def source_label(reg: Registry, kind: str, name: str) -> str:
    """Where an item comes from, for the 'from' column: 'built-in' or 'DIST VERSION'."""
    source = reg.sources.get(reg.origins[(kind, name)])
    if source is None or source.in_code:
        return reg.origins[(kind, name)]
    return "built-in" if source.builtin else f"{source.distribution} {source.version}"


def print_problems(console: Console, reg: Registry, tracebacks: bool = False) -> None:
    """The sections of `clods-bench list` naming failed plugins and deprecated forms in use, one full line each
    (`tracebacks`: and each failure's traceback, for `--debug`)."""
    if reg.failures:
        console.print("failed plugins (left out; --strict-plugins makes this an error):", style="bold", highlight=False)
        for f in reg.failures:
            console.print(f"  - {escape(f.line)}", highlight=False, soft_wrap=True)
            if tracebacks and f.detail:
                console.print(escape(f.detail), highlight=False, soft_wrap=True)
    if reg.notices:
        console.print(f"deprecated forms in use (they still work; plugin API {API_VERSION}):", style="bold", highlight=False)
        for n in reg.notices:
            console.print(f"  - {escape(n.line)}", highlight=False, soft_wrap=True)
