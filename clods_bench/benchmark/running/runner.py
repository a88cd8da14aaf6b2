"""Run a task over its seeds: check plugins, make sure the data exists, resume finished seeds, aggregate."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, Callable

from rich.console import Console

from clods_bench import numerics
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.config import RunConfig, save_config
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.determinism import seed_everything
from clods_bench.benchmark.running.records import aggregate, record_dir, reusable_seed_result, save_seed_result
from clods_bench.benchmark.core.registry import Registry
from clods_bench.datasets.digest import content_digest
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError


def _named_plugin(registry: Registry, kind: str, name: str, option: str) -> Any:
    """`registry.get(kind, name)`, its unknown-name error naming the run option that gave the name."""
    try:
        return registry.get(kind, name)
    except ClodsError as exc:
        raise ClodsError(exc.what, where=option, hint=exc.hint) from None


def check_plugins(cfg: RunConfig, registry: Registry) -> None:
    """Fail before any work if the task, scene or a needed plugin is unknown or missing.

    The simulator is looked up by name for every task, the CloDS rows' backbone included, so any registered
    simulator (a third-party one too) can be named; an unknown name fails here, naming the option `sim`.
    """
    task = registry.get("task", cfg.task)
    registry.get("scene", cfg.data.scene)
    task_datasets(cfg, registry)  # e.g. CDG's eval_data: its fields and scene
    if cfg.sim:
        _named_plugin(registry, "simulator", cfg.sim, "sim")
    if "sim" in task.needs:
        if not cfg.sim:
            raise ClodsError(f"task '{cfg.task}' needs a simulator", where="--sim", hint=f"one of {registry.names('simulator')}")
        spec = registry.get("simulator", cfg.sim)
        spec.make_config(cfg.sim_config.get(cfg.sim, {}), where=f"sim_config.{cfg.sim}")
    if "renderer" in task.needs:
        if not cfg.renderer:
            raise ClodsError(f"task '{cfg.task}' needs a renderer", where="--renderer", hint=f"one of {registry.names('renderer')}")
        spec = registry.get("renderer", cfg.renderer)
        spec.make_config(cfg.renderer_config.get(cfg.renderer, {}), where=f"renderer_config.{cfg.renderer}")
    if cfg.sim and "sim" not in task.needs:  # optional plugins (dvc takes --sim --renderer or --predictor): checked all the same
        registry.get("simulator", cfg.sim).make_config(cfg.sim_config.get(cfg.sim, {}), where=f"sim_config.{cfg.sim}")
    if cfg.renderer and "renderer" not in task.needs:
        registry.get("renderer", cfg.renderer).make_config(cfg.renderer_config.get(cfg.renderer, {}), where=f"renderer_config.{cfg.renderer}")
    if cfg.predictor:
        spec = registry.get("video_predictor", cfg.predictor)
        spec.make_config(cfg.video_config.get(cfg.predictor, {}), where=f"video_config.{cfg.predictor}")


def task_datasets(cfg: RunConfig, registry: Registry) -> list[Any]:
    """The DataConfigs the run's task reads besides `cfg.data` (its TaskSpec's `datasets`; none for most tasks)."""
    extra = getattr(registry.get("task", cfg.task), "datasets", None)
    return list(extra(cfg, registry)) if extra is not None else []


def _plain(value: Any) -> Any:
    """Tuples to lists, recursively: what YAML and JSON give back, so a resolved config reloads to itself."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def resolve_plugin_configs(cfg: RunConfig, registry: Registry) -> RunConfig:
    """`cfg` with the complete options of every plugin it uses (its config dataclass, defaults filled in).

    What a run saves (config.yaml) and what names its record directory then includes the plugins' defaults:
    a changed default gives a new record instead of silently reusing one made with the old value.
    Idempotent; plugins the run does not use keep their mappings as they are.
    """
    used = (("simulator", cfg.sim, "sim_config"), ("renderer", cfg.renderer, "renderer_config"), ("video_predictor", cfg.predictor, "video_config"))
    changes: dict[str, dict[str, dict[str, Any]]] = {}
    for kind, name, field_name in used:
        if not name:
            continue
        mapping = dict(getattr(cfg, field_name))
        plugin_cfg = registry.get(kind, name).make_config(mapping.get(name, {}), where=f"{field_name}.{name}")
        mapping[name] = _plain(dataclasses.asdict(plugin_cfg))
        changes[field_name] = mapping
    return dataclasses.replace(cfg, **changes) if changes else cfg


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
    ($CLODS_BENCH_DETERMINISTIC=0); return the record directory."""
    with numerics.maybe_exact():
        return _run_task(cfg, registry, console or Console(stderr=True), ensure_data)


def _run_task(cfg: RunConfig, registry: Registry, console: Console, ensure_data: Callable[[RunConfig, Registry, bool], object] | None) -> Path:
    check_plugins(cfg, registry)
    cfg = resolve_plugin_configs(cfg, registry)
    task = registry.get("task", cfg.task)
    rdir = record_dir(cfg)
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

    per_seed = {}
    data_digests = run_data_digests(cfg, registry)
    for seed in cfg.seeds:
        done = reusable_seed_result(rdir, seed, data_digests)
        if done is not None:
            console.print(f"[dim]seed {seed}: finished earlier, reusing {rdir / f'seed_{seed}'}[/dim]")
            per_seed[seed] = done
            continue
        console.print(f"[bold]{cfg.task}[/bold] seed {seed} ({rdir})")
        work = rdir / f"seed_{seed}"
        work.mkdir(parents=True, exist_ok=True)
        seed_everything(seed)
        t0, c0 = time.perf_counter(), time.process_time()
        with stage_digests.collecting() as digests:
            for digest in data_digests:
                stage_digests.record("data", digest)
            result = task.run(TaskContext(config=cfg, seed=seed, work_dir=work, registry=registry))
            stage_digests.record("score", result.metrics)
        result.extra["stage_digests"] = digests.result()
        result.timings.setdefault("seed_seconds", time.perf_counter() - t0)
        result.timings.setdefault("seed_cpu_seconds", time.process_time() - c0)  # this process's CPU time: robust to a loaded host
        per_seed[seed] = save_seed_result(rdir, seed, result, data_digests)
    aggregate(cfg, rdir, per_seed, run_timings)
    return rdir
