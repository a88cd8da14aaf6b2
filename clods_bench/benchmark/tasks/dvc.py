"""The DVC forward task (video prediction, the paper's Table 4): predicted videos scored against the truth
with PSNR, SSIM, LPIPS and RMSE (tables show SSIM x10, LPIPS x100, RMSE x100).

Two kinds of rows. A video predictor (`--predictor copylast|simvp|tau|mau|mmvp`): the baselines "cannot utilize
multi-view videos", so, as in the appendix, every scored view of the first `num_trajectories`
training trajectories is a single-view video; the predictor trains on frames 0..interp_steps
(paper: the first 300 steps) and predicts the remaining frames (paper: the following 100) from
them. A simulator + renderer (`--sim mgn --renderer smgs`, Algorithm S2): the renderer is fitted
on frame 0 of each scored trajectory from the training cameras (stage 1), the simulator (trained
from video by the CloDS pipeline, or on ground-truth meshes: `sim_training`) rolls out from the
initial mesh, and every frame is rendered from the scored cameras. Both rows are scored on the same
images: the extrapolation frames of the scored views; the simulator row also reports the scores
over every rendered frame 1..T-1 under `all/`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Sequence

import numpy as np
import torch
from rich.progress import Progress

from clods_bench.atomic import atomic_path, file_lock
from clods_bench.benchmark.config import dataclass_from_dict
from clods_bench.benchmark.descriptors import BuildContext, TaskContext, TaskResult
from clods_bench.benchmark.image_metrics import LpipsMetric, LpipsUnavailable, image_scores, load_lpips, lpips_for
from clods_bench.benchmark.interfaces import FitContext, RolloutInput, VideoPredictor, check_prediction, check_rollout
from clods_bench.benchmark.metrics import divergence_step
from clods_bench.benchmark.fit_cache import fit_cost_seconds, fit_work_dir, predictor_fit_identity
from clods_bench.benchmark.tasks.cdg import build_simulator, fit_on_meshes, split_spec
from clods_bench.benchmark.tasks.nvs import _as_images, _write_grid, build_renderer
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError

if TYPE_CHECKING:
    from clods_bench.datasets.cameras import Camera

METRICS = ("psnr", "ssim", "lpips", "rmse")
Videos = dict[int, tuple[np.ndarray, np.ndarray]]
"""Per scored trajectory: (truth, prediction), each (N,F,H,W,3) over the scored views and frames."""
GRID_FILE = "dvc_grid.png"
WHERE = "task_config.dvc"


@dataclass(frozen=True)
class DvcConfig:
    """Options of the DVC forward task (`task_config.dvc.*`)."""

    num_trajectories: int = 5
    """Training trajectories scored, the first ones (paper: 5); fewer if the dataset has fewer."""
    views: Literal["test", "train", "all"] = "test"
    """Cameras whose videos are predicted and scored: the held-out ones ('test'), the fitting ones, or all."""
    sim_training: Literal["auto", "video", "mesh"] = "auto"
    """Simulator rows: train from the training videos with the CloDS pipeline ('video', needs
    clods_bench.benchmark.clods.pipeline), on the ground-truth meshes as CDG does ('mesh'), or
    'auto': video when the pipeline is installed, else mesh (the record says which ran)."""
    start: Literal["initial", "observed"] = "initial"
    """Simulator rows: roll out from the initial mesh (frames 0-1, Algorithm S2: the whole video is generated), or
    'observed': from the meshes stage 2 recovered from the last two observed frames (interp_steps - 1, interp_steps),
    the context the video predictors get (frames up to interp_steps are the recovered meshes, rendered)."""
    lpips: bool = True
    """Compute LPIPS when its weights are on this machine (never downloaded)."""
    grid_frames: int = 4
    """Scored frames of the first trajectory shown in the truth-vs-prediction PNG grid (0: no grid)."""
    video_format: Literal["gif", "mp4", "none"] = "gif"
    """Format of the written videos (truth above prediction, views side by side); mp4 needs imageio-ffmpeg."""
    video_fps: float = 10.0
    """Frames per second of the written videos."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        if self.num_trajectories < 1:
            raise ClodsError(f"must be >= 1, got {self.num_trajectories}", where=f"{WHERE}.num_trajectories")
        if self.grid_frames < 0:
            raise ClodsError(f"must be >= 0, got {self.grid_frames}", where=f"{WHERE}.grid_frames")
        if self.video_fps <= 0:
            raise ClodsError(f"must be > 0, got {self.video_fps}", where=f"{WHERE}.video_fps")


