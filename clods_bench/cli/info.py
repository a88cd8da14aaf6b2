"""`clods-bench numerics` (deterministic mode: the pins and the paths in use) and `clods-bench list` (what is installed)."""

from __future__ import annotations

import argparse

from rich.table import Table

from clods_bench.cli.common import console, plugin_registry


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this group's commands to the `clods-bench` parser."""
    p = sub.add_parser("numerics", help="deterministic mode: the pinned floating-point paths, and those this process uses")
    p.add_argument("--export", action="store_true", help="print the pins as shell `export` lines (for Python code that imports numpy first)")
    p.add_argument("--probe", action="store_true",
                   help="also run four tiny fits (graph net, video predictor, renderer fit, extraction) and print their digests: "
                        "two machines in deterministic mode print the same ones")  # fmt: skip
    p.set_defaults(func=cmd_numerics)

    p = sub.add_parser("list", help="plugins, scenes, tasks and presets")
    p.set_defaults(func=cmd_list)


def cmd_list(args: argparse.Namespace) -> int:
    from clods_bench import __version__
    from clods_bench.api_version import API_VERSION
    from clods_bench.benchmark.core.config import preset_description, preset_names
    from clods_bench.benchmark.core.plugin_report import print_problems, source_label

    reg = plugin_registry()
    table = Table(title=f"clods-bench {__version__} (plugin API {API_VERSION}): what is installed")
    for col in ("kind", "name", "description", "from"):
        table.add_column(col)
    for kind in ("task", "simulator", "renderer", "video_predictor", "scene"):
        for name in reg.names(kind):
            table.add_row(kind, name, reg.get(kind, name).description, source_label(reg, kind, name))
    for name in preset_names():
        table.add_row("preset", name, preset_description(name), "built-in")
    console.print(table)
    print_problems(console, reg, tracebacks=args.debug)
    return 0


def cmd_numerics(args: argparse.Namespace) -> int:
    from clods_bench import numerics as dm

    if args.export:
        for key, value in sorted(dm.pins().items()):
            print(f"export {key}='{value}'")  # plain print: no line wrapping, the output is for `eval`
        print(f"export {dm.SWITCH_ENV}=1")
        return 0
    from clods_bench.benchmark.core.determinism import effective_paths

    info = dm.describe()
    console.print(f"mode: {info['mode']} (CPU: {info['cpu']}; pins version {dm.PINS_VERSION}, {dm.threads()} thread(s) per job)"
                  if dm.active() else f"mode: host paths (CPU: {info['cpu']}); exact numerics are off", highlight=False)  # fmt: skip
    for key, value in sorted((info.get("pins") or {}).items()):
        console.print(f"  {key}={value}", highlight=False, markup=False)
    missing = dm.missing_cpu_features()
    if dm.requested() and missing:
        console.print(f"this CPU lacks {', '.join(missing)}: deterministic runs stop with an error here", highlight=False)
    console.print("in use: " + ", ".join(f"{k}={v}" for k, v in effective_paths().items()), highlight=False)
    if args.probe:
        from clods_bench.benchmark.speed.determinism_probe import probe

        for family, got in probe().items():
            console.print(f"probe {family}: {got['digest']} ({got['seconds']:.1f} s)", highlight=False)
    return 0
