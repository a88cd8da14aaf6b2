"""Stage 3 (paper eq. 8): train the simulator plugin on the extracted meshes, optionally from MGN* weights.

Learned simulators get `task_config.clods.sim_overrides` laid over their `sim_config` (by default
the 8-step rollout loss). The 'finetune' variant first trains the simulator with its own config on
ground-truth meshes (MGN*: the same fit as the MGN* row's, shared through the fit cache) and starts
stage 3 from those weights (with start=simulator stage 2 predicts each frame with it, so it is trained
first). The stage-3 fit is keyed by the extraction it learns from, so the CDG
and DVC tasks and every re-run of the same row train it once.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from clods_bench.atomic import file_lock
from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.fit_cache import fit_cost_seconds, fit_work_dir, sim_fit_identity
from clods_bench.benchmark.core.interfaces import FitContext, Simulator
from clods_bench.benchmark.core.plugin_calls import plugin_call
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


@dataclass
class Pretrained:
    """The 'finetune' variant's simulator trained on ground-truth meshes (MGN*), its fit identity and statistics."""

    simulator: Simulator
    identity: dict[str, Any]  # `sim_fit_identity` of the mesh fit (its fit-cache key)
    stats: dict[str, float]  # pretrain_seconds, pretrain_cost_seconds, pretrain/<fit statistic>


def pretrain_simulator(ctx: TaskContext, pretrain_ids: Sequence[int]) -> Pretrained:
    """Train the run's simulator, with its own config, on the ground-truth meshes of `pretrain_ids` (the MGN* fit,
    shared with that row through the fit cache); stage 3 starts from it and start=simulator predicts with it."""
    from clods_bench.benchmark.core.builders import build_simulator, fit_on_meshes, split_spec
    from clods_bench.datasets.store import DatasetStore

    pre = build_simulator(ctx)
    ids, pre_stats, wall, _ = fit_on_meshes(ctx, pre, DatasetStore.open(ctx.config.data.dataset_dir()), list(pretrain_ids))
    stats = {"pretrain_seconds": wall, "pretrain_cost_seconds": fit_cost_seconds(wall, pre_stats)}
    stats.update({f"pretrain/{k}": float(v) for k, v in pre_stats.items()})
    identity = sim_fit_identity(ctx, ids, split_spec(ctx).interp_steps + 1, supervision="mesh")
    return Pretrained(pre, identity, stats)


def train_simulator(
    ctx: TaskContext,
    opts: ClodsConfig,
    meshes: Sequence[Trajectory],
    extraction_key: str,
    pretrained: Pretrained | None = None,
) -> tuple[Simulator, dict[str, float]]:
    """Fit the run's simulator on the extracted `meshes` (identified by `extraction_key`), starting from the
    `pretrained` weights when given; return it and statistics (`*_cost_seconds`: training time, cached fits at
    their recorded cost). The fit runs in a content-addressed work directory (`fit_cache`)."""
    from clods_bench.benchmark.core.builders import build_simulator

    cfg = ctx.config
    stats: dict[str, float] = {}
    s3ctx = stage3_context(ctx, opts)
    sim = build_simulator(s3ctx)
    pre_identity = None
    if pretrained is not None:
        stats.update(pretrained.stats)
        warm_start(sim, pretrained.simulator, str(cfg.sim))
        pre_identity = pretrained.identity
    frames = max((m.num_steps for m in meshes), default=0)
    identity = sim_fit_identity(
        ctx, list(range(len(meshes))), frames, sim_config=s3ctx.config.sim_config.get(str(cfg.sim), {}),
        supervision="video", extraction=extraction_key, pretrain=pre_identity,
    )  # fmt: skip
    work = fit_work_dir(ctx, identity)
    t0 = time.perf_counter()
    with file_lock(work / "fit.lock"), plugin_call("simulator", str(cfg.sim), "fit", sim):
        fit_stats = sim.fit(list(meshes), FitContext(work_dir=work, seed=ctx.seed, progress=cfg.progress)) or {}
    stage_digests.record("fit", sim)
    wall = time.perf_counter() - t0
    stats["stage3_seconds"] = wall
    stats["stage3_cost_seconds"] = fit_cost_seconds(wall, fit_stats)
    stats.update({f"stage3/{k}": float(v) for k, v in fit_stats.items()})
    return sim, stats