def dvc_options(ctx: TaskContext) -> DvcConfig:
    """This run's DvcConfig, checked."""
    opts: DvcConfig = dataclass_from_dict(DvcConfig, dict(ctx.config.task_config.get("dvc", {})), where=WHERE, prefix="dvc.")
    opts.validate()
    return opts


def build_predictor(ctx: TaskContext) -> VideoPredictor:
    """Build the configured video-predictor plugin for this seed."""
    cfg = ctx.config
    spec = ctx.registry.get("video_predictor", cfg.predictor)
    pcfg = spec.make_config(cfg.video_config.get(cfg.predictor, {}), where=f"video_config.{cfg.predictor}")
    scene = ctx.registry.get("scene", cfg.data.scene)
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
        stats = dict(pred.fit(videos, FitContext(work_dir=work, seed=ctx.seed, progress=cfg.progress)) or {})
    wall = time.perf_counter() - t0
    return stats, {"fit_seconds": fit_cost_seconds(wall, stats), "fit_wall_seconds": wall}


def _views(opts: DvcConfig, splits: Any) -> list[int]:
    """Indices of the scored cameras."""
    views = {"test": list(splits.test_views), "train": list(splits.train_views), "all": list(splits.train_views) + list(splits.test_views)}[opts.views]
    if not views:
        raise ClodsError("no cameras to score", where=f"{WHERE}.views", hint="data.num_views_test is 0: use views=train")
    return views


def _float(frames: np.ndarray) -> np.ndarray:
    return np.asarray(frames, dtype=np.float32) / 255.0


class _Scores:
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


def run_dvc(ctx: TaskContext) -> TaskResult:
    """One seed of the DVC forward task: a video predictor or a simulator + renderer, scored on the same frames."""
    cfg = ctx.config
    if not cfg.data.render_frames:
        raise ClodsError("DVC needs rendered frames", where="data.render_frames", hint="set data.render_frames=true")
    use_predictor = cfg.predictor is not None
    if use_predictor and (cfg.sim or cfg.renderer):
        raise ClodsError("give either --predictor or --sim with --renderer, not both", where="dvc")
    if not use_predictor and not (cfg.sim and cfg.renderer):
        raise ClodsError(
            "dvc needs a video predictor or a simulator and a renderer",
            where="--predictor / --sim --renderer",
            hint=f"e.g. --predictor copylast, or --sim mgn --renderer smgs; predictors: {ctx.registry.names('video_predictor')}",
        )
    opts = dvc_options(ctx)
    splits = split_spec(ctx)
    store = DatasetStore.open(cfg.data.dataset_dir())
    cams = store.cameras()
    views = _views(opts, splits)
    view_cams = [cams[v] for v in views]
    traj_ids = list(range(min(opts.num_trajectories, splits.num_train)))
    future = list(range(splits.interp_steps + 1, splits.num_steps))  # the scored (extrapolation) frames
    h, w = view_cams[0].height, view_cams[0].width
    lpips: LpipsMetric | LpipsUnavailable = load_lpips() if opts.lpips else LpipsUnavailable(f"LPIPS switched off ({WHERE}.lpips=false)")
    lpips = lpips_for((h, w), lpips)
    scores = _Scores(lpips if isinstance(lpips, LpipsMetric) else None)
    torch.manual_seed(ctx.seed)

    run = _run_predictor if use_predictor else _run_simulator
    videos, timings, extra = run(ctx, opts, store, traj_ids, views, view_cams, future, scores)

    if isinstance(lpips, LpipsMetric):
        timings["lpips_seconds"] = lpips.seconds
    metrics = scores.means(set(future))
    if not use_predictor:
        metrics.update(scores.means(None, prefix="all/"))
    curves = scores.curves(future)
    written = _write_outputs(ctx.work_dir, opts, videos, future)
    extra.update(
        {
            "trajectories": traj_ids,
            "views": views,
            "scored_frames": future,
            "images": len(traj_ids) * len(future) * len(views),
            "lpips_unavailable": lpips.reason if isinstance(lpips, LpipsUnavailable) else None,
            "lpips_source": lpips.source if isinstance(lpips, LpipsMetric) else None,
            "lpips_files": [str(f) for f in lpips.files] if isinstance(lpips, LpipsMetric) else [],
            **written,
        }
    )
    return TaskResult(metrics=metrics, timings=timings, curves=curves, extra=extra)


