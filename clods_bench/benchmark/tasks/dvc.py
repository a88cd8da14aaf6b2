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
over every rendered frame 1..T-1 under `all/`. With `task_config.clods.initial_mesh=reconstructed` the simulator row
reads nothing of the ground truth: each video is rolled out on the mesh stage 0 built from its frame-0 images and
rendered by the renderer stage 1 fitted on it, so it also runs on a dataset without meshes (imported from video).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch
from rich.progress import Progress

from clods_bench.benchmark.clods.video_runs import (
    ImageScores,
    Recovered,
    build_predictor,
    fit_predictor,
    fit_renderer,
    own_meshes,
    own_rollout_input,
    to_float,
    train_simulator,
    video_frames,
    write_video,
)
from clods_bench.benchmark.core.builders import as_images, split_spec
from clods_bench.benchmark.core.descriptors import TaskContext, TaskResult
from clods_bench.benchmark.core.interfaces import RolloutInput, check_prediction, check_rollout, rollout_checked
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.benchmark.outputs.films import save_film
from clods_bench.benchmark.outputs.media import write_image_grid
from clods_bench.benchmark.outputs.mesh_pictures import save_mesh_sample
from clods_bench.benchmark.scoring.image_metrics import LpipsMetric, LpipsUnavailable, load_lpips, lpips_for
from clods_bench.benchmark.scoring.metrics import divergence_step
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

if TYPE_CHECKING:
    from clods_bench.datasets.cameras import Camera

Videos = dict[int, tuple[np.ndarray, np.ndarray]]
"""Per scored trajectory: (truth, prediction), each (N,F,H,W,3) over the scored views and frames."""
GRID_FILE = "dvc_grid.png"
FILM_FILE = "dvc_frames.npz"
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
    """Compute LPIPS when its weights are installed (never downloaded)."""
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


def _views(opts: DvcConfig, splits: Any) -> list[int]:
    """Indices of the scored cameras."""
    views = {"test": list(splits.test_views), "train": list(splits.train_views), "all": list(splits.train_views) + list(splits.test_views)}[opts.views]
    if not views:
        raise ClodsError("no cameras to score", where=f"{WHERE}.views", hint="data.num_views_test is 0: use views=train")
    return views


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
    scores = ImageScores(lpips if isinstance(lpips, LpipsMetric) else None)
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
    if videos:  # the first trajectory's frames, for the report's labelled animation of the table's rows
        first = next(iter(videos))
        save_film(ctx.work_dir / FILM_FILE, *videos[first], views, future, f"traj {first}",
                  f"{cfg.label or cfg.predictor or cfg.sim}: scored frames of trajectory {first}, seed {ctx.seed}")  # fmt: skip
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
    view_cams: list["Camera"], future: list[int], scores: ImageScores,
) -> tuple[Videos, dict[str, float], dict[str, Any]]:  # fmt: skip
    """Train the predictor on frames 0..interp of every scored view, predict the rest, score it."""
    cfg = ctx.config
    observed = future[0]  # frames 0..observed-1 are given
    pred = build_predictor(ctx)
    clips = {i: to_float(store.frames(i)[:, views]).transpose(1, 0, 2, 3, 4) for i in traj_ids}  # (N,T,H,W,3), scored views only
    train = [clip[v, :observed] for clip in clips.values() for v in range(len(views))]
    stats, timings = fit_predictor(ctx, pred, train, traj_ids, views, observed)
    predict_seconds, videos = 0.0, {}
    with Progress(transient=True, disable=not cfg.progress) as bar:
        job = bar.add_task(f"dvc ({cfg.predictor})", total=len(traj_ids))
        for i, clip in clips.items():
            context = clip[:, :observed]
            t0 = time.perf_counter()
            with plugin_call("video predictor", str(cfg.predictor), "predict", pred):
                raw = pred.predict(context, len(future), view_cams)
            out = check_prediction(raw, context, len(future), cfg.predictor)
            predict_seconds += time.perf_counter() - t0
            for k, t in enumerate(future):
                scores.add(i, t, out[:, k], clip[:, t])
            videos[i] = (clip[:, future], out)
            bar.advance(job)
    images = len(traj_ids) * len(future) * len(views)
    timings.update({"predict_seconds": predict_seconds, "predict_ms_per_frame": 1000.0 * predict_seconds / max(images, 1)})
    timings.update({f"fit/{k}": float(v) for k, v in stats.items()})
    return videos, timings, {"train_videos": len(train), "context_frames": observed}


def _rollout_input(traj: Any, opts: DvcConfig, recovered: dict[int, Recovered], index: int, splits: Any) -> tuple[RolloutInput, np.ndarray | None]:
    """The rollout input of one scored trajectory and, for start='observed', the recovered meshes of frames 0..interp."""
    if opts.start == "initial":
        return RolloutInput.from_trajectory(traj, splits.num_steps), None
    known = recovered.get(int(index))
    if known is None:
        raise ClodsError(
            f"start=observed needs the meshes stage 2 recovered from trajectory {index}'s video, and there are none",
            where=f"{WHERE}.start", hint="use the video-trained simulator (sim_training=video, train_subset=all) or start=initial",
        )  # fmt: skip
    first = splits.interp_steps - 1  # the rollout's frames 0, 1 are the last two observed ones
    kin = traj.world_pos[first : splits.num_steps].astype(np.float32).copy()
    kin[:, traj.node_type == 0] = np.nan
    world = known.mesh.world_pos
    inp = RolloutInput(traj.cells, traj.mesh_pos, traj.node_type, np.asarray(world[first : first + 2], np.float32), kin, traj.dt)
    return inp, np.asarray(world[: splits.interp_steps + 1], np.float32)


