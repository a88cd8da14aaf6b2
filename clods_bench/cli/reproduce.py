"""`clods-bench reproduce` (the plan of every table, `--check` against committed results), `compare` and `seed-spread`."""

from __future__ import annotations

import argparse
import copy
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from rich.table import Table

from clods_bench.cli.common import add_device_arg, console, err_console, plugin_registry, report_device
from clods_bench.errors import ClodsError

if TYPE_CHECKING:
    from clods_bench.benchmark.core.config import RunConfig


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """Add this group's commands to the `clods-bench` parser."""
    p = sub.add_parser("reproduce", help="run the paper's tables from the reproduce plan; tables + manifest.json into --out")
    p.add_argument("--preset", default="ci", help="built-in preset: ci, small, paper (default: ci)")
    p.add_argument("--plan", type=Path, help="plan YAML (default: the built-in clods_bench/benchmark/reproduction/plans/reproduce.yaml)")
    p.add_argument("--out", type=Path, help="folder of the tables and manifest (default: results/<preset>)")
    p.add_argument("--executor", choices=("local", "ray"), default="local", help="run the (run, seed) jobs here (default) or as Ray tasks")
    p.add_argument("--jobs", type=int,
                   help="local executor: (run, seed) jobs run in this many worker processes (default: one per core; the numbers "
                        "are the same for any count)")  # fmt: skip
    p.add_argument("--ray-address", help="Ray cluster address (default: start a local one)")
    p.add_argument("--only", nargs="+", default=[], metavar="TABLE", help="only these table ids of the plan")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="override applied to every run")
    add_device_arg(p)
    p.add_argument("--check", type=Path, metavar="DIR", help="then compare the fresh CSVs with the committed ones in DIR (exit 1 on a moved number)")
    p.add_argument(
        "--first-seeds",
        type=int,
        metavar="K",
        help="run only the first K seeds of every run (a quicker --check: seed-to-seed std columns are then not compared)",
    )
    p.add_argument(
        "--budget",
        type=float,
        metavar="SECONDS",
        help="local executor: start no job after SECONDS; tables left unfinished are not written (nor checked), the next run resumes them",
    )
    p.add_argument("--dry-run", action="store_true", help="check the plan and list its runs, run nothing")
    p.add_argument("--claims", type=Path, metavar="FILE",
                   help="with --dry-run: check that the claims file's tables, rows and columns exist in the plan (default: "
                        "docs/claims.yaml where it exists, for the built-in plan)")  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("compare", help="compare fresh result CSVs with committed ones (tolerance.yaml of the committed folder)")
    p.add_argument("committed", type=Path, help="folder with the committed CSV tables and tolerance.yaml")
    p.add_argument("fresh", type=Path, help="folder with freshly produced CSV tables")
    p.add_argument("--tolerance", type=Path, help="tolerance YAML (default: COMMITTED/tolerance.yaml)")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("seed-spread", help="seed-to-seed variation of every metric in the run records (justifies the tolerance)")
    p.add_argument("--runs", type=Path, default=Path("runs"), help="runs folder whose records, each with two or more seeds, are read (default runs)")
    p.add_argument("--task", help="only this task")
    p.add_argument("--csv", type=Path, help="also write the per-metric rows as CSV")
    p.set_defaults(func=cmd_seed_spread)