def _run_predictor(
    ctx: TaskContext, opts: DvcConfig, store: DatasetStore, traj_ids: list[int], views: list[int],
    view_cams: list["Camera"], future: list[int], scores: _Scores,
) -> tuple[Videos, dict[str, float], dict[str, Any]]:  # fmt: skip
    """Train the predictor on frames 0..interp of every scored view, predict the rest, score it."""
    cfg = ctx.config
    observed = future[0]  # frames 0..observed-1 are given
    pred = build_predictor(ctx)
    clips = {i: _float(store.frames(i)[:, views]).transpose(1, 0, 2, 3, 4) for i in traj_ids}  # (N,T,H,W,3), scored views only
    train = [clip[v, :observed] for clip in clips.values() for v in range(len(views))]
    stats, timings = fit_predictor(ctx, pred, train, traj_ids, views, observed)
    predict_seconds, videos = 0.0, {}
    with Progress(transient=True, disable=not cfg.progress) as bar:
        job = bar.add_task(f"dvc ({cfg.predictor})", total=len(traj_ids))
        for i, clip in clips.items():
            context = clip[:, :observed]
            t0 = time.perf_counter()
            out = check_prediction(pred.predict(context, len(future), view_cams), context, len(future), cfg.predictor)
            predict_seconds += time.perf_counter() - t0
            for k, t in enumerate(future):
                scores.add(i, t, out[:, k], clip[:, t])
            videos[i] = (clip[:, future], out)
            bar.advance(job)
    images = len(traj_ids) * len(future) * len(views)
    timings.update({"predict_seconds": predict_seconds, "predict_ms_per_frame": 1000.0 * predict_seconds / max(images, 1)})
    timings.update({f"fit/{k}": float(v) for k, v in stats.items()})
    return videos, timings, {"train_videos": len(train), "context_frames": observed}


def _pipeline() -> Any:
    """The CloDS pipeline module, or None while it is not installed."""
    try:
        from clods_bench.benchmark.clods import pipeline
    except ImportError:
        return None
    return pipeline


def _train_simulator(
    ctx: TaskContext, sim_training: str, train_ids: list[int] | None = None, where: str = f"{WHERE}.sim_training"
) -> tuple[Any, dict[str, float], str, dict[int, np.ndarray]]:
    """The simulator for the rollouts, from the training videos (CloDS stages 1-3) or the ground-truth meshes of
    `train_ids` (default: every training trajectory, or the first half with `train_subset`); with the video-trained
    one also the meshes stage 2 recovered per training trajectory (frames 0..interp_steps)."""
    cfg = ctx.config
    splits = split_spec(ctx)
    if train_ids is None:
        train_ids = list(splits.train if cfg.train_subset == "all" else splits.first_half)
    pipeline = _pipeline()
    have_video = pipeline is not None and hasattr(pipeline, "train_from_video")
    mode = ("video" if have_video else "mesh") if sim_training == "auto" else sim_training
    t0 = time.perf_counter()
    extracted: dict[int, np.ndarray] = {}
    if mode == "video":
        if not have_video:
            raise ClodsError("the CloDS pipeline (clods_bench.benchmark.clods.pipeline.train_from_video) is not available",
                             where=where, hint=f"set {where}=mesh")  # fmt: skip
        if hasattr(pipeline, "run_pipeline"):
            result = pipeline.run_pipeline(ctx, train_ids)
            sim, stats = result.simulator, result.stats
            extracted = {int(i): m.world_pos for i, m in zip(train_ids, result.meshes)}
        else:
            sim, stats = pipeline.train_from_video(ctx, train_ids)
    else:
        store = DatasetStore.open(cfg.data.dataset_dir())
        sim = build_simulator(ctx)
        _, stats, _ = fit_on_meshes(ctx, sim, store, train_ids)
    wall = time.perf_counter() - t0
    cost = max(wall, float(stats.get("cost_seconds", 0.0))) if mode == "video" else fit_cost_seconds(wall, stats)
    timings = {"sim_fit_seconds": cost, "sim_fit_wall_seconds": wall}
    timings.update({f"sim_fit/{k}": float(v) for k, v in (stats or {}).items() if isinstance(v, (int, float))})
    return sim, timings, mode, extracted


