"""How a `clods-bench` command ends when it fails: one line naming the failure, and the exit status.

Exit statuses: 0 success; 1 a check found a difference (`reproduce --check`, `compare`), or an internal error (a bug
of clods-bench: the line says where to report it and names the file its traceback was saved to); 2 a problem of the
input (a config value, a file, a plugin name), of a third-party plugin (it raised, or broke its interface's contract),
or of the machine (disk full, permission denied, out of memory); 130 interrupted (Ctrl-C, or SIGTERM in a computing
command), finished work kept.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import signal
import threading
import time
import traceback
from pathlib import Path
from typing import Any, Iterator, Sequence

from rich.console import Console
from rich.markup import escape

from clods_bench.errors import STAGE_ATTRIBUTE, ClodsError, PluginError, environment_problem

EXIT_INTERNAL = 1
EXIT_PROBLEM = 2
EXIT_INTERRUPTED = 130
INTERRUPTED = "interrupted; finished work is kept and the next run resumes"
TRACKER_LABELS = ("issues", "issue tracker", "bug tracker", "tracker", "bugs")
"""`[project.urls]` labels (case-insensitive) that name the issue tracker."""


def report(exc: BaseException, args: argparse.Namespace | None, console: Console, argv: Sequence[str] = ()) -> int:
    """Print the one line that names `exc` (and where it happened) on `console`; return the exit status. `argv`: the
    command's arguments, written at the top of a traceback file."""
    if isinstance(exc, KeyboardInterrupt):
        by = " by SIGTERM" if str(exc) == f"signal {int(signal.SIGTERM)}" else ""
        console.print(INTERRUPTED.replace("interrupted", f"interrupted{by}", 1), highlight=False, markup=False)
        return EXIT_INTERRUPTED
    if isinstance(exc, PluginError) and exc.builtin:
        return _internal(exc, exc.message, args, console, argv)
    if isinstance(exc, ClodsError):
        line = exc.message
        if isinstance(exc, PluginError):  # a third-party plugin's bug: its author wants the traceback
            saved = save_traceback(exc, args, argv)
            line += f" (traceback: {saved})" if saved else ""
        console.print(f"[bold red]error:[/bold red] {escape(line)}", highlight=False)
        return EXIT_PROBLEM
    env = environment(exc)
    if env is not None:
        (what, advice), where = env, stage_of(exc)
        console.print(f"[bold red]error:[/bold red] {escape(what)}{escape(f' (stage: {where})') if where else ''}; {escape(advice)}", highlight=False)
        return EXIT_PROBLEM
    where = stage_of(exc)
    return _internal(exc, f"{type(exc).__name__}: {exc}" + (f" (stage: {where})" if where else ""), args, console, argv)


def _internal(exc: BaseException, line: str, args: argparse.Namespace | None, console: Console, argv: Sequence[str]) -> int:
    """The line of a clods-bench bug: what failed, where to report it, the file holding the traceback."""
    saved = save_traceback(exc, args, argv)
    keep = f"; please report it at {issue_tracker()} with the traceback saved in {saved}" if saved else f"; please report it at {issue_tracker()}"
    console.print(f"[bold red]internal error:[/bold red] {escape(line)} (a bug in clods-bench{escape(keep)})", highlight=False)
    return EXIT_INTERNAL


def environment(exc: BaseException) -> tuple[str, str] | None:
    """(what failed, what to do) when `exc`, or an exception it was raised from, is the machine's failure."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        found = environment_problem(exc)
        if found is not None:
            return found
        exc = exc.__cause__  # type: ignore[assignment]
    return None


def stage_of(exc: BaseException) -> str | None:
    """The stage of the run `exc` (or an exception it was raised from) passed through, if any noted it."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        where = getattr(exc, STAGE_ATTRIBUTE, None)
        if where:
            return str(where)
        exc = exc.__cause__  # type: ignore[assignment]
    return None


def issue_tracker() -> str:
    """The issue tracker's URL from the installed package's `[project.urls]`, else 'the clods-bench issue tracker'."""
    import importlib.metadata

    try:
        urls = importlib.metadata.metadata("clods-bench").get_all("Project-URL") or []
    except importlib.metadata.PackageNotFoundError:
        urls = []
    for entry in urls:
        label, _, url = str(entry).partition(",")
        if label.strip().lower() in TRACKER_LABELS and url.strip():
            return url.strip()
    return "the clods-bench issue tracker"


def traceback_dir(args: argparse.Namespace | None) -> Path:
    """Where a traceback file goes: the command's runs_dir when it has one that exists, else the working directory."""
    try:
        if args is not None and hasattr(args, "preset") and hasattr(args, "overrides"):
            from clods_bench.benchmark.core.config import load_config

            runs = Path(load_config(args.preset, getattr(args, "config", None), list(args.overrides)).runs_dir)
            if runs.is_dir():
                return runs
    except Exception:  # noqa: BLE001 - the config that failed may not load: the working directory then
        pass
    return Path.cwd()


def save_traceback(exc: BaseException, args: argparse.Namespace | None, argv: Sequence[str] = ()) -> Path | None:
    """Write the command line `argv` and `exc`'s traceback (with its causes) to `clods-bench-traceback-<time>-<pid>.txt`
    atomically; its path, or None when it could not be written (the line then names no file)."""
    from clods_bench.atomic import write_text

    path = traceback_dir(args) / f"clods-bench-traceback-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.txt"
    text = f"clods-bench {shlex.join(argv)}\n\n" + "".join(traceback.format_exception(exc))
    try:
        write_text(path, text)
    except Exception:  # noqa: BLE001 - a full disk must not hide the error being reported
        return None
    return path.resolve()


@contextlib.contextmanager
def term_as_interrupt(active: bool = True) -> Iterator[None]:
    """While active (main thread only), SIGTERM raises KeyboardInterrupt('signal 15') like Ctrl-C, so `kill <pid>` or a
    scheduler's time limit ends a computing command with the 'interrupted' line and status 130, its atomic writes
    and locks released on the way out."""
    if not active or threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")
