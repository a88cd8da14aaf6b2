"""Content-addressed work directories for simulator and video-predictor fits, so equal fits are trained once.

A simulator's `fit` gets a work directory; learned simulators keep a resumable checkpoint there
and, finding a finished one, load it instead of training. Keying that directory by everything that
decides the trained model (simulator, its resolved config, the data, the training trajectories and
frames, the seed, and for the CloDS pipeline the extraction it learns from) turns the checkpoint
into a cache: the CDG row MGN, the stability task's MGN, the DVC task's simulator, CloDS' MGN*
pre-training and a re-run all share one training; likewise a video predictor trained on the same videos by
the DVC task (Table 4) and the multi-trajectory task. Timings stay honest: `fit_cost_seconds` counts a
cached model at the training time recorded with it, not at the near-zero time of loading it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping

from clods_bench.atomic import write_json
from clods_bench.benchmark.core.cache_keys import digest
from clods_bench.benchmark.core.descriptors import TaskContext

FIT_CACHE_DIR = "fit_cache"
IDENTITY_FILE = "identity.json"


def fit_identity(ctx: TaskContext, sim: str, sim_config: Mapping[str, Any], train_ids: list[int], frames: int, **extra: Any) -> dict[str, Any]:
    """What decides a fit: simulator, its config mapping, data identity, training trajectories and frames, seed, extras."""
    return {
        "sim": sim,
        "sim_config": dict(sim_config),
        "data": ctx.config.data.identity(),
        "train_ids": [int(i) for i in train_ids],
        "frames": int(frames),
        "seed": int(ctx.seed),
        **extra,
    }


def sim_fit_identity(ctx: TaskContext, train_ids: list[int], frames: int, sim_config: Mapping[str, Any] | None = None, **extra: Any) -> dict[str, Any]:
    """`fit_identity` of the run's simulator, its config resolved through the plugin's config class (defaults
    included, so a changed default is a different fit); `sim_config` replaces the run's mapping when given."""
    cfg = ctx.config
    spec = ctx.registry.get("simulator", cfg.sim)
    mapping = dict(cfg.sim_config.get(cfg.sim, {}) if sim_config is None else sim_config)
    resolved = spec.make_config(mapping, where=f"sim_config.{cfg.sim}")
    values = dataclasses.asdict(resolved) if dataclasses.is_dataclass(resolved) else mapping
    values.pop("device", None)  # where a simulator trains (CPU or a GPU) does not decide the model: a fit serves both
    if "num_threads" in values:  # nor its thread count (the checkpoint's digest ignores it too): one thread's fit serves all
        values["num_threads"] = None
    return fit_identity(ctx, str(cfg.sim), values, train_ids, frames, **extra)


def predictor_fit_identity(ctx: TaskContext, train_ids: list[int], views: list[int], frames: int) -> dict[str, Any]:
    """What decides a video predictor's fit: the predictor, its config resolved through its class (defaults
    included), the data identity, the training trajectories, their views and frames (0..frames-1), the seed."""
    cfg = ctx.config
    spec = ctx.registry.get("video_predictor", cfg.predictor)
    mapping = dict(cfg.video_config.get(cfg.predictor, {}))
    resolved = spec.make_config(mapping, where=f"video_config.{cfg.predictor}")
    values = dataclasses.asdict(resolved) if dataclasses.is_dataclass(resolved) else mapping
    values.pop("device", None)  # as for simulators: a fit on the CPU or a GPU serves both
    return {
        "predictor": str(cfg.predictor),
        "predictor_config": values,
        "data": ctx.config.data.identity(),
        "train_ids": [int(i) for i in train_ids],
        "views": [int(v) for v in views],
        "frames": int(frames),
        "seed": int(ctx.seed),
    }


def fit_work_dir(ctx: TaskContext, identity: Mapping[str, Any]) -> Path:
    """`<runs_dir>/fit_cache/<sim or predictor>-<digest>`, created, with the identity written beside the checkpoint."""
    key = digest(dict(identity))
    name = identity.get("sim") or identity.get("predictor") or "sim"
    path = Path(ctx.config.runs_dir) / FIT_CACHE_DIR / f"{name}-{key}"
    path.mkdir(parents=True, exist_ok=True)
    if not (path / IDENTITY_FILE).exists():
        write_json(path / IDENTITY_FILE, dict(identity))
    return path


def fit_cost_seconds(wall_seconds: float, stats: Mapping[str, Any] | None) -> float:
    """Training cost of a fit: the simulator's own `train_seconds` when it reports one (it includes steps
    done in earlier, cached or interrupted, calls), never less than the wall time of this call."""
    recorded = (stats or {}).get("train_seconds")
    try:
        return max(float(wall_seconds), float(recorded)) if recorded is not None else float(wall_seconds)
    except (TypeError, ValueError):
        return float(wall_seconds)
