"""The datasets a run reads: opened when complete, else generated (their trajectories in parallel through an
executor, if given). `data.path` names an existing dataset, which is never generated."""

from __future__ import annotations

from typing import Any

from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.plugin_calls import stage
from clods_bench.benchmark.core.registry import Registry
from clods_bench.datasets.generate import generate, open_existing, scene_fingerprint
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError


def ensure_dataset(cfg: RunConfig, registry: Registry, progress: bool = True, executor: Any = None) -> Any:
    """Open the run's dataset, generating whatever part of it is missing (in parallel through `executor`, if given)."""
    if cfg.data.path:
        return open_existing(cfg.data.path, cfg.data.num_train + cfg.data.num_test)
    scene = registry.get("scene", cfg.data.scene)
    with stage(f"generating dataset {cfg.data.dataset_dir()}"):
        return generate(cfg.data, scene, progress=progress, executor=executor)


def ensure_complete_dataset(cfg: RunConfig, registry: Registry, progress: bool = True, executor: Any = None) -> Any:
    """The run's dataset: opened as is when every trajectory is complete (the dataset dir is a hash of its settings), else
    generated (its trajectories in parallel through `executor`, if given)."""
    root = cfg.data.dataset_dir()
    if root.is_dir():
        try:
            store = DatasetStore.open(root)
        except ClodsError:
            store = None
        if (
            store is not None
            and set(range(cfg.data.num_train + cfg.data.num_test)) <= store.completed_indices()
            and _same_scene(store, cfg, registry)
        ):
            return store
    return ensure_dataset(cfg, registry, progress, executor=executor)


def _same_scene(store: Any, cfg: RunConfig, registry: Registry) -> bool:
    """Whether a generated dataset was made from the scene definition the registry holds now (an edited scene, e.g.
    a changed obstacle or solver parameter, must not reuse it: `generate` then reports the difference)."""
    made_with = store.config.get("scene_spec") if isinstance(store.config, dict) else None
    if made_with is None or cfg.data.path:
        return True  # imported data, or a store from before scene fingerprints
    try:
        return made_with == scene_fingerprint(registry.get("scene", cfg.data.scene))
    except ClodsError:
        return True  # an unknown scene is reported by the run itself
