"""What the video-prediction tasks (DVC, Table 4, and its multi-trajectory table) share: building and fitting a
predictor, the simulator + renderer row's simulator training and stage-1 renderer fit, the rollouts on each video's
own reconstructed mesh of a row from video alone, per-image scores, and the truth-above-prediction videos. Below the
tasks, so neither task imports the other."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from clods_bench.atomic import atomic_path, file_lock
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.builders import build_renderer, build_simulator, fit_on_meshes, split_spec
from clods_bench.benchmark.core.descriptors import BuildContext, TaskContext
from clods_bench.benchmark.core.fit_cache import fit_cost_seconds, fit_work_dir, predictor_fit_identity
from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput, VideoPredictor
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.benchmark.outputs.mesh_pictures import save_mesh_sample
from clods_bench.benchmark.scoring.image_metrics import LpipsMetric, image_scores
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import NORMAL, Trajectory
from clods_bench.errors import ClodsError

if TYPE_CHECKING:
    from clods_bench.datasets.cameras import Camera

METRICS = ("psnr", "ssim", "lpips", "rmse")


def build_predictor(ctx: TaskContext) -> VideoPredictor:
    """Build the configured video-predictor plugin for this seed."""
    cfg = ctx.config
    spec = ctx.registry.get("video_predictor", cfg.predictor)
    pcfg = spec.make_config(cfg.video_config.get(cfg.predictor, {}), where=f"video_config.{cfg.predictor}")
    scene = ctx.registry.get("scene", cfg.data.scene)
    with plugin_call("video predictor", str(cfg.predictor), "build", spec.build):
        pred = spec.build(pcfg, BuildContext(scene=scene, seed=ctx.seed, work_dir=ctx.work_dir, progress=cfg.progress))
    if not isinstance(pred, VideoPredictor):
        raise ClodsError("plugin did not return a VideoPredictor (needs fit() and predict())", where=f"video predictor '{cfg.predictor}'")
    return pred


def fit_predictor(
    ctx: TaskContext, pred: VideoPredictor, videos: list[np.ndarray], train_ids: list[int], views: list[int], frames: int
) -> tuple[dict[str, float], dict[str, float]]:
    """Fit `pred` on `videos` (frames 0..frames-1 of the `views` of `train_ids`); return (fit statistics, timings).

    A learned predictor trains in a content-addressed work directory (`fit_work_dir`), so the DVC rows and the
    multi-trajectory rows that train on the same videos share one training; `fit_seconds` counts a fit found
    finished at its recorded training time, `fit_wall_seconds` is this call's.
    """
    cfg = ctx.config
    learned = ctx.registry.get("video_predictor", cfg.predictor).learned
    work = fit_work_dir(ctx, predictor_fit_identity(ctx, train_ids, views, frames)) if learned else ctx.work_dir
    t0 = time.perf_counter()
    with file_lock(Path(work) / "fit.lock"):  # a parallel job training the same fit: wait, then load its checkpoint
        with plugin_call("video predictor", str(cfg.predictor), "fit", pred):
            stats = dict(pred.fit(videos, FitContext(work_dir=work, seed=ctx.seed, progress=cfg.progress)) or {})
    stage_digests.record("fit", pred)
    wall = time.perf_counter() - t0
    return stats, {"fit_seconds": fit_cost_seconds(wall, stats), "fit_wall_seconds": wall}


def to_float(frames: np.ndarray) -> np.ndarray:
    """uint8 frames as float32 in [0, 1]."""
    return np.asarray(frames, dtype=np.float32) / 255.0


class ImageScores:
    """Per-image scores collected frame by frame: (trajectory, frame) -> dict of (views,) arrays."""

    def __init__(self, lpips: LpipsMetric | None) -> None:
        self.lpips = lpips
        self.rows: list[tuple[int, int, dict[str, np.ndarray]]] = []

    def add(self, traj: int, frame: int, pred: np.ndarray, gt: np.ndarray) -> None:
        s = image_scores(pred, gt, self.lpips)
        s["rmse"] = np.sqrt(np.mean((pred.astype(np.float64) - gt.astype(np.float64)) ** 2, axis=(1, 2, 3)))
        self.rows.append((traj, frame, s))

    def means(self, frames: set[int] | None = None, prefix: str = "") -> dict[str, float]:
        """Mean of every metric over all images (of the given frames)."""
        rows = [s for _, f, s in self.rows if frames is None or f in frames]
        return {prefix + k: float(np.mean(np.concatenate([s[k] for s in rows]))) for k in METRICS if rows and k in rows[0]}

    def curves(self, frames: Sequence[int]) -> dict[str, list[float]]:
        """Per-frame means over trajectories and views."""
        out: dict[str, list[float]] = {}
        for k in METRICS:
            per = [[float(np.mean(s[k])) for _, f, s in self.rows if f == t and k in s] for t in frames]
            if all(per):
                out[k] = [float(np.mean(p)) for p in per]
        return out


def pipeline_module() -> Any:
    """The CloDS pipeline module, or None while it is not installed."""
    try:
        from clods_bench.benchmark.clods import pipeline
    except ImportError:
        return None
    return pipeline


@dataclass(frozen=True)
class Recovered:
    """What the CloDS pipeline recovered from one training video: its meshes over frames 0..interp_steps (the video's
    own topology and handles when the initial mesh was reconstructed) and the stage-1 renderer they were tracked with."""

    mesh: Trajectory
    renderer: Any


def train_simulator(
    ctx: TaskContext, sim_training: str, train_ids: list[int] | None = None, where: str = "task_config.dvc.sim_training"
) -> tuple[Any, dict[str, float], str, dict[int, Recovered]]:
    """The simulator for the rollouts, from the training videos (CloDS stages 1-3) or the ground-truth meshes of
    `train_ids` (default: every training trajectory, or the first half with `train_subset`); with the video-trained
    one also what the pipeline recovered per training trajectory (frames 0..interp_steps)."""
    cfg = ctx.config
    splits = split_spec(ctx)
    if train_ids is None:
        train_ids = list(splits.train if cfg.train_subset == "all" else splits.first_half)
    pipeline = pipeline_module()
    have_video = pipeline is not None and hasattr(pipeline, "train_from_video")
    mode = ("video" if have_video else "mesh") if sim_training == "auto" else sim_training
    t0 = time.perf_counter()
    extracted: dict[int, Recovered] = {}
    if mode == "video":
        if not have_video:
            raise ClodsError("the CloDS pipeline (clods_bench.benchmark.clods.pipeline.train_from_video) is not available",
                             where=where, hint=f"set {where}=mesh")  # fmt: skip
        if hasattr(pipeline, "run_pipeline"):
            result = pipeline.run_pipeline(ctx, train_ids)
            sim, stats = result.simulator, result.stats
            extracted = {int(i): Recovered(m, r) for i, m, r in zip(train_ids, result.meshes, result.renderers)}
            if result.meshes:  # the report's picture of what stage 2 recovered, beside the truth where it has the same topology
                first = result.meshes[0]
                same = bool(result.truth) and result.truth[0].world_pos.shape == first.world_pos.shape
                save_mesh_sample(ctx.work_dir / "extraction_meshes.npz", first.cells, {"extracted (stage 2)": first.world_pos},
                                 truth=result.truth[0].world_pos if same else None, title=f"meshes extracted from training video {train_ids[0]}, seed {ctx.seed}")  # fmt: skip
        else:
            sim, stats = pipeline.train_from_video(ctx, train_ids)
    else:
        store = DatasetStore.open(cfg.data.dataset_dir())
        sim = build_simulator(ctx)
        _, stats, _, _ = fit_on_meshes(ctx, sim, store, train_ids)
    wall = time.perf_counter() - t0
    cost = max(wall, float(stats.get("cost_seconds", 0.0))) if mode == "video" else fit_cost_seconds(wall, stats)
    timings = {"sim_fit_seconds": cost, "sim_fit_wall_seconds": wall}
    timings.update({f"sim_fit/{k}": float(v) for k, v in (stats or {}).items() if isinstance(v, (int, float))})
    return sim, timings, mode, extracted


def uses_own_meshes(ctx: TaskContext, mode: str) -> bool:
    """Whether a simulator row rolls each video out on its own mesh: the simulator learned from video (`mode`
    'video') with `task_config.clods.initial_mesh=reconstructed`, so nothing of the ground truth is read."""
    if mode != "video":
        return False
    from clods_bench.benchmark.clods.config import clods_config

    return clods_config(ctx.config).initial_mesh == "reconstructed"


def own_meshes(ctx: TaskContext, store: DatasetStore, mode: str, recovered: dict[int, Recovered], ids: Sequence[int], where: str) -> bool:
    """`uses_own_meshes`, checked: a row from a true initial mesh refuses a dataset without meshes, and a row on own
    meshes refuses scored videos the pipeline recovered nothing from (`where` names the option to change)."""
    if not uses_own_meshes(ctx, mode):
        store.require_meshes(f"a simulator row from a true initial mesh (sim_training={mode}; on video alone set "
                             "task_config.clods.initial_mesh=reconstructed)")  # fmt: skip
        return False
    missing = [int(i) for i in ids if int(i) not in recovered]
    if missing:
        raise ClodsError(f"trajectories {missing} are scored, and their videos did not train the simulator, so they have no reconstructed mesh",
                         where=where, hint="use train_subset=all or score fewer trajectories")  # fmt: skip
    return True


def own_rollout_input(mesh: Trajectory, first: int, stop: int) -> RolloutInput:
    """The rollout over frames first..stop-1 of a video on its own reconstructed mesh: it starts from the meshes stage 2
    recovered at frames `first`, `first + 1`, and the handles found in the video's motion hold still where they are
    at `first`, as a pinned edge does."""
    start = np.asarray(mesh.world_pos[first : first + 2], np.float32)
    kin = np.full((stop - first, mesh.num_nodes, 3), np.nan, np.float32)
    pinned = mesh.node_type != NORMAL
    kin[:, pinned] = start[0, pinned]
    return RolloutInput(mesh.cells, mesh.mesh_pos, mesh.node_type, start, kin, mesh.dt)


def recover_videos(ctx: TaskContext, ids: list[int], frames: int) -> dict[int, Recovered]:
    """Stages 0-2 (reconstructed initial mesh) on frames 0..frames-1 of videos the simulator did not learn from, e.g. the
    given frames of unseen test videos: each video's own mesh with its handles, and its stage-1 renderer (cached)."""
    pipeline = pipeline_module()
    ext = pipeline.extract_meshes(ctx, ids, frames=frames)
    return {int(i): Recovered(m, r) for i, m, r in zip(ids, ext.meshes, ext.renderers)}


