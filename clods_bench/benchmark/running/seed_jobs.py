"""Many runs as (run, seed) jobs on an executor: their datasets first, finished seeds skipped, then every run aggregated.

`run_seed_job` runs one job through the ordinary runner, which writes `seed_<k>/result.json` into the run's record
directory; afterwards the driver aggregates every run locally (all seeds are then resumed from disk), so both
executors produce the same records and the same numbers. Paths in the configs are made absolute before dispatch:
Ray workers may start in another directory.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, Sequence

from rich.console import Console

from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.resolve import resolve_plugins, task_datasets
from clods_bench.benchmark.running.executors import LocalExecutor, RayExecutor, SeedJob
from clods_bench.benchmark.running.records import config_digest, load_seed_result, record_dir, require_seeds, reusable_seed_result
from clods_bench.benchmark.running.run_data import ensure_complete_dataset
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict


def run_seed_job(job: SeedJob) -> dict[str, Any]:
    """Run one seed of one run (in whatever process executes it); return {'name', 'seed', 'record_dir', 'wall_seconds'}."""
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.benchmark.running.runner import run_task

    cfg = dataclass_from_dict(RunConfig, dict(job.config), where=f"job {job.name}")
    cfg.seeds = [int(job.seed)]
    t0 = time.perf_counter()
    rdir = run_task(cfg, default_registry(), Console(stderr=True, quiet=True), ensure_data=ensure_complete_dataset)
    return {"name": job.name, "seed": int(job.seed), "record_dir": str(rdir), "wall_seconds": time.perf_counter() - t0}


def absolute_paths(cfg: RunConfig) -> RunConfig:
    """The same config with `runs_dir` and `data.root` made absolute (so a worker anywhere writes to the same place)."""
    cfg.runs_dir = str(Path(cfg.runs_dir).resolve())
    cfg.data.root = str(Path(cfg.data.root).resolve())
    return cfg


def run_configs(
    configs: Sequence[tuple[str, RunConfig]],
    executor: LocalExecutor | RayExecutor,
    registry: Any,
    console: Console,
    deadline: float | None = None,
) -> list[dict[str, Any]]:
    """Run every (name, config) over its seeds through `executor`; aggregate each run here; return one summary per run.

    Datasets are generated first, once per distinct data config, their trajectories in parallel through `executor`.
    Seeds finished earlier are skipped. Summary: name, record_dir, wall_seconds (this call's jobs), seeds_run,
    complete (every seed recorded). `deadline` (`time.monotonic()`, local executor only): no job starts after it; a
    run left with a seed unrecorded is not aggregated (complete False) and resumes on the next call.
    """
    if deadline is not None and executor.name != "local":  # before any dataset is generated
        raise ClodsError("a time budget needs the local executor (Ray schedules every job at once)", where="--budget")
    from clods_bench.benchmark.running.runner import run_data_digests, run_task

    for _, cfg in configs:
        require_seeds(cfg)
    configs = [(name, resolve_plugins(absolute_paths(cfg), registry)) for name, cfg in configs]
    parallel = executor.name == "ray" or getattr(executor, "jobs", 1) > 1
    seen: set[Path] = set()
    for name, cfg in configs:
        for d in [cfg.data, *task_datasets(cfg, registry)]:  # the training data and any other the task scores on
            ddir = d.dataset_dir()
            if ddir not in seen:
                seen.add(ddir)
                console.print(f"[dim]dataset {ddir}[/dim]")
                ensure_complete_dataset(dataclasses.replace(cfg, data=d), registry, cfg.progress, executor=executor if parallel else None)

    digests: dict[str, list[str]] = {}  # per run, read only for runs with a finished seed

    def reusable(name: str, cfg: RunConfig, seed: int) -> bool:
        """Whether the seed has a result to reuse (one made from other data or under other pins is an error, here
        before any job starts)."""
        rdir = record_dir(cfg, registry)
        if load_seed_result(rdir, seed) is None:
            return False
        if name not in digests:
            digests[name] = run_data_digests(cfg, registry)
        return reusable_seed_result(rdir, seed, digests[name], config_digest(cfg)) is not None

    # Seed-major order: every run's first seed before any second seed. Parallel workers then start different
    # runs together instead of two seeds of one run that would wait on each other's shared cached stages.
    jobs = []
    depth = max((len(cfg.seeds) for _, cfg in configs), default=0)
    for k in range(depth):
        for name, cfg in configs:
            if k >= len(cfg.seeds):
                continue
            seed = cfg.seeds[k]
            if not reusable(name, cfg, seed):
                worker_cfg = cfg.to_dict()
                worker_cfg["progress"] = False if parallel else cfg.progress
                jobs.append(SeedJob(config=worker_cfg, seed=int(seed), name=name))
    console.print(f"{len(jobs)} seed job(s) to run on the {executor.name} executor ({sum(len(c.seeds) for _, c in configs) - len(jobs)} finished earlier)")
    results = executor.map(run_seed_job, jobs, describe=lambda j: f"{j.name} seed {j.seed}", progress=any(c.progress for _, c in configs),
                           deadline=deadline)  # fmt: skip

    summaries = []
    for name, cfg in configs:
        mine = [r for r in results if r is not None and r["name"] == name]
        rdir = record_dir(cfg, registry)
        summary = {"name": name, "record_dir": str(rdir), "wall_seconds": sum(r["wall_seconds"] for r in mine),
                   "seeds_run": sorted(r["seed"] for r in mine), "complete": True}  # fmt: skip
        if any(load_seed_result(rdir, seed) is None for seed in cfg.seeds):
            summary["complete"] = False  # left out by the deadline: aggregating would run its seeds here
        else:
            rdir = run_task(cfg, registry, Console(stderr=True, quiet=True), ensure_data=ensure_complete_dataset)  # every seed is on disk now: this only aggregates
            summary["record_dir"] = str(rdir)
        summaries.append(summary)
    return summaries