def _run_simulator(
    ctx: TaskContext, opts: DvcConfig, store: DatasetStore, traj_ids: list[int], views: list[int],
    view_cams: list["Camera"], future: list[int], scores: ImageScores,
) -> tuple[Videos, dict[str, float], dict[str, Any]]:  # fmt: skip
    """Algorithm S2: roll the simulator out from the initial mesh, render every frame, score it.

    From the ground-truth initial mesh with one renderer fitted on the scored trajectories' frame 0, or, when the
    simulator learned from a reconstructed initial mesh, from each video's own mesh with the renderer stage 1 fitted
    on it (then nothing of the ground truth is read, and a dataset without meshes runs too)."""
    cfg = ctx.config
    splits = split_spec(ctx)
    train_views = list(splits.train_views)
    train_cams = [store.cameras()[v] for v in train_views]
    if opts.sim_training == "mesh":  # refuse before training
        store.require_meshes(f"{WHERE}.sim_training=mesh (it trains the simulator on ground-truth meshes)")
    sim, timings, mode, recovered = train_simulator(ctx, opts.sim_training)
    own = own_meshes(ctx, store, mode, recovered, traj_ids, f"{WHERE}.num_trajectories")
    t0 = time.perf_counter()
    if own:  # stage 1 was fitted per video by the pipeline: its cost is in the simulator's
        trajs: dict[int, Any] = {i: recovered[i].mesh for i in traj_ids}
        renderers = {i: recovered[i].renderer for i in traj_ids}
        render_stats: dict[str, Any] = {}
    else:
        trajs = {i: store.load_trajectory(i) for i in traj_ids}
        first = np.stack([to_float(store.frames(i)[0, train_views]) for i in traj_ids])
        renderer, render_stats = fit_renderer(ctx, list(trajs.values()), first, train_cams)
        renderers = {i: renderer for i in traj_ids}
    render_fit = time.perf_counter() - t0
    timings.update({f"render_fit/{k}": float(v) for k, v in render_stats.items()})
    render_s, rollout_s, rendered, steps = 0.0, 0.0, 0, 0
    diverged: dict[str, int] = {}
    videos = {}
    with Progress(transient=True, disable=not cfg.progress) as bar:
        job = bar.add_task(f"dvc ({cfg.sim}+{cfg.renderer})", total=len(traj_ids) * (splits.num_steps - 1))
        for i, traj in trajs.items():
            clip = to_float(store.frames(i)[:, views])  # (T,V,H,W,3), the scored views only
            if own:
                first = 0 if opts.start == "initial" else splits.interp_steps - 1
                inp = own_rollout_input(traj, first, splits.num_steps)
                observed = None if opts.start == "initial" else np.asarray(traj.world_pos[: splits.interp_steps + 1], np.float32)
            else:
                inp, observed = _rollout_input(traj, opts, recovered, i, splits)
            t0 = time.perf_counter()
            mesh = rollout_checked(sim, inp, cfg.sim)
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
                with torch.no_grad(), plugin_call("renderer", str(cfg.renderer), "render", renderers[i]):
                    out = renderers[i].render(torch.from_numpy(mesh[t]), view_cams)
                render_s += time.perf_counter() - t0
                rendered += len(view_cams)
                img = as_images(out, (len(view_cams), *clip.shape[2:]), where=f"renderer '{cfg.renderer}', trajectory {i}, frame {t}")
                scores.add(i, t, img, clip[t])
                frames.append(img)
                bar.advance(job)
            pred = np.stack(frames, axis=1)  # (N,T-1,H,W,3), frames 1..T-1
            videos[i] = (clip[future].transpose(1, 0, 2, 3, 4), pred[:, [t - 1 for t in future]])
            if own and i == traj_ids[0]:  # the predicted cloth on its own mesh, for the report's pictures and export
                save_mesh_sample(ctx.work_dir / "rollout_meshes.npz", traj.cells, {cfg.label or str(cfg.sim): mesh},
                                 marks=[splits.interp_steps], title=f"rollout of trajectory {i}'s reconstructed mesh, seed {ctx.seed}")  # fmt: skip
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
    extra = {"diverged": diverged, "sim_training": mode, "start": opts.start, "mesh": "reconstructed (per video)" if own else "ground truth"}
    return videos, timings, extra


def _write_outputs(work: Path, opts: DvcConfig, videos: Videos, future: list[int]) -> dict[str, Any]:
    """Per trajectory a truth-above-prediction video; for the first one a PNG grid of a few scored frames."""
    out: dict[str, Any] = {"videos": [], "grid": None}
    if opts.video_format != "none":
        for i, (truth, pred) in videos.items():
            path = work / f"dvc_traj{i}.{opts.video_format}"
            out["videos"].append(str(write_video(path, video_frames(truth, pred), opts.video_fps)))
    if opts.grid_frames and videos:
        truth, pred = next(iter(videos.values()))
        picks = np.linspace(0, len(future) - 1, min(opts.grid_frames, len(future))).round().astype(int)
        out["grid"] = str(write_image_grid(work / GRID_FILE, [truth[:, k] for k in picks], [pred[:, k] for k in picks]))
        out["grid_frames"] = [future[k] for k in picks]
    return out
