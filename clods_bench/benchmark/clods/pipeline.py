"""The CloDS pipeline end to end: stage 1 (renderer), stage 2 (mesh extraction), stage 3 (simulator).

Public API (the CDG and DVC tasks use it): `train_from_video(ctx, train_ids)` and `fit_stage1(...)`;
`run_pipeline` also returns the per-frame E-GT curve (extracted vs ground-truth mesh RMSE).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from clods_bench.atomic import file_lock
from clods_bench.benchmark.clods.cache import ExtractionCache
from clods_bench.benchmark.clods.config import ClodsConfig, clods_config
from clods_bench.benchmark.clods.extract import extract_trajectory, stage2_stats
from clods_bench.benchmark.clods.noise import initial_mesh
from clods_bench.benchmark.clods.predict import OneStepPredictor
from clods_bench.benchmark.clods.smooth import smooth_meshes, smoothing_tag
from clods_bench.benchmark.clods.stage1 import cache_root, extraction_seed, fit_stage1, fit_stage1_keyed
from clods_bench.benchmark.clods.stage3 import Pretrained, pretrain_simulator, train_simulator
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.cache_keys import digest
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.interfaces import Simulator
from clods_bench.benchmark.scoring.cross_topology import attach, attached_rmse
from clods_bench.benchmark.scoring.metrics import rmse_per_step
from clods_bench.datasets.obstacle_nodes import cloth_nodes
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError

__all__ = ["Extraction", "PipelineResult", "error_accumulation", "extract_meshes", "extraction_identity", "fit_stage1", "pretrain_ids", "run_pipeline", "train_from_video", "video_train_ids"]


@dataclass
class PipelineResult:
    """A trained simulator, flat statistics and the mean E-GT curve (one value per extracted frame)."""

    simulator: Simulator
    stats: dict[str, float]
    egt_curve: list[float] = field(default_factory=list)
    egt_per_trajectory: dict[str, float] = field(default_factory=dict)
    meshes: list[Trajectory] = field(default_factory=list)  # the extracted meshes stage 3 learned from
    truth: list[Trajectory] = field(default_factory=list)  # the true meshes of the same frames (none without meshes)
    renderers: list[Any] = field(default_factory=list)  # per extracted video, the stage-1 renderer fitted on its frame 0


def video_train_ids(ctx: TaskContext) -> list[int]:
    """Trajectories whose videos train the row: CloDS** all training ones, CloDS* the first half, CloDS the second half."""
    from clods_bench.benchmark.core.builders import split_spec

    cfg, opts, splits = ctx.config, clods_config(ctx.config), split_spec(ctx)
    if opts.variant == "finetune":
        if cfg.train_subset != "all":
            raise ClodsError("the finetune variant trains on first-half meshes and second-half videos; train_subset does not apply",
                             where="train_subset", hint="leave it at 'all' with task_config.clods.variant=finetune")  # fmt: skip
        return list(splits.second_half)
    return list(splits.train if cfg.train_subset == "all" else splits.first_half)


def pretrain_ids(ctx: TaskContext, opts: ClodsConfig) -> list[int]:
    """Trajectories whose ground-truth meshes pretrain the simulator: the first half for variant=finetune, else none."""
    from clods_bench.benchmark.core.builders import split_spec

    return list(split_spec(ctx).first_half) if opts.variant == "finetune" else []


def _views(ctx: TaskContext, opts: ClodsConfig) -> list[int]:
    """Training camera indices used by stages 1-2: all, or the first `num_cameras` of them (neighbours on the rig:
    two cameras spread to opposite sides would see the cloth along one line, with no baseline to triangulate)."""
    from clods_bench.benchmark.core.builders import split_spec

    views = list(split_spec(ctx).train_views)
    if opts.num_cameras is not None:
        if opts.num_cameras > len(views):
            raise ClodsError(f"{opts.num_cameras} cameras asked, the rig has {len(views)} training cameras", where="task_config.clods.num_cameras")
        views = views[: opts.num_cameras]
    return views


@dataclass
class Extraction:
    """Stages 1-2 of one row: extracted meshes (with the true ones), statistics, per-frame E-GT and the cache key."""

    meshes: list[Trajectory]  # extracted, frames 0..interp_steps, one per training video
    truth: list[Trajectory]  # the ground truth over the same frames; empty for a dataset without meshes
    stats: dict[str, float]
    egt: np.ndarray | None  # (B, frames) RMSE of extracted vs true mesh per frame (E-GT, the appendix figure); None without truth
    key: str  # extraction cache key (stage 3 is keyed by it)
    renderers: list[Any] = field(default_factory=list)  # per video, the stage-1 renderer its meshes were tracked with


def extraction_identity(
    stage1_key: str, opts: ClodsConfig, data: dict[str, Any], frames: int, views: Sequence[int], predictor: dict[str, Any] | None = None
) -> dict[str, Any]:
    """What decides a row's extracted meshes (its cache key is the digest): the stage-1 fit, the stage-2 options, the
    data, frames and views, and with start=simulator the pretrained fit's identity (`predictor`, required then)."""
    identity: dict[str, Any] = {"stage1": stage1_key, "clods": opts.extraction_identity(), "data": data, "frames": frames, "views": list(views)}
    if opts.start == "simulator":  # a different predictor gives different meshes; the other starts keep their key
        if predictor is None:
            raise ClodsError("start=simulator needs the pretrained fit's identity in the cache key", where="task_config.clods.start")
        identity["predictor"] = predictor
    return identity


