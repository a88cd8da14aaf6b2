"""`clods-bench reproduce`: run the paper's tables from a plan (YAML data) and write them with a manifest.

The plan (`clods_bench/benchmark/reproduction/plans/reproduce.yaml` by default) lists tables and runs; each
run names its task, plugins, row label, `--set` overrides and the table it belongs to. Adding
a row is editing YAML. Every run is checked before anything starts: an unregistered task or
plugin, an unknown config key or a run pointing at an unknown table fails the whole command,
listing every problem. The runs' records go to the preset's `runs_dir` (resumable per seed);
the tables (markdown, LaTeX, CSV, one set per table id) and `manifest.json` go to `--out`.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

from rich.console import Console

from clods_bench import numerics
from clods_bench.atomic import write_json
from clods_bench.benchmark.core.config import RunConfig, load_config, read_yaml
from clods_bench.benchmark.core.descriptors import TableLayout
from clods_bench.benchmark.core.resolve import resolve_plugins
from clods_bench.benchmark.outputs.tables import layout_frames, scored_scenes, table_layout, write_table
from clods_bench.benchmark.reproduction import run_digests
from clods_bench.benchmark.running.environment import git_commit, package_versions
from clods_bench.benchmark.running.records import RECORD_FILE, read_record, restrict
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

PLAN_VERSION = 1
MANIFEST_FILE = "manifest.json"


@dataclass
class PlanTable:
    """One output table: its id (file stem), title (caption) and the task of every row."""

    id: str
    """File stem in the output folder, e.g. table2_cdg."""
    title: str
    """Caption written above the table."""
    task: str
    """Task of every run in this table (cdg, nvs, stability, dvc, ...)."""
    overrides: list[str] = field(default_factory=list)
    """Overrides applied to every run of this table (after the plan's, before the run's own)."""


@dataclass
class PlanRun:
    """One row: a task run with its plugins and overrides, over the plan's seeds."""

    table: str
    """Id of the table this row belongs to."""
    task: str
    """Task name (must be registered)."""
    label: str | None = None
    """Row label (unique within its table and scene; also names the record directory). None: the plugin's own
    (`PluginSpec.row_label`, e.g. 'BSMS (MGN cloth frame)'), for a row of one plugin whose plugin declares one."""
    sim: str | None = None
    """Simulator plugin."""
    renderer: str | None = None
    """Renderer plugin."""
    predictor: str | None = None
    """Video predictor (tasks that take one, e.g. dvc)."""
    train_subset: str | None = None
    """'all' or 'first_half' (MGN*)."""
    scene: str | None = None
    """Scene of this row (`data.scene`, applied before the row's overrides); default: the preset's. Rows of one
    table may share a label when their scenes differ (the stability table: one row per simulator and scene)."""
    overrides: list[str] = field(default_factory=list)
    """`--set` style overrides, e.g. renderer_config.smgs.gaussians_per_face=10."""


@dataclass
class ReproducePlan:
    """The plan: tables, their runs, seeds and overrides applied to every run."""

    version: int = PLAN_VERSION
    """Plan schema version."""
    description: str = ""
    """One line shown by `reproduce --dry-run`."""
    seeds: list[int] | None = None
    """Seeds of every run (default: the preset's); at least 2."""
    overrides: list[str] = field(default_factory=list)
    """Overrides applied to every run before its own."""
    tables: list[PlanTable] = field(default_factory=list)
    """Output tables, in order."""
    runs: list[PlanRun] = field(default_factory=list)
    """Rows, in table order."""


def default_plan_path() -> Path:
    """The built-in plan shipped with the package."""
    return Path(str(resources.files("clods_bench.benchmark.reproduction") / "plans" / "reproduce.yaml"))