def cmd_reproduce(args: argparse.Namespace) -> int:
    from clods_bench.benchmark.core.config import load_config
    from clods_bench.benchmark.reproduction.reproduce import reproduce, run_name, run_overrides
    from clods_bench.benchmark.running.executors import default_jobs
    from clods_bench.devices import resolve_device

    out = args.out or Path("results") / args.preset
    if args.check is not None and out.resolve() == args.check.resolve():
        raise ClodsError("--check compares fresh tables with committed ones: they cannot be the same folder", where=str(out), hint="write the fresh ones elsewhere with --out")
    overrides = [*([f"device={args.device}"] if args.device else []), *args.overrides, *(["progress=false"] if args.no_progress else [])]
    try:
        device = load_config(args.preset, None, overrides).device  # --device, or the preset's device: every run's
    except ClodsError:
        device = "cpu"  # a bad override: the plan's check below names it, with every other problem
    where = "--device" if args.device else "device"
    if device != "cpu":
        resolve_device(device, where, check=args.executor != "ray")  # a GPU that is not there: one line, before the plan
    runs = _plan_runs(args, overrides) if device != "cpu" or args.dry_run else []
    if device != "cpu":
        report_device(device, where, [cfg for _, cfg in runs], plugin_registry(), args.executor)
    if args.dry_run:
        registry = plugin_registry()
        table = Table(title=f"reproduce plan, preset {args.preset}: {len(runs)} runs")
        for col in ("table / label", "task", "plugins", "seeds", "done", "overrides"):
            table.add_column(col)
        rdirs = _record_dirs(runs, registry)
        finished = _finished_seeds(runs, rdirs)
        for (run, cfg), done in zip(runs, finished):
            plugins = "+".join(p for p in (cfg.sim, cfg.renderer, getattr(cfg, "predictor", None)) if p)
            table.add_row(run_name(run), run.task, plugins, str(cfg.seeds), ",".join(map(str, done)) or "-", " ".join(run_overrides(run)))
        console.print(table)
        # Rows of one config (a table reusing another's run) share their record: count each (config, seed) once.
        jobs = {(str(rdir), seed): seed in done for (_, cfg), done, rdir in zip(runs, finished, rdirs) for seed in cfg.seeds}
        console.print(f"{sum(jobs.values())} of {len(jobs)} seed jobs have records under {runs[0][1].runs_dir if runs else '-'}; {len(jobs) - sum(jobs.values())} to run")
        if args.check is not None:
            _report_config_changes(args.check, runs, rdirs, args.preset)
        _check_claims(args, runs)
        return 0
    manifest = reproduce(
        args.preset, out, plugin_registry(), err_console, args.executor, args.plan, overrides, args.only, args.ray_address, args.jobs or default_jobs(), args.first_seeds,
        budget_seconds=args.budget,
    )  # fmt: skip
    console.print(f"wrote {len(manifest['files'])} table files and manifest.json to {out} in {manifest['wall_seconds_total']:.1f} s")
    unfinished = manifest.get("unfinished") or {}
    if unfinished:
        done = len(manifest["tables"]) - len(unfinished)
        console.print(
            f"time budget of {args.budget:g} s: {done} of {len(manifest['tables'])} tables finished; not run (the same command resumes them): "
            + "; ".join(f"{t} ({len(rows)} row(s))" for t, rows in unfinished.items()),
            highlight=False,
        )
    if args.check is not None:
        if unfinished and len(unfinished) == len(manifest["tables"]):
            raise ClodsError(f"the time budget of {args.budget:g} s left no table to check", where="--budget", hint="give a larger budget")
        return _report_check(args.check, out, [t for t in manifest["tables"] if t not in unfinished], args.first_seeds, args.preset,
                             not_run=sorted(unfinished))  # fmt: skip
    return 0


def _check_claims(args: argparse.Namespace, runs: Sequence[tuple[Any, RunConfig]]) -> None:
    """`--dry-run`: the claims file (`--claims`, else docs/claims.yaml where it exists) against the whole plan's rows."""
    from clods_bench.benchmark.outputs.claims_check import check_claims_against_plan

    default = Path("docs/claims.yaml")
    path = args.claims or (default if args.plan is None and default.is_file() else None)  # the built-in plan's claims
    if path is None or args.only:
        return  # `--only` lists part of the plan: a claim on another table is not wrong
    if not path.is_file():
        raise ClodsError("no such file", where=str(path))
    labels: dict[str, set[str]] = {}
    for run, _ in runs:
        labels.setdefault(run.table, set()).add(run.label)
    check_claims_against_plan(path, labels)
    console.print(f"{path}: every claim's table, rows and columns are in the plan", highlight=False)


def _plan_runs(args: argparse.Namespace, overrides: Sequence[str]) -> list[tuple[Any, RunConfig]]:
    """The (plan row, resolved config) of every run `reproduce` would run (its `--plan`, `--only` and seeds)."""
    from clods_bench.benchmark.reproduction.reproduce import build_configs, load_plan

    plan = load_plan(args.plan)
    if args.only:
        plan.runs = [r for r in plan.runs if r.table in args.only]
        plan.tables = [t for t in plan.tables if t.id in args.only]
    return build_configs(plan, args.preset, plugin_registry(), overrides, first_seeds=args.first_seeds)


def _report_check(committed: Path, fresh: Path, tables: Sequence[str], first_seeds: int | None, preset: str, not_run: Sequence[str] = ()) -> int:
    """`reproduce --check`: print what moved (rows with their first differing stage, table cells) and the tables to regenerate."""
    from clods_bench.benchmark.reproduction.regression_check import check_reproduction, regenerate_command

    if not_run:
        console.print(f"not checked (left by the time budget): {', '.join(not_run)}", highlight=False)
    report = check_reproduction(committed, fresh, tables, first_seeds)
    for note in report.notes:
        console.print(note, highlight=False)
    if report.ok:
        what = "first seed of every" if first_seeds is not None else "every"
        console.print(f"the {what} row of {len(tables)} table(s) in {fresh} equals {committed} (exact, or within its tolerance.yaml)", highlight=False)
        return 0
    if report.digest_lines:
        err_console.print(f"[bold red]{len(report.digest_lines)} row seed(s) moved[/bold red] (first stage that differs, metrics that moved):", highlight=False)
        for line in report.digest_lines:
            err_console.print(f"  {line}", highlight=False, markup=False)
    if report.table_lines:
        err_console.print(f"[bold red]{len(report.table_lines)} table cell(s) moved[/bold red] ({fresh} against {committed}):", highlight=False)
        for line in report.table_lines:
            err_console.print(f"  {line}", highlight=False, markup=False)
    err_console.print(f"tables to regenerate: {', '.join(report.tables)}; when the change is intended: {regenerate_command(preset, report.tables, str(committed))}",
                      highlight=False, markup=False)  # fmt: skip
    return 1