def _rollout_input(traj: Any, opts: DvcConfig, extracted: dict[int, np.ndarray], index: int, splits: Any) -> tuple[RolloutInput, np.ndarray | None]:
    """The rollout input of one scored trajectory and, for start='observed', the recovered meshes of frames 0..interp."""
    if opts.start == "initial":
        return RolloutInput.from_trajectory(traj, splits.num_steps), None
    known = extracted.get(int(index))
    if known is None:
        raise ClodsError(
            f"start=observed needs the meshes stage 2 recovered from trajectory {index}'s video, and there are none",
            where=f"{WHERE}.start", hint="use the video-trained simulator (sim_training=video, train_subset=all) or start=initial",
        )  # fmt: skip
    first = splits.interp_steps - 1  # the rollout's frames 0, 1 are the last two observed ones
    kin = traj.world_pos[first : splits.num_steps].astype(np.float32).copy()
    kin[:, traj.node_type == 0] = np.nan
    inp = RolloutInput(traj.cells, traj.mesh_pos, traj.node_type, np.asarray(known[first : first + 2], np.float32), kin, traj.dt)
    return inp, np.asarray(known[: splits.interp_steps + 1], np.float32)


def _fit_renderer(ctx: TaskContext, trajs: list[Any], images: np.ndarray, train_cams: list["Camera"]) -> tuple[Any, dict[str, float]]:
    """Stage 1: one renderer fitted on frame 0 of the scored trajectories, images (B,N,H,W,3) from the training cameras.

    Through the CloDS pipeline's `fit_stage1` when it is installed (cached: a run whose pipeline fitted the
    same first frames reuses that fit), else the renderer plugin's own `fit`.
    """
    pipeline = _pipeline()
    if pipeline is not None and hasattr(pipeline, "fit_stage1"):
        out = pipeline.fit_stage1(ctx, trajs, images, train_cams)
        return (out[0], dict(out[1] or {})) if isinstance(out, tuple) else (out, {})
    renderer = build_renderer(ctx)
    verts = np.stack([t.world_pos[0] for t in trajs]).astype(np.float32)
    stats = renderer.fit(verts, trajs[0].cells, trajs[0].mesh_pos, images, train_cams)
    return renderer, dict(stats or {})


def _run_simulator(
    ctx: TaskContext, opts: DvcConfig, store: DatasetStore, traj_ids: list[int], views: list[int],
    view_cams: list["Camera"], future: list[int], scores: _Scores,
) -> tuple[Videos, dict[str, float], dict[str, Any]]:  # fmt: skip
    """Algorithm S2: roll the simulator out from the initial mesh, render every frame, score it."""
    cfg = ctx.config
    splits = split_spec(ctx)
    train_views = list(splits.train_views)
    train_cams = [store.cameras()[v] for v in train_views]
    sim, timings, mode, extracted = _train_simulator(ctx, opts.sim_training)
    trajs = {i: store.load_trajectory(i) for i in traj_ids}
    t0 = time.perf_counter()
    renderer, render_stats = _fit_renderer(ctx, list(trajs.values()), np.stack([_float(store.frames(i)[0, train_views]) for i in traj_ids]), train_cams)
    render_fit = time.perf_counter() - t0
    timings.update({f"render_fit/{k}": float(v) for k, v in render_stats.items()})
    render_s, rollout_s, rendered, steps = 0.0, 0.0, 0, 0
    diverged: dict[str, int] = {}
    videos = {}
    with Progress(transient=True, disable=not cfg.progress) as bar:
        job = bar.add_task(f"dvc ({cfg.sim}+{cfg.renderer})", total=len(traj_ids) * (splits.num_steps - 1))
        for i, traj in trajs.items():
            clip = _float(store.frames(i)[:, views])  # (T,V,H,W,3), the scored views only
            inp, observed = _rollout_input(traj, opts, extracted, i, splits)
            t0 = time.perf_counter()
            mesh = check_rollout(sim.rollout(inp), inp, cfg.sim)
            rollout_s += time.perf_counter() - t0
            steps += inp.num_frames - 2
            if observed is not None:  # frames 0..interp: the recovered meshes; the rollout continues from the last two
                mesh = np.concatenate([observed, mesh[2:]])
            bad = divergence_step(mesh)
            if bad is not None:  # a blown-up rollout is data: the last finite mesh stands in for the rest, and it is recorded
                diverged[str(i)] = bad
                mesh[bad:] = mesh[bad - 1]
            frames = []
            for t in range(1, splits.num_steps):
                t0 = time.perf_counter()
                with torch.no_grad():
                    out = renderer.render(torch.from_numpy(mesh[t]), view_cams)
                render_s += time.perf_counter() - t0
                rendered += len(view_cams)
                img = _as_images(out, (len(view_cams), *clip.shape[2:]), where=f"renderer '{cfg.renderer}', trajectory {i}, frame {t}")
                scores.add(i, t, img, clip[t])
                frames.append(img)
                bar.advance(job)
            pred = np.stack(frames, axis=1)  # (N,T-1,H,W,3), frames 1..T-1
            videos[i] = (clip[future].transpose(1, 0, 2, 3, 4), pred[:, [t - 1 for t in future]])
    timings.update(
        {
            "fit_seconds": timings["sim_fit_seconds"] + render_fit,
            "render_fit_seconds": render_fit,
            "render_ms_per_frame": 1000.0 * render_s / max(rendered, 1),
            "rollout_ms_per_step": 1000.0 * rollout_s / max(steps, 1),
            # one image (one view, one frame): its share of the rollout step plus its render
            "predict_ms_per_frame": 1000.0 * (rollout_s / max(steps, 1) / len(view_cams) + render_s / max(rendered, 1)),
        }
    )
    return videos, timings, {"diverged": diverged, "sim_training": mode, "start": opts.start}