def fit_renderer(ctx: TaskContext, trajs: list[Any], images: np.ndarray, train_cams: list["Camera"]) -> tuple[Any, dict[str, float]]:
    """Stage 1: one renderer fitted on frame 0 of the scored trajectories, images (B,N,H,W,3) from the training cameras.

    Through the CloDS pipeline's `fit_stage1` when it is installed (cached: a run whose pipeline fitted the
    same first frames reuses that fit), else the renderer plugin's own `fit`.
    """
    pipeline = pipeline_module()
    if pipeline is not None and hasattr(pipeline, "fit_stage1"):
        out = pipeline.fit_stage1(ctx, trajs, images, train_cams)
        return (out[0], dict(out[1] or {})) if isinstance(out, tuple) else (out, {})
    renderer = build_renderer(ctx)
    verts = np.stack([t.world_pos[0] for t in trajs]).astype(np.float32)
    with plugin_call("renderer", str(ctx.config.renderer), "fit", renderer):
        stats = renderer.fit(verts, trajs[0].cells, trajs[0].mesh_pos, images, train_cams)
    stage_digests.record("renderer fit", renderer)
    return renderer, dict(stats or {})


def upscale(img: np.ndarray, min_side: int = 128) -> np.ndarray:
    """Nearest-neighbour upscaling by an integer factor to at least `min_side` pixels (for viewing)."""
    k = max(1, math.ceil(min_side / max(img.shape[:2])))
    return np.kron(img, np.ones((k, k, 1), dtype=img.dtype)) if k > 1 else img


