"""Where independent (run, seed) jobs execute: in this process (default) or as Ray tasks.

A job is a resolved `RunConfig` (as a plain dict, so it pickles the same everywhere) and one
seed. `run_seed_job` runs it through the ordinary runner, which writes `seed_<k>/result.json`
into the run's record directory; afterwards the driver aggregates every run locally (all seeds
are then resumed from disk), so both executors produce the same records and the same numbers.
Paths in the configs are made absolute before dispatch: Ray workers may start in another directory.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Literal, Sequence

from rich.console import Console
from rich.progress import Progress

from clods_bench.benchmark.config import RunConfig, dataclass_from_dict
from clods_bench.benchmark.records import load_seed_result, record_dir
from clods_bench.errors import ClodsError

ExecutorName = Literal["local", "ray"]
EXECUTORS: tuple[str, ...] = ("local", "ray")


@dataclass(frozen=True)
class SeedJob:
    """One seed of one run: the resolved config (a dict) and the seed."""

    config: dict[str, Any]
    seed: int
    name: str


def ensure_complete_dataset(cfg: RunConfig, registry: Any, progress: bool = True) -> Any:
    """The run's dataset: opened as is when every trajectory is complete (the dataset dir is a hash of its settings), else generated."""
    from clods_bench.datasets.generate import ensure_dataset
    from clods_bench.datasets.store import DatasetStore

    root = cfg.data.dataset_dir()
    if root.is_dir():
        try:
            store = DatasetStore.open(root)
        except ClodsError:
            store = None
        if store is not None and set(range(cfg.data.num_train + cfg.data.num_test)) <= store.completed_indices():
            return store
    return ensure_dataset(cfg, registry, progress)


def run_seed_job(job: SeedJob) -> dict[str, Any]:
    """Run one seed of one run (in whatever process executes it); return {'name', 'seed', 'record_dir', 'wall_seconds'}."""
    from clods_bench.benchmark.registry import default_registry
    from clods_bench.benchmark.runner import run_task

    cfg = dataclass_from_dict(RunConfig, dict(job.config), where=f"job {job.name}")
    cfg.seeds = [int(job.seed)]
    t0 = time.perf_counter()
    rdir = run_task(cfg, default_registry(), Console(stderr=True, quiet=True), ensure_data=ensure_complete_dataset)
    return {"name": job.name, "seed": int(job.seed), "record_dir": str(rdir), "wall_seconds": time.perf_counter() - t0}


class LocalExecutor:
    """Runs jobs one after another in this process."""

    name = "local"

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], describe: Callable[[Any], str] = str, progress: bool = True) -> list[Any]:
        """`[fn(item) for item in items]`, with a progress bar."""
        out = []
        with Progress(disable=not progress) as bar:
            task = bar.add_task("jobs (local)", total=len(items))
            for item in items:
                bar.update(task, description=f"job {describe(item)}")
                out.append(fn(item))
                bar.advance(task)
        return out


class RayExecutor:
    """Runs jobs as Ray tasks: on an existing cluster (`address`), the one this process joined, or a local one it starts.

    Each task asks for `cpus_per_task` CPUs and, when the cluster has GPUs, one GPU.
    """

    name = "ray"

    def __init__(self, address: str | None = None, cpus_per_task: float = 1.0, num_cpus: int | None = None) -> None:
        self.address = address
        self.cpus_per_task = cpus_per_task
        self.num_cpus = num_cpus

    def _ray(self) -> Any:
        try:
            import ray
        except ImportError:
            raise ClodsError(
                "the Ray executor needs the 'ray' package", where="--executor ray", hint="pip install 'clods-bench[ray]' (or: pip install ray)"
            ) from None
        return ray

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], describe: Callable[[Any], str] = str, progress: bool = True) -> list[Any]:
        """Submit `fn(item)` for every item as a Ray task and return the results in item order."""
        ray = self._ray()
        started = False
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"address": self.address} if self.address else {"num_cpus": self.num_cpus}
            ray.init(log_to_driver=False, include_dashboard=False, **kwargs)
            started = True
        try:
            gpus = 1 if ray.cluster_resources().get("GPU", 0) >= 1 else 0
            remote = ray.remote(num_cpus=self.cpus_per_task, num_gpus=gpus, max_retries=0)(fn)
            refs = [remote.remote(item) for item in items]
            index = {ref: i for i, ref in enumerate(refs)}
            out: list[Any] = [None] * len(refs)
            pending = list(refs)
            with Progress(disable=not progress) as bar:
                task = bar.add_task(f"jobs (ray, {gpus} GPU/task)", total=len(refs))
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    for ref in done:
                        try:
                            out[index[ref]] = ray.get(ref)
                        except ray.exceptions.RayTaskError as exc:
                            cause = exc.as_instanceof_cause()
                            if isinstance(cause, ClodsError):
                                raise ClodsError(cause.what, where=cause.where, hint=cause.hint) from None
                            raise ClodsError(f"Ray task failed: {exc}", where=f"job {describe(items[index[ref]])}") from None
                        bar.advance(task)
            return out
        finally:
            if started:
                ray.shutdown()


def make_executor(name: str, address: str | None = None) -> LocalExecutor | RayExecutor:
    """The executor called `name` ('local' or 'ray')."""
    if name == "local":
        return LocalExecutor()
    if name == "ray":
        return RayExecutor(address=address)
    raise ClodsError(f"unknown executor '{name}'", where="--executor", hint=f"one of {', '.join(EXECUTORS)}")


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
) -> list[dict[str, Any]]:
    """Run every (name, config) over its seeds through `executor`; aggregate each run here; return one summary per run.

    Datasets are generated first, here, once per distinct data config (workers must not race on them).
    Seeds finished earlier are skipped. Summary: name, record_dir, wall_seconds (this call's jobs), seeds_run.
    """
    from clods_bench.benchmark.runner import check_plugins, run_task

    configs = [(name, absolute_paths(cfg)) for name, cfg in configs]
    for name, cfg in configs:
        check_plugins(cfg, registry)
    seen: set[Path] = set()
    for name, cfg in configs:
        ddir = cfg.data.dataset_dir()
        if ddir not in seen:
            seen.add(ddir)
            console.print(f"[dim]dataset {ddir}[/dim]")
            ensure_complete_dataset(cfg, registry, cfg.progress)

    jobs = []
    for name, cfg in configs:
        rdir = record_dir(cfg)
        for seed in cfg.seeds:
            if load_seed_result(rdir, seed) is None:
                worker_cfg = cfg.to_dict()
                worker_cfg["progress"] = False if executor.name == "ray" else cfg.progress
                jobs.append(SeedJob(config=worker_cfg, seed=int(seed), name=name))
    console.print(f"{len(jobs)} seed job(s) to run on the {executor.name} executor ({sum(len(c.seeds) for _, c in configs) - len(jobs)} finished earlier)")
    results = executor.map(run_seed_job, jobs, describe=lambda j: f"{j.name} seed {j.seed}", progress=any(c.progress for _, c in configs))

    summaries = []
    for name, cfg in configs:
        mine = [r for r in results if r["name"] == name]
        rdir = run_task(cfg, registry, Console(stderr=True, quiet=True), ensure_data=ensure_complete_dataset)  # every seed is on disk now: this only aggregates
        summaries.append({"name": name, "record_dir": str(rdir), "wall_seconds": sum(r["wall_seconds"] for r in mine), "seeds_run": sorted(r["seed"] for r in mine)})
    return summaries