def load_plan(path: Path | None = None) -> ReproducePlan:
    """Read and type-check a plan YAML file; structural mistakes fail with the file and field."""
    path = Path(path) if path is not None else default_plan_path()
    data = read_yaml(path)
    plan: ReproducePlan = dataclass_from_dict(ReproducePlan, data, where=str(path))
    if plan.version != PLAN_VERSION:
        raise ClodsError(f"plan version {plan.version} is not supported (expected {PLAN_VERSION})", where=f"{path}: version")
    ids = [t.id for t in plan.tables]
    dupes = sorted({i for i in ids if ids.count(i) > 1})
    if dupes:
        raise ClodsError(f"table ids listed twice: {', '.join(dupes)}", where=f"{path}: tables")
    if not plan.runs:
        raise ClodsError("the plan has no runs", where=f"{path}: runs")
    return plan


def plan_digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]


def settle_label(run: PlanRun, registry: Any) -> str | None:
    """Give a row without a label its plugin's row label, and check a row's label against its plugins' names: a row
    naming a variant plugin's published name must say how it differs. Returns the problem, or None."""
    used = [(kind, name) for kind, name in (("simulator", run.sim), ("renderer", run.renderer), ("video_predictor", run.predictor)) if name]
    specs = []
    for kind, name in used:
        try:
            specs.append(registry.get(kind, name))
        except ClodsError:
            specs.append(None)  # an unknown plugin is reported with the row's config
    if run.label is None:
        if len(used) != 1 or specs[0] is None or getattr(specs[0], "label", None) is None:
            run.label = "+".join(name for _, name in used) or run.task
            named = ", ".join(f"{kind} '{name}'" for kind, name in used) or "no plugin"
            return f"no label, and {named} declares none (PluginSpec.label): give the row a `label:`"
        run.label = specs[0].row_label(run.train_subset == "first_half")
        return None
    for spec in specs:
        variant, published = getattr(spec, "variant", None), getattr(spec, "label", None)
        if variant and published and published in run.label and variant not in run.label:
            return (f"label '{run.label}' names {published}, but plugin '{spec.name}' is a variant ({variant}): the label must say "
                    f"'{variant}' (or leave the label out for '{spec.row_label(run.train_subset == 'first_half')}')")
    return None


def run_name(run: PlanRun) -> str:
    """A stable id of a plan row: '<table>/<label>', with '@<scene>' when the row names its scene."""
    return f"{run.table}/{run.label}" + (f"@{run.scene}" if run.scene else "")


def run_overrides(run: PlanRun) -> list[str]:
    """The row's own overrides, its scene first."""
    return ([f"data.scene={run.scene}"] if run.scene else []) + list(run.overrides)


def config_identity(cfg: RunConfig) -> str:
    """What decides a run's numbers: the resolved config without its label and progress flag."""
    d = cfg.to_dict()
    d.pop("label")
    d.pop("progress")
    return json.dumps(d, sort_keys=True, default=str)


def canonical_rows(runs: Sequence[tuple[PlanRun, RunConfig]]) -> tuple[list[tuple[str, RunConfig]], dict[str, str]]:
    """Rows whose configs differ only in their label (e.g. the default SMGS in several tables) run once: the first row
    of each config as (name, config), and every row's name -> the name of the row that runs for it."""
    canonical: dict[str, tuple[str, RunConfig]] = {}
    same_as = {}
    for run, cfg in runs:
        first = canonical.setdefault(config_identity(cfg), (run_name(run), cfg))
        same_as[run_name(run)] = first[0]
    return list(canonical.values()), same_as


