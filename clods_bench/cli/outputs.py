"""`clods-bench tables` and `clods-bench report`: the tables (in each task's declared layout) and the HTML report of
run records."""

from __future__ import annotations

import argparse
from pathlib import Path

from clods_bench.cli.common import console, err_console, plugin_registry
from clods_bench.errors import ClodsError


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this group's commands to the `clods-bench` parser."""
    p = sub.add_parser("tables", help="tables (markdown, LaTeX, CSV) from run records, in the layout each task declares")
    p.add_argument("--runs", type=Path, nargs="+", default=[Path("runs")],
                   help="runs folder(s): the records of several (other machines, committed records) make one table")
    p.add_argument("--out", type=Path, default=Path("tables"), help="folder the tables are written into (default tables)")
    p.add_argument("--task", default="all", help="a task (cdg, nvs, stability, dvc, dvc_multi, extract, initial_mesh, a plugin's), or all (every task with records; default)")
    p.set_defaults(func=cmd_tables)

    p = sub.add_parser("report", help="HTML report (report/index.html): every table, error-vs-time and rollout plots, NVS grids, DVC media, "
                       "rollout videos and 3D views")  # fmt: skip
    p.add_argument("--runs", type=Path, default=Path("runs"), help="runs folder whose records the report shows (default runs)")
    p.add_argument("--out", type=Path, default=Path("report"), help="folder of index.html and its figures and media (default report)")
    p.add_argument("--metric", default="unviewed/extrap/d_avg", help="CDG metric on the error axis (group/phase/stat)")
    p.add_argument("--bench", type=Path, default=Path("bench"), help="folder of `bench infer` results shown in the report when present (default bench)")
    watch = p.add_mutually_exclusive_group()
    watch.add_argument("--watch", nargs="+", metavar="LABEL_OR_RECORD", default=[],
                       help="animate only these runs (row labels or record folders) in the Watch section (default: every run)")
    watch.add_argument("--no-watch", action="store_true", help="no Watch section (no rollout videos, 3D views or frame animations)")
    p.set_defaults(func=cmd_report)


def cmd_tables(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.outputs.tables import write_tables
    from clods_bench.benchmark.running.records import iter_records, runs_label

    registry = plugin_registry()
    if args.task == "all":
        tasks = [t for t in registry.names("task") if any(True for _ in iter_records(args.runs, t))]
        if not tasks:
            raise ClodsError("no run records found", where=runs_label(args.runs), hint="run e.g. `clods-bench run cdg --sim constvel` first")
    else:
        tasks = [args.task]
    paths = [p for task in tasks for p in write_tables(args.runs, args.out, task, registry)]
    for p in paths:
        if p.suffix == ".md":
            console.print(p.read_text())
    console.print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.outputs.html_report import build_html_report

    paths = build_html_report(args.runs, args.out, args.metric, bench_dir=args.bench, registry=plugin_registry(),
                              watch=None if args.no_watch else args.watch, warn=lambda line: err_console.print(f"[yellow]warning:[/yellow] {line}", highlight=False))  # fmt: skip
    console.print("wrote " + ", ".join(str(p) for p in paths))
    return 0
