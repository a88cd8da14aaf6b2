"""Run a task over its seeds: resolve its plugins, make sure the data exists, resume finished seeds, aggregate."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable

from rich.console import Console

from clods_bench import numerics
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.config import RunConfig, save_config
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.determinism import seed_everything
from clods_bench.benchmark.core.plugin_calls import stage
from clods_bench.benchmark.core.registry import Registry
from clods_bench.benchmark.core.resolve import resolve_plugins, task_datasets
from clods_bench.benchmark.running.records import (
    aggregate,
    default_label,
    record_dir,
    record_identity,
    require_seeds,
    reusable_seed_result,
    save_seed_result,
)
from clods_bench.datasets.digest import content_digest
from clods_bench.datasets.store import DatasetStore


def run_data_digests(cfg: RunConfig, registry: Registry) -> list[str]:
    """Content digests of the run's datasets (its own, then the task's extra ones), which must exist: what a seed's
    result records, so that a later run can tell it was made from other data."""
    return [content_digest(DatasetStore.open(d.dataset_dir())) for d in [cfg.data, *task_datasets(cfg, registry)]]


def run_task(
    cfg: RunConfig,
    registry: Registry,
    console: Console | None = None,
    ensure_data: Callable[[RunConfig, Registry, bool], object] | None = None,
) -> Path:
    """Run every seed of `cfg.task` not already finished, inside the exact scope unless host paths are asked for
    ($CLODS_BENCH_DETERMINISTIC=0), then rebuild the record from every seed finished in its folder; return the
    record directory."""
    with numerics.maybe_exact():
        return _run_task(cfg, registry, console or Console(stderr=True), ensure_data)


def _run_task(cfg: RunConfig, registry: Registry, console: Console, ensure_data: Callable[[RunConfig, Registry, bool], object] | None) -> Path:
    require_seeds(cfg)
    cfg = resolve_plugins(cfg, registry)
    task = registry.get("task", cfg.task)
    rdir = record_dir(cfg, registry)
    rdir.mkdir(parents=True, exist_ok=True)
    save_config(cfg, rdir / "config.yaml")

    run_timings: dict[str, float] = {}
    if ensure_data is None:
        from clods_bench.benchmark.running.run_data import ensure_dataset as ensure_data
    t0 = time.perf_counter()
    ensure_data(cfg, registry, cfg.progress)
    for d in task_datasets(cfg, registry):
        ensure_data(dataclasses.replace(cfg, data=d), registry, cfg.progress)
    run_timings["data_seconds"] = time.perf_counter() - t0

    data_digests = run_data_digests(cfg, registry)
    identity = record_identity(cfg, data_digests)
    for seed in cfg.seeds:
        done = reusable_seed_result(rdir, seed, data_digests, identity["config"])
        if done is not None:
            console.print(f"[dim]seed {seed}: finished earlier, reusing {rdir / f'seed_{seed}'}[/dim]")
            continue
        console.print(f"[bold]{cfg.task}[/bold] seed {seed} ({rdir})")
        work = rdir / f"seed_{seed}"
        work.mkdir(parents=True, exist_ok=True)
        seed_everything(seed)
        t0, c0 = time.perf_counter(), time.process_time()
        with stage_digests.collecting() as digests, stage(f"task {cfg.task}", seed=seed):  # names the seed in a failure
            for digest in data_digests:
                stage_digests.record("data", digest)
            result = task.run(TaskContext(config=cfg, seed=seed, work_dir=work, registry=registry))
            stage_digests.record("score", result.metrics)
        result.extra["stage_digests"] = digests.result()
        result.timings.setdefault("seed_seconds", time.perf_counter() - t0)
        result.timings.setdefault("seed_cpu_seconds", time.process_time() - c0)  # this process's CPU time: robust to a loaded host
        save_seed_result(rdir, seed, result, data_digests, identity)
    record = aggregate(cfg, default_label(cfg, registry), rdir, run_timings, data_digests)
    for seed, why in record.get("left_out", {}).items():
        console.print(f"[yellow]seed {seed} left out of the record: {why}[/yellow]")
    return rdir