def video_frames(truth: np.ndarray, pred: np.ndarray, gap: int = 2) -> np.ndarray:
    """(F,H',W',3) uint8: per frame, the views' truth side by side above their predictions."""
    n, f, h, w, _ = truth.shape
    canvas = np.full((f, 2 * h + 3 * gap, n * (w + gap) + gap, 3), 0.5, np.float32)
    for v in range(n):
        x = gap + v * (w + gap)
        canvas[:, gap : gap + h, x : x + w] = truth[v]
        canvas[:, 2 * gap + h : 2 * gap + 2 * h, x : x + w] = pred[v]
    return np.stack([np.clip(np.rint(upscale(c) * 255.0), 0, 255).astype(np.uint8) for c in canvas])


def write_video(path: Path, frames: np.ndarray, fps: float) -> Path:
    """Write (F,H,W,3) uint8 frames as a looping GIF or an MP4 (by `path`'s suffix), atomically."""
    import imageio.v3 as iio

    if path.suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ClodsError("writing MP4 needs the imageio-ffmpeg package", where="task_config.dvc.video_format", hint="pip install imageio-ffmpeg, or use gif") from None
        with atomic_path(path) as tmp:
            iio.imwrite(tmp, frames, extension=".mp4", fps=fps)
    else:
        with atomic_path(path) as tmp:
            iio.imwrite(tmp, frames, extension=".gif", duration=1000.0 / fps, loop=0)
    return path