def build_configs(
    plan: ReproducePlan,
    preset: str,
    registry: Any,
    extra_overrides: Sequence[str] = (),
    config_file: Path | None = None,
    first_seeds: int | None = None,
) -> list[tuple[PlanRun, RunConfig]]:
    """Resolve every run's config and check it against the registry; raise one ClodsError listing every problem.

    `first_seeds` keeps only the first that many seeds of every run: a quicker regression check (CI) whose fresh
    tables have no seed-to-seed std; a full reproduce needs at least 2 seeds.
    """
    if first_seeds is not None and first_seeds < 1:
        raise ClodsError(f"first_seeds must be >= 1, got {first_seeds}", where="--first-seeds")
    problems: list[str] = []
    value_problems: dict[str, list[str]] = {}  # a config problem -> the rows that have it (an override shared by many rows: one line)
    tables = {t.id: t for t in plan.tables}
    labels: dict[str, set[tuple[str, str]]] = {}  # (label, scene) per table
    out: list[tuple[PlanRun, RunConfig]] = []
    for i, run in enumerate(plan.runs):
        label_problem = settle_label(run, registry)
        where = f"runs[{i}] ({run_name(run)})"
        if label_problem:
            problems.append(f"{where}: {label_problem}")
            continue
        table = tables.get(run.table)
        if table is None:
            problems.append(f"{where}: unknown table '{run.table}' (tables: {', '.join(tables) or 'none'})")
            continue
        if table.task != run.task:
            problems.append(f"{where}: task '{run.task}' but table '{run.table}' holds '{table.task}' rows")
        scene = run.scene or "the preset's scene"
        if (run.label, scene) in labels.setdefault(run.table, set()):
            problems.append(f"{where}: label '{run.label}' appears twice in table '{run.table}' ({scene})")
        labels[run.table].add((run.label, scene))
        if run.task not in registry.names("task"):
            problems.append(f"{where}: task '{run.task}' is not registered (registered: {', '.join(registry.names('task'))})")
            continue
        fields: dict[str, Any] = {"task": run.task, "sim": run.sim, "renderer": run.renderer, "label": run.label, "train_subset": run.train_subset}
        if run.predictor is not None:
            fields["predictor"] = run.predictor  # a config without this field fails below, naming it
        if plan.seeds is not None:
            fields["seeds"] = plan.seeds
        try:
            cfg = load_config(preset, config_file, [*plan.overrides, *table.overrides, *run_overrides(run), *extra_overrides], **fields)
            cfg = resolve_plugins(cfg, registry)  # rows that differ only in a plugin default are one run
        except ClodsError as exc:
            value_problems.setdefault(exc.message, []).append(run_name(run))
            continue
        if first_seeds is not None:
            cfg.seeds = list(cfg.seeds[:first_seeds])
        elif len(cfg.seeds) < 2:
            problems.append(f"{where}: {len(cfg.seeds)} seed(s); reproduce needs at least 2 (seed-to-seed std)")
        out.append((run, cfg))
    for table in plan.tables:  # a table needs its task's layout: checked before anything runs
        if table.task in registry.names("task"):
            try:
                table_layout(table.task, registry)
            except ClodsError as exc:
                problems.append(f"table '{table.id}': {exc.message}")
    empty = [t.id for t in plan.tables if not any(r.table == t.id for r in plan.runs)]
    if empty:
        problems.append(f"tables without runs: {', '.join(empty)}")
    lines = [f"{message} ({_rows_text(rows)})" for message, rows in value_problems.items()]
    if len(lines) == 1 and not problems:
        raise ClodsError(lines[0])
    if problems or lines:
        raise ClodsError("the reproduce plan cannot run:\n  " + "\n  ".join([*lines, *problems]),
                         hint="enable only runs whose task and plugins are installed (`clods-bench list`)")  # fmt: skip
    return out


def _rows_text(rows: Sequence[str], shown: int = 3) -> str:
    """'row a' / 'rows a, b and c' / 'rows a, b, c and 4 more': the plan rows a problem was found in."""
    if len(rows) == 1:
        return f"row {rows[0]}"
    if len(rows) <= shown:
        return f"rows {', '.join(rows[:-1])} and {rows[-1]}"
    return f"{len(rows)} rows: {', '.join(rows[:shown])} and {len(rows) - shown} more"


# ---------------------------------------------------------------- tables


FIRST_SEED_DIR = "first_seed"
"""Subfolder of a reproduce output holding every table's CSV over the first seed alone (what `--first-seeds 1` checks)."""


def write_plan_table(table: PlanTable, layout: TableLayout, records: list[dict[str, Any]], out_dir: Path, preset: str) -> list[Path]:
    """Write `<id>.md`, `<id>.tex` and `<id>.csv` for one plan table in its task's `layout`, rows in plan order."""
    display, numeric, note = layout_frames(layout, records)
    seeds = "/".join(str(n) for n in sorted({len(r["seeds"]) for r in records}))
    scenes = ", ".join(sorted(set().union(*(scored_scenes(r) for r in records))))
    caption = f"{table.title} ({scenes}, preset {preset}; mean ± std over {seeds} seeds)" + (f". {note}" if note else "")
    return write_table(Path(out_dir) / table.id, caption, display, numeric)


