"""What every task and the CloDS pipeline build from a run's config: the splits, the simulator and renderer plugins,
a simulator fitted on meshes, and a renderer's output checked as images. One module below the tasks, so the
pipeline (clods/) and the tasks share them without importing one another."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from clods_bench.atomic import file_lock
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.descriptors import BuildContext, TaskContext
from clods_bench.benchmark.core.fit_cache import fit_work_dir, sim_fit_identity
from clods_bench.benchmark.core.interfaces import FitContext, Renderer, Simulator
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.datasets.data_config import DataConfig
from clods_bench.datasets.splits import SplitSpec
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError


def split_spec(ctx: TaskContext) -> SplitSpec:
    """The paper's splits scaled to this run's data config."""
    return data_splits(ctx.config.data)


def data_splits(d: DataConfig) -> SplitSpec:
    """The paper's splits scaled to a data config (the run's, or another dataset it is scored on)."""
    return SplitSpec(
        num_train=d.num_train,
        num_test=d.num_test,
        num_steps=d.num_steps,
        interp_steps=d.interp_steps,
        num_views_train=d.num_cameras - d.num_views_test,
        num_views_test=d.num_views_test,
    )


def build_simulator(ctx: TaskContext, scene_name: str | None = None) -> Simulator:
    """Build the configured simulator plugin for this seed, for the run's scene or for `scene_name` (a simulator with
    nothing to learn, e.g. the physics solver, rolled out on another scene than `data.scene` must know that scene)."""
    cfg = ctx.config
    spec = ctx.registry.get("simulator", cfg.sim)
    sim_cfg = spec.make_config(cfg.sim_config.get(cfg.sim, {}), where=f"sim_config.{cfg.sim}")
    scene = ctx.registry.get("scene", scene_name or cfg.data.scene)
    with plugin_call("simulator", str(cfg.sim), "build", spec.build):
        sim = spec.build(sim_cfg, BuildContext(scene=scene, seed=ctx.seed, work_dir=ctx.work_dir, progress=cfg.progress))
    if not isinstance(sim, Simulator):
        raise ClodsError("plugin did not return a Simulator (needs fit() and rollout())", where=f"simulator '{cfg.sim}'")
    return sim


def fit_on_meshes(
    ctx: TaskContext, sim: Simulator, store: DatasetStore, train_ids: list[int] | None = None, snapshot_every: int = 0,
    identity_extra: dict | None = None,
) -> tuple[list[int], dict, float, Path]:  # fmt: skip
    """Fit `sim` on the interpolation frames of the training meshes (all, or the first half for `train_subset`
    first_half) in its content-addressed work directory; return (train_ids, fit statistics, wall seconds, work dir).

    `snapshot_every` is passed on to the fit (`FitContext`); `identity_extra` keys a separate work directory."""
    cfg, splits = ctx.config, split_spec(ctx)
    if train_ids is None:
        train_ids = list(splits.train if cfg.train_subset == "all" else splits.first_half)
    frames = splits.interp_steps + 1
    train = [store.load_trajectory(i).slice(0, frames) for i in train_ids]
    work = fit_work_dir(ctx, sim_fit_identity(ctx, train_ids, frames, supervision="mesh", **(identity_extra or {})))
    t0 = time.perf_counter()
    with file_lock(work / "fit.lock"):  # a parallel job training the same fit: wait, then resume its finished checkpoint
        fit_ctx = FitContext(work_dir=work, seed=ctx.seed, progress=cfg.progress, snapshot_every=int(snapshot_every))
        with plugin_call("simulator", str(cfg.sim), "fit", sim):
            stats = sim.fit(train, fit_ctx) or {}
    stage_digests.record("fit", sim)
    return list(train_ids), dict(stats), time.perf_counter() - t0, work


def build_renderer(ctx: TaskContext) -> Renderer:
    """Build the configured renderer plugin for this seed (a fresh object per fit)."""
    cfg = ctx.config
    spec = ctx.registry.get("renderer", cfg.renderer)
    rcfg = spec.make_config(cfg.renderer_config.get(cfg.renderer, {}), where=f"renderer_config.{cfg.renderer}")
    scene = ctx.registry.get("scene", cfg.data.scene)
    with plugin_call("renderer", str(cfg.renderer), "build", spec.build):
        renderer = spec.build(rcfg, BuildContext(scene=scene, seed=ctx.seed, work_dir=ctx.work_dir, progress=cfg.progress))
    if not isinstance(renderer, Renderer):
        raise ClodsError("plugin did not return a Renderer (needs fit() and render())", where=f"renderer '{cfg.renderer}'")
    return renderer


def as_images(out: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    """A renderer's output as float32 (N,H,W,3) numpy in [0,1]; ClodsError on a wrong shape or NaN."""
    arr = out.detach().cpu().numpy() if isinstance(out, torch.Tensor) else np.asarray(out)
    if arr.shape != shape:
        raise ClodsError(f"render returned shape {arr.shape}, expected {shape}", where=where)
    if not np.isfinite(arr).all():
        raise ClodsError("render returned NaN/Inf pixels", where=where)
    images = np.clip(arr.astype(np.float32), 0.0, 1.0)
    stage_digests.record("rollout", images)
    return images