def _upscale(img: np.ndarray, min_side: int = 128) -> np.ndarray:
    k = max(1, math.ceil(min_side / max(img.shape[:2])))
    return np.kron(img, np.ones((k, k, 1), dtype=img.dtype)) if k > 1 else img


def _video_frames(truth: np.ndarray, pred: np.ndarray, gap: int = 2) -> np.ndarray:
    """(F,H',W',3) uint8: per frame, the views' truth side by side above their predictions."""
    n, f, h, w, _ = truth.shape
    canvas = np.full((f, 2 * h + 3 * gap, n * (w + gap) + gap, 3), 0.5, np.float32)
    for v in range(n):
        x = gap + v * (w + gap)
        canvas[:, gap : gap + h, x : x + w] = truth[v]
        canvas[:, 2 * gap + h : 2 * gap + 2 * h, x : x + w] = pred[v]
    return np.stack([np.clip(np.rint(_upscale(c) * 255.0), 0, 255).astype(np.uint8) for c in canvas])


def write_video(path: Path, frames: np.ndarray, fps: float) -> Path:
    """Write (F,H,W,3) uint8 frames as a looping GIF or an MP4 (by `path`'s suffix), atomically."""
    import imageio.v3 as iio

    if path.suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ClodsError("writing MP4 needs the imageio-ffmpeg package", where=f"{WHERE}.video_format", hint="pip install imageio-ffmpeg, or use gif") from None
        with atomic_path(path) as tmp:
            iio.imwrite(tmp, frames, extension=".mp4", fps=fps)
    else:
        with atomic_path(path) as tmp:
            iio.imwrite(tmp, frames, extension=".gif", duration=1000.0 / fps, loop=0)
    return path


def _write_outputs(work: Path, opts: DvcConfig, videos: Videos, future: list[int]) -> dict[str, Any]:
    """Per trajectory a truth-above-prediction video; for the first one a PNG grid of a few scored frames."""
    out: dict[str, Any] = {"videos": [], "grid": None}
    if opts.video_format != "none":
        for i, (truth, pred) in videos.items():
            path = work / f"dvc_traj{i}.{opts.video_format}"
            out["videos"].append(str(write_video(path, _video_frames(truth, pred), opts.video_fps)))
    if opts.grid_frames and videos:
        truth, pred = next(iter(videos.values()))
        picks = np.linspace(0, len(future) - 1, min(opts.grid_frames, len(future))).round().astype(int)
        out["grid"] = str(_write_grid(work / GRID_FILE, [truth[:, k] for k in picks], [pred[:, k] for k in picks]))
        out["grid_frames"] = [future[k] for k in picks]
    return out
