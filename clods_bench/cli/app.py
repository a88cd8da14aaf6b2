"""The `clods-bench` application: its parser, built from the command groups, and `main()` (deterministic mode pinned
before anything numeric loads, the exact scope of a computing command, one line per error)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from typing import Any, Iterator, Sequence

from clods_bench.cli import bench, data, failures, info, outputs, reproduce, run
from clods_bench.cli.common import err_console

GROUPS = (info, data, run, outputs, reproduce, bench)
"""The command groups, in the order their commands are listed."""


def build_parser() -> argparse.ArgumentParser:
    """The whole `clods-bench` parser: the global options, then each group's commands."""
    parser = argparse.ArgumentParser(prog="clods-bench", description="Benchmark for learning cloth dynamics from multi-view video.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    parser.add_argument(
        "--no-deterministic", action="store_true",
        help="use the host CPU's own (fastest) floating-point paths; by default every computing command runs with exact "
             "numerics, which give the same bits on every x86-64 CPU with AVX2 (same as CLODS_BENCH_DETERMINISTIC=0; see "
             "`clods-bench numerics`)",
    )  # fmt: skip
    parser.add_argument(
        "--strict-plugins", action="store_true",
        help="stop with an error when an installed plugin fails to load (by default it is named in a warning and left "
             "out); same as CLODS_BENCH_STRICT_PLUGINS=1, which CI sets",
    )  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True)
    for group in GROUPS:
        group.add_parsers(sub)
    return parser


SCOPED_COMMANDS = ("data", "run", "reproduce", "bench", "numerics")
"""Commands that compute with the numeric libraries: they run inside the exact scope unless --no-deterministic."""


def _exact_scope(args: argparse.Namespace) -> Any:
    """The exact scope for a computing command (None for the others, and with --no-deterministic or
    CLODS_BENCH_DETERMINISTIC=0)."""
    from clods_bench import numerics

    if args.command not in SCOPED_COMMANDS or args.no_deterministic or not numerics.requested():
        return None
    if args.command == "numerics" and (args.export or numerics.missing_cpu_features()):
        return None  # `numerics` still reports on a CPU the scope cannot pin
    return numerics.exact()


@contextlib.contextmanager
def _switch_for_workers(off: bool) -> Iterator[None]:
    """With --no-deterministic, $CLODS_BENCH_DETERMINISTIC=0 for the command's duration: its worker processes and
    runner then stay on the host's paths too."""
    import os

    from clods_bench.numerics import SWITCH_ENV

    before = os.environ.get(SWITCH_ENV)
    if off:
        os.environ[SWITCH_ENV] = "0"
    try:
        yield
    finally:
        if off:
            if before is None:
                os.environ.pop(SWITCH_ENV, None)
            else:
                os.environ[SWITCH_ENV] = before


def main(argv: Sequence[str] | None = None) -> int:
    """Run `clods-bench` with `argv` (default: the command line); return its exit status (`cli.failures`): 0, 1 (a
    check found a difference, or an internal error), 2 (a problem of the input, a plugin or the machine, in one
    line), 130 (interrupted: Ctrl-C, or SIGTERM in a computing command)."""
    from clods_bench import numerics

    argv = list(sys.argv[1:] if argv is None else argv)
    if "--no-deterministic" not in argv and numerics.requested():
        numerics.pin_environment()  # first: building the parser loads the plugins, and they load numpy
    elif not any(m in sys.modules for m in ("numpy", "torch", "numba")):
        numerics.unpin_environment()  # host paths: pins inherited from a parent process or exported by hand go
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        from clods_bench.benchmark.core.plugin_report import plugin_options

        with _switch_for_workers(args.no_deterministic), contextlib.ExitStack() as stack:
            stack.enter_context(failures.term_as_interrupt(args.command in SCOPED_COMMANDS))
            scope = _exact_scope(args)
            if scope is not None:
                stack.enter_context(scope)
            stack.enter_context(plugin_options(args.strict_plugins, err_console))
            return int(args.func(args) or 0)
    except KeyboardInterrupt as exc:
        return failures.report(exc, args, err_console, argv)
    except Exception as exc:  # one line; the traceback with --debug (or, for a bug, in the file the line names)
        if args.debug:
            raise
        return failures.report(exc, args, err_console, argv)