# ---------------------------------------------------------------- the command


def _shown(path: str | Path) -> str:
    """`path` relative to the working directory when it lies below it (manifests get committed), else absolute."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def reproduce(
    preset: str,
    out_dir: Path,
    registry: Any,
    console: Console,
    executor_name: str = "local",
    plan_path: Path | None = None,
    overrides: Sequence[str] = (),
    only: Sequence[str] = (),
    ray_address: str | None = None,
    jobs: int = 1,
    first_seeds: int | None = None,
    budget_seconds: float | None = None,
) -> dict[str, Any]:
    """Run every run of the plan (resuming finished seeds), write every table and `manifest.json`; return the manifest.

    `first_seeds`: run only the first that many seeds of every run (see `build_configs`). `budget_seconds`: start no
    (run, seed) job later than this many seconds after the call began (local executor); a table whose rows did not all
    finish is not written but listed under the manifest's `unfinished` (table id -> row labels), and a later call
    resumes it.
    """
    from clods_bench.benchmark.running.executors import make_executor
    from clods_bench.benchmark.running.seed_jobs import run_configs

    t_start = time.perf_counter()
    if budget_seconds is not None and not budget_seconds > 0:
        raise ClodsError(f"must be a number of seconds > 0, got {budget_seconds}", where="--budget")
    deadline = None if budget_seconds is None else time.monotonic() + float(budget_seconds)
    plan_file = Path(plan_path) if plan_path is not None else default_plan_path()
    plan = load_plan(plan_file)
    if only:
        unknown = sorted(set(only) - {t.id for t in plan.tables})
        if unknown:
            raise ClodsError(f"unknown table id(s): {', '.join(unknown)}", where="--only", hint=f"one of {', '.join(t.id for t in plan.tables)}")
        plan.tables = [t for t in plan.tables if t.id in only]
        plan.runs = [r for r in plan.runs if r.table in only]
    runs = build_configs(plan, preset, registry, overrides, first_seeds=first_seeds)
    executor = make_executor(executor_name, ray_address, jobs)
    canonical, same_as = canonical_rows(runs)
    # Jobs start in the order of the plan's tables (a run shared by several tables with its first one), so a time
    # budget finishes whole tables in the order the plan lists them. The order changes no number.
    position = {t.id: i for i, t in enumerate(plan.tables)}
    first_table: dict[str, int] = {}
    for run, _ in runs:
        name = same_as[run_name(run)]
        first_table[name] = min(first_table.get(name, len(position)), position[run.table])
    canonical.sort(key=lambda item: first_table[item[0]])
    summaries = {s["name"]: s for s in run_configs(canonical, executor, registry, console, deadline=deadline)}

    out_dir = Path(out_dir)
    records: dict[str, dict[str, Any]] = {}
    manifest_runs = []
    unfinished: dict[str, list[str]] = {}
    for run, cfg in runs:
        summary = summaries[same_as[run_name(run)]]
        if not summary.get("complete", True):
            unfinished.setdefault(run.table, []).append(run.label + (f" @{run.scene}" if run.scene else ""))
            continue
        # The plan's seeds only: a runs folder may hold more seeds of this config (records accumulate), and the
        # tables of a plan stay those of its seeds.
        rec = restrict(read_record(Path(summary["record_dir"]) / RECORD_FILE), cfg.seeds)
        rec["label"] = run.label
        records[run_name(run)] = rec
        seed_seconds = [s["timings"].get("seed_seconds") for s in rec["per_seed"].values()]
        manifest_runs.append(
            {
                "table": run.table,
                "label": run.label,
                "task": run.task,
                "sim": cfg.sim,
                "renderer": cfg.renderer,
                "seeds": rec["seeds"],
                "record_dir": _shown(summary["record_dir"]),
                "same_as": None if same_as[run_name(run)] == run_name(run) else same_as[run_name(run)],
                "wall_seconds": summary["wall_seconds"] if same_as[run_name(run)] == run_name(run) else 0.0,
                "seeds_run": summary["seeds_run"] if same_as[run_name(run)] == run_name(run) else [],
                "compute_seconds": float(sum(s for s in seed_seconds if s is not None and math.isfinite(s))),
                "data_seconds": rec.get("run_timings", {}).get("data_seconds"),
            }
        )
    written: list[str] = []
    for table in plan.tables:
        if table.id in unfinished:
            console.print(f"[bold]{table.id}[/bold]: not written, {len(unfinished[table.id])} row(s) left by the time budget")
            continue
        recs = [records[run_name(r)] for r in plan.runs if r.table == table.id]
        written += [p.name for p in write_plan_table(table, table_layout(table.task, registry), recs, out_dir, preset)]
        first = min(recs[0]["seeds"]) if recs and recs[0]["seeds"] else None
        if any(len(r["seeds"]) > 1 for r in recs):  # the first seed's table too: what a `--first-seeds 1` check compares with
            single = [restrict(r, [min(r["seeds"])]) for r in recs]
            write_plan_table(table, table_layout(table.task, registry), single, out_dir / FIRST_SEED_DIR, preset)
        elif first is not None and (out_dir / FIRST_SEED_DIR).is_dir():
            (out_dir / FIRST_SEED_DIR / f"{table.id}.csv").unlink(missing_ok=True)  # a stale one from an earlier 2-seed run
        console.print(f"[bold]{table.id}[/bold]: {len(recs)} row(s)")
    rows = {}
    for run, cfg in runs:
        if run_name(run) not in records:
            continue
        canonical_name = same_as[run_name(run)]
        rows[run_name(run)] = run_digests.row_entry(run.table, run.label, record_key(summaries[canonical_name]["record_dir"]),
                                                    records[run_name(run)], None if canonical_name == run_name(run) else canonical_name)  # fmt: skip
    made_with = next((r.get("numerics") for r in records.values() if r.get("numerics")), numerics.describe())
    run_digests.write(out_dir / run_digests.DIGESTS_FILE, run_digests.build(preset, rows, made_with), merge_into_existing=bool(only))
    manifest = {
        "preset": preset,
        "plan": _shown(plan_file),
        "plan_sha256": plan_digest(plan_file),
        "overrides": list(overrides),
        "first_seeds": first_seeds,
        "executor": executor_name,
        "jobs": int(jobs),
        "commit": git_commit(),
        "versions": package_versions(),
        "tables": [t.id for t in plan.tables],
        "files": sorted(written),
        "runs": manifest_runs,
        "budget_seconds": budget_seconds,
        "unfinished": unfinished,
        "wall_seconds_total": time.perf_counter() - t_start,
        "numerics": made_with,
        "written": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    if only:
        manifest = _merged_manifest(out_dir / MANIFEST_FILE, manifest)
    write_json(out_dir / MANIFEST_FILE, manifest)
    return manifest


def _merged_manifest(path: Path, new: dict[str, Any]) -> dict[str, Any]:
    """`new` (a `--only` run) over an existing manifest of the same preset: its tables' runs and files replaced,
    the other tables' kept (an unreadable or other-preset manifest is replaced whole)."""
    try:
        old = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return new
    if not isinstance(old, dict) or old.get("preset") != new["preset"]:
        return new
    tables = set(new["tables"])
    merged = dict(new)
    merged["runs"] = [r for r in old.get("runs", []) if r.get("table") not in tables] + new["runs"]
    stems = {Path(f).stem for f in new["files"]}
    merged["files"] = sorted({f for f in old.get("files", []) if Path(f).stem not in stems} | set(new["files"]))
    merged["tables"] = [t for t in old.get("tables", []) if t not in tables] + new["tables"]
    return merged


def record_key(record_dir: str | Path) -> str:
    """A run's record folder below its runs folder (`<task>/<label>/<scene>-<preset>-<config digest>`): what names its
    config, wherever the runs folder lies."""
    return "/".join(Path(record_dir).parts[-3:])
