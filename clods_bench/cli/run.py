"""`clods-bench run TASK`: one task over its seeds (here or in worker processes, or on Ray), then its record's metrics."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.table import Table

from clods_bench.cli.common import add_config_args, add_device_arg, console, err_console, plugin_registry, report_device, run_config


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this group's commands to the `clods-bench` parser."""
    p = sub.add_parser("run", help="run a task: cdg, nvs, stability, dvc, ...")
    p.add_argument("task", help="task name")
    p.add_argument("--sim", help="simulator plugin")
    p.add_argument("--renderer", help="renderer plugin")
    p.add_argument("--predictor", help="video-predictor plugin (dvc task baselines: copylast, simvp, tau, mau, mmvp)")
    p.add_argument("--label", help="row label in the tables")
    p.add_argument("--train-subset", choices=("all", "first_half"), help="training trajectories: all (MGN) or first half (MGN*)")
    p.add_argument("--seeds", type=int, nargs="+", help="seeds (default from the preset)")
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="run the seeds here (default) or as Ray tasks")
    p.add_argument("--jobs", type=int,
                   help="local executor: seeds run in this many worker processes (default: one per core, at most one per seed; "
                        "the numbers are the same for any count)")  # fmt: skip
    p.add_argument("--ray-address", help="Ray cluster address (default: start a local one)")
    add_device_arg(p)
    add_config_args(p)
    p.set_defaults(func=cmd_run)


def cmd_run(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.running.records import RECORD_FILE, read_record
    from clods_bench.benchmark.running.runner import run_task

    cfg = run_config(args, task=args.task, sim=args.sim, renderer=args.renderer, predictor=args.predictor, label=args.label, train_subset=args.train_subset, seeds=args.seeds,
                     device=args.device)  # fmt: skip
    report_device(cfg.device, "--device" if args.device else "device", [cfg], plugin_registry(), args.executor)
    from clods_bench.benchmark.running.executors import default_jobs, make_executor
    from clods_bench.benchmark.running.seed_jobs import run_configs

    jobs = args.jobs or min(default_jobs(), max(1, len(cfg.seeds)))
    if args.executor == "local" and jobs == 1:
        rdir = run_task(cfg, plugin_registry(), err_console)
    else:
        summary = run_configs([("run", cfg)], make_executor(args.executor, args.ray_address, jobs), plugin_registry(), err_console)
        rdir = Path(summary[0]["record_dir"])
    rec = read_record(rdir / RECORD_FILE)
    table = Table(title=f"{rec['task']} / {rec['label']} / {rec['scene']} / preset {rec['preset']} ({len(rec['seeds'])} seeds)")
    table.add_column("metric")
    table.add_column("mean ± std", justify="right")
    for key, v in sorted(rec["metrics"].items(), key=lambda kv: _metric_order(kv[0])):
        table.add_row(key, _pm(v))
    for key, v in rec["timings"].items():
        table.add_row(f"[dim]{key}[/dim]", _pm(v))
    console.print(table)
    console.print(f"record: {rdir}")
    return 0


def _metric_order(key: str) -> tuple:
    """Sort 'group/phase/stat' keys in the paper's column order."""
    from clods_bench.benchmark.scoring.metrics import GROUPS, PHASES, STATS

    order = {name: i for i, name in enumerate((*GROUPS, *PHASES, *STATS))}
    ranks = [order.get(part, 99) for part in key.split("/")]
    return (*ranks, *[99] * (3 - len(ranks)), key)  # padded: keys of different depths ('psnr', 'all/psnr') compare


def _pm(v: dict) -> str:
    if v["mean"] is None:
        return "n/a"
    return f"{v['mean']:.4g} ± {v['std']:.2g}"
