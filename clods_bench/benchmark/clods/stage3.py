"""Stage 3 (paper eq. 8): train the simulator plugin on the extracted meshes, optionally from MGN* weights.

Learned simulators get `task_config.clods.sim_overrides` laid over their `sim_config` (by default
the 8-step rollout loss). The 'finetune' variant first trains the simulator with its own config on
ground-truth meshes (MGN*) and starts stage 3 from those weights.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Sequence
from typing import Any

from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.descriptors import TaskContext
from clods_bench.benchmark.interfaces import FitContext, Simulator
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError


def stage3_context(ctx: TaskContext, opts: ClodsConfig) -> TaskContext:
    """`ctx` whose simulator config carries the stage-3 overrides (learned simulators only)."""
    cfg = ctx.config
    if not ctx.registry.get("simulator", cfg.sim).learned or not opts.sim_overrides:
        return ctx
    merged = {**cfg.sim_config.get(cfg.sim, {}), **opts.sim_overrides}
    return dataclasses.replace(ctx, config=dataclasses.replace(cfg, sim_config={**cfg.sim_config, cfg.sim: merged}))


def warm_start(sim: Any, pretrained: Any, name: str) -> None:
    """Make `sim` start training from `pretrained`'s weights: its `warm_start(other)` if it has one, else a
    learned simulator's `build_model` is made to return a copy of the trained model."""
    if hasattr(sim, "warm_start"):
        sim.warm_start(pretrained)
        return
    model = getattr(pretrained, "model", None)
    if hasattr(sim, "build_model") and model is not None:
        sim.build_model = lambda seed: copy.deepcopy(model).train()
        return
    raise ClodsError(
        "cannot fine-tune this simulator (it has neither warm_start(other) nor a learned model)",
        where=f"simulator '{name}'", hint="use task_config.clods.variant=scratch",
    )  # fmt: skip


def train_simulator(
    ctx: TaskContext, opts: ClodsConfig, meshes: Sequence[Trajectory], pretrain: Sequence[Trajectory] | None = None
) -> tuple[Simulator, dict[str, float]]:
    """Fit the run's simulator on `meshes` (after pre-training on `pretrain` when given); return it and statistics."""
    from clods_bench.benchmark.tasks.cdg import build_simulator

    cfg = ctx.config
    stats: dict[str, float] = {}
    sim = build_simulator(stage3_context(ctx, opts))
    if pretrain:
        pre = build_simulator(ctx)
        t0 = time.perf_counter()
        pre_stats = pre.fit(list(pretrain), FitContext(work_dir=ctx.work_dir / "pretrain", seed=ctx.seed, progress=cfg.progress)) or {}
        stats["pretrain_seconds"] = time.perf_counter() - t0
        stats.update({f"pretrain/{k}": float(v) for k, v in pre_stats.items()})
        warm_start(sim, pre, str(cfg.sim))
    t0 = time.perf_counter()
    fit_stats = sim.fit(list(meshes), FitContext(work_dir=ctx.work_dir / "stage3", seed=ctx.seed, progress=cfg.progress)) or {}
    stats["stage3_seconds"] = time.perf_counter() - t0
    stats.update({f"stage3/{k}": float(v) for k, v in fit_stats.items()})
    return sim, stats