def extract_meshes(ctx: TaskContext, train_ids: Sequence[int], pretrained: Pretrained | None = None, frames: int | None = None) -> Extraction:
    """Stages 1-2 on the videos of `train_ids` (frames 0..interp_steps, or 0..frames-1; training cameras only), cached and
    resumable.

    With start=simulator each frame starts from `pretrained`'s one-step prediction (pretrained here when not given);
    the cache key then includes that fit's identity, and the statistics its pretraining cost."""
    from clods_bench.benchmark.core.builders import split_spec

    cfg, opts, splits = ctx.config, clods_config(ctx.config), split_spec(ctx)
    if not cfg.data.render_frames:
        raise ClodsError("the CloDS pipeline learns from video and needs rendered frames", where="data.render_frames", hint="set it to true")
    if not train_ids:
        raise ClodsError("no training videos", where="clods pipeline")
    store = DatasetStore.open(cfg.data.dataset_dir())
    views = _views(ctx, opts)
    cams = [store.cameras()[v] for v in views]
    frames = splits.interp_steps + 1 if frames is None else int(frames)
    if not 2 <= frames <= splits.num_steps:
        raise ClodsError(f"stage 2 needs 2..{splits.num_steps} frames, asked for {frames}", where="clods pipeline")
    seed = extraction_seed(ctx, opts)
    gts = [store.load_trajectory(i).slice(0, frames) for i in train_ids] if store.has_meshes else []
    videos = [store.frames(i).select(slice(0, frames), views) for i in train_ids]  # lazy: read frame by frame as fitted
    if opts.initial_mesh == "reconstructed":  # stage 0 per video: its own topology, stage 1 per video
        from clods_bench.benchmark.clods.reconstructed import extract_reconstructed

        identity = extraction_identity("per-video", opts, cfg.data.identity(), frames, views)
        dt_meta = [(g.dt, g.meta) for g in gts] if gts else [(store.dt(i), store.meta(i)) for i in train_ids]
        meshes, stats, egt, key, renderers = extract_reconstructed(ctx, opts, train_ids, gts, videos, cams, identity, seed, dt_meta)
        stage_digests.record("extraction", [m.world_pos for m in meshes])
        return Extraction(meshes, gts, stats, egt, key, renderers)
    if not gts:
        raise ClodsError(f"the dataset has no meshes (imported from video), and initial_mesh={opts.initial_mesh} starts stage 2 from "
                         "the true frame-0 mesh", where="task_config.clods.initial_mesh",
                         hint="set task_config.clods.initial_mesh=reconstructed: stage 0 builds the mesh from the frame-0 images")  # fmt: skip
    initial = np.stack([initial_mesh(g.world_pos[0], opts, seed, i) for g, i in zip(gts, train_ids)])

    renderer, stats, stage1_key = fit_stage1_keyed(ctx, initial, gts[0].cells, gts[0].mesh_pos, np.stack([v[0] for v in videos]), cams)
    use_sim = opts.start == "simulator"
    if use_sim and pretrained is None:
        pretrained = pretrain_simulator(ctx, pretrain_ids(ctx, opts))
    if use_sim and pretrained is not None:
        stats.update(pretrained.stats)
    identity = extraction_identity(stage1_key, opts, cfg.data.identity(), frames, views, pretrained.identity if use_sim and pretrained else None)
    predictors = [OneStepPredictor(pretrained.simulator, g.cells, g.mesh_pos, g.node_type, g.dt, str(cfg.sim)) if use_sim and pretrained else None for g in gts]
    cache = ExtractionCache(cache_root(ctx, opts), digest(identity), identity)

    t0, extracted, cached = time.perf_counter(), [], 0
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TextColumn("{task.fields[info]}"))
    with Progress(*columns, transient=True, disable=not cfg.progress) as bar:
        for g, video, i, init, predict in zip(gts, videos, train_ids, initial, predictors):
            with file_lock(cache.path(i).with_suffix(".lock")):  # a parallel job extracting it: wait, then read it
                cached += cache.load(i) is not None
                extracted.append(extract_trajectory(renderer, cams, video, init, g.cells, g.node_type, opts, cache, i, bar, predict))
    stats["stage2_wall_seconds"] = time.perf_counter() - t0
    stage_digests.record("extraction", [e.world_pos for e in extracted])

    egt = np.stack([rmse_per_step(e.world_pos, g.world_pos, cloth_nodes(g.node_type)) for e, g in zip(extracted, gts)])  # (B, frames)
    stats.update(stage2_stats(extracted, egt, cached))
    meshes = [
        Trajectory(g.cells, g.mesh_pos, g.node_type, e.world_pos.astype(np.float32), g.dt, {**g.meta, "source": "clods stage 2", "cache": cache.key})
        for g, e in zip(gts, extracted)
    ]
    return Extraction(meshes, gts, stats, egt, cache.key, [renderer] * len(meshes))