def _report_config_changes(committed: Path, runs: Sequence[tuple[Any, RunConfig]], rdirs: Sequence[Path], preset: str) -> None:
    """`reproduce --dry-run --check DIR`: the rows whose resolved config differs from the one DIR's digests were made
    with (their record keys differ), and the tables that must be regenerated for them."""
    from clods_bench.benchmark.reproduction import run_digests
    from clods_bench.benchmark.reproduction.regression_check import regenerate_command
    from clods_bench.benchmark.reproduction.reproduce import record_key, run_name

    committed_digests = run_digests.load(Path(committed) / run_digests.DIGESTS_FILE)
    current = {run_name(run): record_key(rdir) for (run, _), rdir in zip(runs, rdirs)}
    changed = run_digests.changed_configs(committed_digests, current)
    if not changed:
        console.print(f"every row's config is the one {committed} was made with (a code change can still move numbers: run the check)")
        return
    console.print(f"{len(changed)} row(s) with another config than {committed}'s:", highlight=False)
    for _, line in changed:
        console.print(f"  {line}", highlight=False, markup=False)
    names = [name for name, _ in changed]
    tables = list(dict.fromkeys([*run_digests.tables_of(names, committed_digests), *(run.table for run, _ in runs if run_name(run) in names)]))
    console.print(f"tables to regenerate: {', '.join(tables)}: {regenerate_command(preset, tables, str(committed))}", highlight=False, markup=False)


def _record_dirs(runs: Sequence[tuple[Any, RunConfig]], registry: Any) -> list[Path]:
    """Each run's record folder as `reproduce` resolves it: a row whose config differs from an earlier row's only in
    its label reads that row's record; plugin defaults filled, paths absolute."""
    from clods_bench.benchmark.core.resolve import resolve_plugins
    from clods_bench.benchmark.reproduction.reproduce import canonical_rows, run_name
    from clods_bench.benchmark.running.records import record_dir
    from clods_bench.benchmark.running.seed_jobs import absolute_paths

    canonical, same_as = canonical_rows(runs)
    dirs = {name: record_dir(resolve_plugins(absolute_paths(copy.deepcopy(cfg)), registry), registry) for name, cfg in canonical}
    return [dirs[same_as[run_name(run)]] for run, _ in runs]


def _finished_seeds(runs: Sequence[tuple[Any, RunConfig]], rdirs: Sequence[Path]) -> list[list[int]]:
    """The seeds of each run whose results are recorded already in its record folder (what `reproduce` would skip)."""
    from clods_bench.benchmark.running.records import load_seed_result

    return [[int(s) for s in cfg.seeds if load_seed_result(rdir, int(s)) is not None] for (_, cfg), rdir in zip(runs, rdirs)]


def _report_comparison(committed: Path, fresh: Path, tolerance: Path | None, skip_columns: Sequence[str] = (), not_run: Sequence[str] = ()) -> int:
    """Compare and print; `not_run`: table ids a time budget left out, named as not checked (not a failure)."""
    from clods_bench.benchmark.reproduction.compare import compare_dirs

    if not_run:
        console.print(f"not checked (left by the time budget): {', '.join(not_run)}", highlight=False)
    problems = compare_dirs(committed, fresh, tolerance, skip_columns, skip_tables=not_run)
    if problems:
        err_console.print(f"[bold red]{len(problems)} number(s) moved beyond tolerance or tables differ[/bold red] ({fresh} vs committed {committed}):", highlight=False)
        for line in problems:
            err_console.print(f"  {line}", highlight=False, markup=False)
        return 1
    console.print(f"every compared number of {fresh} is within tolerance of {committed}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    return _report_comparison(args.committed, args.fresh, args.tolerance)


def cmd_seed_spread(args: argparse.Namespace) -> int:
    from clods_bench.atomic import write_text
    from clods_bench.benchmark.reproduction.compare import seed_spread

    frame = seed_spread(args.runs, args.task)
    if frame.empty:
        raise ClodsError("no record with at least 2 seeds and finite metrics", where=str(args.runs))
    summary = frame.groupby(["task", "label", "preset"]).agg(metrics=("metric", "size"), seeds=("seeds", "max"), median_rel_std=("rel_std", "median"),
                                                              max_rel_std=("rel_std", "max"), max_rel_dev=("max_rel_dev", "max")).reset_index()  # fmt: skip
    table = Table(title=f"seed-to-seed variation of the metrics ({args.runs}); rel = / |mean over seeds|")
    for col in summary.columns:
        table.add_column(str(col), justify="right")
    for row in summary.itertuples(index=False):
        table.add_row(*[f"{v:.3g}" if isinstance(v, float) else str(v) for v in row])
    console.print(table)
    if args.csv is not None:
        write_text(args.csv, frame.to_csv(index=False))
        console.print(f"wrote {args.csv}")
    return 0