def run_pipeline(ctx: TaskContext, train_ids: Sequence[int]) -> PipelineResult:
    """Stages 1-3 on the videos of `train_ids` (frames 0..interp_steps, training cameras only)."""
    opts = clods_config(ctx.config)
    ids = pretrain_ids(ctx, opts)
    pretrained = pretrain_simulator(ctx, ids) if opts.start == "simulator" else None  # stage 2 predicts with it
    ext = extract_meshes(ctx, train_ids, pretrained)
    stats = dict(ext.stats)
    if ids and pretrained is None:  # the other starts pretrain after stage 2, as they always have
        pretrained = pretrain_simulator(ctx, ids)
    meshes = smooth_meshes(ext.meshes, opts.smooth_window, opts.smooth_order)
    if opts.smooth_window:  # E-GT of what stage 3 learns from (egt_rmse stays stage 2's own); not with reconstructed meshes
        same = [(m, g) for m, g in zip(meshes, ext.truth) if m.world_pos.shape == g.world_pos.shape]
        if same:
            stats["egt_smoothed_rmse"] = float(np.mean([rmse_per_step(m.world_pos, g.world_pos, cloth_nodes(g.node_type))[1:].mean() for m, g in same]))
    sim, sim_stats = train_simulator(ctx, opts, meshes, ext.key + smoothing_tag(opts.smooth_window, opts.smooth_order), pretrained)
    stats.update(sim_stats)
    parts = ("stage1_cost_seconds", "stage2_seconds", "pretrain_cost_seconds", "stage3_cost_seconds")
    stats["cost_seconds"] = float(sum(v for v in (stats.get(k, 0.0) for k in parts) if math.isfinite(v)))  # a cache without its cost counts 0
    if ext.egt is None:  # a dataset without meshes: no E-GT
        return PipelineResult(sim, stats, [], {}, meshes, ext.truth, ext.renderers)
    per_traj = {str(i): float(c[1:].mean()) for i, c in zip(train_ids, ext.egt)}
    return PipelineResult(sim, stats, ext.egt.mean(axis=0).tolist(), per_traj, meshes, ext.truth, ext.renderers)


def error_accumulation(sim: Simulator, meshes: Sequence[Trajectory], truth: Sequence[Trajectory]) -> dict[str, list[float]]:
    """The paper's appendix figure on error accumulation, on the training videos: per frame, the RMSE of the extracted
    meshes against the truth (E-GT), of the simulator's rollout from the true first two frames against the truth
    (P-GT) and against the extracted meshes (P-E), each averaged over the trajectories."""
    from clods_bench.benchmark.core.interfaces import RolloutInput, rollout_checked

    curves: dict[str, list[np.ndarray]] = {"E-GT": [], "P-GT": [], "P-E": []}
    for ext, gt in zip(meshes, truth):
        inp = RolloutInput.from_trajectory(gt, gt.num_steps)
        pred = rollout_checked(sim, inp, "clods")
        nodes = cloth_nodes(gt.node_type)
        curves["P-GT"].append(rmse_per_step(pred, gt.world_pos, nodes))
        if ext.world_pos.shape == gt.world_pos.shape:
            curves["E-GT"].append(rmse_per_step(ext.world_pos, gt.world_pos, nodes))
            curves["P-E"].append(rmse_per_step(pred, ext.world_pos, nodes))
        else:  # a reconstructed mesh: the true nodes attached to it at frame 0 and carried by it
            att = attach(np.asarray(gt.world_pos[0], np.float64), np.asarray(ext.world_pos[0], np.float64), ext.cells)
            curves["E-GT"].append(attached_rmse(ext.world_pos, ext.cells, att, gt.world_pos))
            curves["P-E"].append(attached_rmse(ext.world_pos, ext.cells, att, pred))
    return {k: np.mean(np.stack(v), axis=0).tolist() for k, v in curves.items() if v}


def train_from_video(ctx: TaskContext, train_ids: Sequence[int]) -> tuple[Simulator, dict[str, float]]:
    """Stages 1-3 on the videos of `train_ids`; returns the trained simulator and timings/metrics
    (stage1_seconds, stage2_ms_per_frame, stage2_seconds, egt_rmse, stage3_seconds, ...)."""
    result = run_pipeline(ctx, train_ids)
    return result.simulator, result.stats

