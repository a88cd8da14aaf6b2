"""Video prediction trained on several trajectories (the paper's appendix table "video prediction models trained
on multiple trajectories"): Extrapolation and Generalization, each scored with PSNR, SSIM, LPIPS and RMSE.

The split (`multi_split`), with the data's splits:
- training trajectories: the first `num_train_trajectories` of the training split (paper: 10); every scored view
  of each is a single-view video whose interpolation frames 0..interp_steps train the predictor (windows drawn
  across trajectories, never across a boundary: each video is its own sample list);
- Extrapolation: the remaining frames interp_steps+1..num_steps-1 of those same trajectories, predicted from
  their observed frames (the paper: the last 100 frames of the 10 training trajectories);
- Generalization: the first `num_test_trajectories` unseen test trajectories (paper: 2); frames
  0..gen_context-1 are given and the next `gen_frames` (default: as many as Extrapolation scores, the paper's
  100 and 100) are scored, inside the interpolation phase the predictors were trained on.

A simulator + renderer row (CloDS: `--sim mgn --renderer smgs`) is Table 4's DVC row applied to both splits:
the simulator learns from the same training trajectories (the CloDS pipeline on their videos, through its
caches), a renderer is fitted on frame 0 of each split's trajectories (stage 1), and each trajectory is rolled
out from its initial mesh (Algorithm S2) and rendered at the scored frames. With
`task_config.clods.initial_mesh=reconstructed` each video runs on its own mesh instead (an unseen one's from stages
0-2 on its given frames), so the row also runs on a dataset without meshes. A task of its own rather than a
`dvc` option: its records hold two column groups, so `tables` and `reproduce` pick the layout by task, and
`dvc` records (Table 4) never mix with these.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch

from clods_bench.benchmark.clods.video_runs import (
    ImageScores,
    build_predictor,
    fit_predictor,
    fit_renderer,
    own_meshes,
    own_rollout_input,
    recover_videos,
    to_float,
    train_simulator,
    video_frames,
    write_video,
)
from clods_bench.benchmark.core.builders import as_images, split_spec
from clods_bench.benchmark.core.descriptors import TaskContext, TaskResult
from clods_bench.benchmark.core.interfaces import RolloutInput, VideoPredictor, check_prediction, check_rollout, rollout_checked
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.benchmark.outputs.films import FILM_SUFFIX, save_film
from clods_bench.benchmark.scoring.image_metrics import LpipsMetric, LpipsUnavailable, load_lpips, lpips_for
from clods_bench.benchmark.scoring.metrics import divergence_step
from clods_bench.datasets.splits import SplitSpec
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

if TYPE_CHECKING:
    from clods_bench.datasets.cameras import Camera

WHERE = "task_config.dvc_multi"
SPLITS = ("extrap", "gen")
"""Metric prefixes: `extrap/psnr`, `gen/psnr`, ..."""


@dataclass(frozen=True)
class DvcMultiConfig:
    """Options of the multi-trajectory video-prediction task (`task_config.dvc_multi.*`)."""

    num_train_trajectories: int = 10
    """Training trajectories the predictors train on and Extrapolation scores, the first ones (paper: 10);
    fewer if the data has fewer."""
    num_test_trajectories: int = 2
    """Unseen test trajectories Generalization scores, the first ones (paper: 2); fewer if the data has fewer."""
    gen_context: int = 10
    """Generalization: frames 0..gen_context-1 of an unseen trajectory are given (a predictor reads its last
    context_frames of them; the simulator rows start from frames 0-1)."""
    gen_frames: int = 0
    """Generalization: frames scored after the given ones (0: as many as Extrapolation scores, as the paper)."""
    views: Literal["test", "train", "all"] = "test"
    """Cameras whose videos are predicted and scored: the held-out ones ('test'), the fitting ones, or all."""
    sim_training: Literal["auto", "video", "mesh"] = "auto"
    """Simulator rows: trained from the training trajectories' videos (CloDS pipeline), on their meshes, or 'auto'
    (video when the pipeline is installed), as `task_config.dvc.sim_training`."""
    lpips: bool = True
    """Compute LPIPS when its weights are installed (never downloaded)."""
    video_format: Literal["gif", "mp4", "none"] = "gif"
    """Written videos (truth above prediction) of the first trajectory of each split; mp4 needs imageio-ffmpeg."""
    video_fps: float = 10.0
    """Frames per second of the written videos."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        if self.num_train_trajectories < 1:
            raise ClodsError(
                f"no training trajectories: must be >= 1, got {self.num_train_trajectories}",
                where=f"{WHERE}.num_train_trajectories", hint="the predictors train on them and Extrapolation scores them",
            )  # fmt: skip
        if self.num_test_trajectories < 1:
            raise ClodsError(
                f"no unseen test trajectories for the Generalization split: must be >= 1, got {self.num_test_trajectories}",
                where=f"{WHERE}.num_test_trajectories",
            )
        if self.gen_context < 1:
            raise ClodsError(f"must be >= 1 (frames given before the scored ones), got {self.gen_context}", where=f"{WHERE}.gen_context")
        if self.gen_frames < 0:
            raise ClodsError(f"must be >= 0 (0: as many as Extrapolation scores), got {self.gen_frames}", where=f"{WHERE}.gen_frames")
        if self.video_fps <= 0:
            raise ClodsError(f"must be > 0, got {self.video_fps}", where=f"{WHERE}.video_fps")


def dvc_multi_options(ctx: TaskContext) -> DvcMultiConfig:
    """This run's DvcMultiConfig, checked."""
    raw = dict(ctx.config.task_config.get("dvc_multi", {}))
    opts: DvcMultiConfig = dataclass_from_dict(DvcMultiConfig, raw, where=WHERE, prefix="dvc_multi.")
    opts.validate()
    return opts


@dataclass(frozen=True)
class MultiSplit:
    """Which trajectories and frames train, and which are scored in each split (0-based store indices)."""

    train_ids: list[int]
    """Training trajectories: their frames 0..observed-1 train the predictors; Extrapolation scores their rest."""
    observed: int
    """Frames 0..observed-1 (the interpolation phase, interp_steps + 1 frames) train and give the context."""
    extrap_frames: list[int]
    """Extrapolation: scored frames of `train_ids`."""
    test_ids: list[int]
    """Unseen test trajectories scored by Generalization."""
    gen_context: int
    """Generalization: frames 0..gen_context-1 of `test_ids` are given."""
    gen_frames: list[int]
    """Generalization: scored frames of `test_ids`."""

    def scored(self, split: str) -> tuple[list[int], int, list[int]]:
        """(trajectories, frames given, scored frames) of 'extrap' or 'gen'."""
        return (self.train_ids, self.observed, self.extrap_frames) if split == "extrap" else (self.test_ids, self.gen_context, self.gen_frames)


def multi_split(splits: SplitSpec, opts: DvcMultiConfig) -> MultiSplit:
    """The trajectories and frames of each split for these data splits and options (see the module docstring)."""
    opts.validate()
    observed = splits.interp_steps + 1
    extrap = list(range(observed, splits.num_steps))
    n_gen = opts.gen_frames or len(extrap)
    if opts.gen_context + n_gen > observed:
        raise ClodsError(
            f"Generalization gives frames 0..{opts.gen_context - 1} and scores {n_gen} more, past the interpolation phase "
            f"(frames 0..{splits.interp_steps})",
            where=f"{WHERE}.gen_context",
            hint=f"keep gen_context + gen_frames <= interp_steps + 1 = {observed} (gen_frames 0 means {len(extrap)})",
        )
    return MultiSplit(
        train_ids=list(splits.train)[: opts.num_train_trajectories],
        observed=observed,
        extrap_frames=extrap,
        test_ids=list(splits.unviewed)[: opts.num_test_trajectories],
        gen_context=opts.gen_context,
        gen_frames=list(range(opts.gen_context, opts.gen_context + n_gen)),
    )


def training_videos(clips: dict[int, np.ndarray], observed: int) -> list[np.ndarray]:
    """Single-view training videos: frames 0..observed-1 of every view (N,T,H,W,3) of every trajectory, each its
    own video, so a training window never spans two trajectories (or two views)."""
    return [clip[v, :observed] for clip in clips.values() for v in range(clip.shape[0])]


def check_context(name: str, pred: VideoPredictor, split: MultiSplit) -> None:
    """Fail before training when the predictor's context cannot fit: 2 x context_frames training frames inside the
    interpolation phase, and at most gen_context frames to read on an unseen trajectory."""
    c = getattr(getattr(pred, "cfg", None), "context_frames", None)
    if not isinstance(c, int):
        return  # no fixed context (copylast reads the last frame)
    where, hint = f"video_config.{name}.context_frames", f"set video_config.{name}.context_frames to at most {min(split.observed // 2, split.gen_context)}"
    if 2 * c > split.observed:
        raise ClodsError(
            f"{c} context frames need training windows of 2 x {c} = {2 * c} frames; the interpolation phase has {split.observed} "
            f"(frames 0..{split.observed - 1})",
            where=where, hint=hint,
        )  # fmt: skip
    if c > split.gen_context:
        raise ClodsError(
            f"{c} context frames, but Generalization gives {split.gen_context} (frames 0..{split.gen_context - 1} of an unseen trajectory)",
            where=where, hint=f"{hint}, or raise {WHERE}.gen_context",
        )  # fmt: skip


def _read(store: DatasetStore, index: int, frames: int, views: list[int]) -> np.ndarray:
    """(N,frames,H,W,3) in [0,1]: frames 0..frames-1 of the scored views."""
    return to_float(store.frames(index)[:frames, views]).transpose(1, 0, 2, 3, 4)


def run_dvc_multi(ctx: TaskContext) -> TaskResult:
    """One seed: a video predictor or a simulator + renderer trained on several trajectories, scored on both splits."""
    cfg = ctx.config
    if not cfg.data.render_frames:
        raise ClodsError("dvc_multi needs rendered frames", where="data.render_frames", hint="set data.render_frames=true")
    use_predictor = cfg.predictor is not None
    if use_predictor and (cfg.sim or cfg.renderer):
        raise ClodsError("give either --predictor or --sim with --renderer, not both", where="dvc_multi")
    if not use_predictor and not (cfg.sim and cfg.renderer):
        raise ClodsError(
            "dvc_multi needs a video predictor or a simulator and a renderer",
            where="--predictor / --sim --renderer",
            hint=f"e.g. --predictor copylast, or --sim mgn --renderer smgs; predictors: {ctx.registry.names('video_predictor')}",
        )
    opts = dvc_multi_options(ctx)
    splits = split_spec(ctx)
    split = multi_split(splits, opts)
    views = {"test": list(splits.test_views), "train": list(splits.train_views), "all": list(splits.train_views) + list(splits.test_views)}[opts.views]
    if not views:
        raise ClodsError("no cameras to score", where=f"{WHERE}.views", hint="data.num_views_test is 0: use views=train")
    store = DatasetStore.open(cfg.data.dataset_dir())
    view_cams = [store.cameras()[v] for v in views]
    lpips: LpipsMetric | LpipsUnavailable = load_lpips() if opts.lpips else LpipsUnavailable(f"LPIPS switched off ({WHERE}.lpips=false)")
    lpips = lpips_for((view_cams[0].height, view_cams[0].width), lpips)
    metric = lpips if isinstance(lpips, LpipsMetric) else None
    scores = {s: ImageScores(metric) for s in SPLITS}
    torch.manual_seed(ctx.seed)

    run = _run_predictor if use_predictor else _run_simulator
    videos, timings, extra = run(ctx, opts, store, split, views, view_cams, scores)

    if isinstance(lpips, LpipsMetric):
        timings["lpips_seconds"] = lpips.seconds
    metrics: dict[str, float] = {}
    curves: dict[str, list[float]] = {}
    for s in SPLITS:
        frames = split.scored(s)[2]
        metrics.update(scores[s].means(set(frames), prefix=f"{s}/"))
        curves.update({f"{s}/{k}": v for k, v in scores[s].curves(frames).items()})
    written = _write_videos(ctx.work_dir, opts, videos)
    for s, (i, truth, pred) in videos.items():  # each split's first trajectory, for the report's labelled animation
        name = "extrapolation" if s == "extrap" else "generalization"
        save_film(ctx.work_dir / f"dvc_multi_{s}{FILM_SUFFIX}", truth, pred, views, split.scored(s)[2], f"{name}, traj {i}",
                  f"{cfg.label or cfg.predictor or cfg.sim}: {name}, trajectory {i}, seed {ctx.seed}")  # fmt: skip
    images = {s: len(split.scored(s)[0]) * len(split.scored(s)[2]) * len(views) for s in SPLITS}
    extra.update(
        {
            "train_trajectories": split.train_ids,
            "test_trajectories": split.test_ids,
            "views": views,
            "extrap_frames": split.extrap_frames,
            "gen_context": split.gen_context,
            "gen_frames": split.gen_frames,
            "images": images,
            "lpips_unavailable": lpips.reason if isinstance(lpips, LpipsUnavailable) else None,
            "lpips_source": lpips.source if isinstance(lpips, LpipsMetric) else None,
            "lpips_files": [str(f) for f in lpips.files] if isinstance(lpips, LpipsMetric) else [],
            "videos": written,
        }
    )
    return TaskResult(metrics=metrics, timings=timings, curves=curves, extra=extra)


Videos = dict[str, tuple[int, np.ndarray, np.ndarray]]
"""Per split, its first trajectory: (index, truth, prediction), each (N,F,H,W,3) over the scored views and frames."""


def _run_predictor(
    ctx: TaskContext, opts: DvcMultiConfig, store: DatasetStore, split: MultiSplit, views: list[int],
    view_cams: list["Camera"], scores: dict[str, ImageScores],
) -> tuple[Videos, dict[str, float], dict[str, Any]]:  # fmt: skip
    """Train on the interpolation frames of every training trajectory's views; predict and score both splits."""
    cfg = ctx.config
    pred = build_predictor(ctx)
    check_context(str(cfg.predictor), pred, split)
    train_clips = {i: _read(store, i, split.observed + len(split.extrap_frames), views) for i in split.train_ids}
    train = training_videos(train_clips, split.observed)
    stats, timings = fit_predictor(ctx, pred, train, split.train_ids, views, split.observed)  # shared with Table 4's fit on the same videos
    predict_seconds, videos = 0.0, {}
    for s in SPLITS:
        ids, given, frames = split.scored(s)
        for i in ids:
            clip = train_clips[i] if s == "extrap" else _read(store, i, frames[-1] + 1, views)
            context = clip[:, :given]
            t0 = time.perf_counter()
            with plugin_call("video predictor", str(cfg.predictor), "predict", pred):
                raw = pred.predict(context, len(frames), view_cams)
            out = check_prediction(raw, context, len(frames), str(cfg.predictor))
            predict_seconds += time.perf_counter() - t0
            for k, t in enumerate(frames):
                scores[s].add(i, t, out[:, k], clip[:, t])
            videos.setdefault(s, (i, clip[:, frames], out))
    images = sum(len(split.scored(s)[0]) * len(split.scored(s)[2]) for s in SPLITS) * len(views)
    timings.update({"predict_seconds": predict_seconds, "predict_ms_per_frame": 1000.0 * predict_seconds / max(images, 1)})
    timings.update({f"fit/{k}": float(v) for k, v in stats.items()})
    return videos, timings, {"train_videos": len(train)}


def _run_simulator(
    ctx: TaskContext, opts: DvcMultiConfig, store: DatasetStore, split: MultiSplit, views: list[int],
    view_cams: list["Camera"], scores: dict[str, ImageScores],
) -> tuple[Videos, dict[str, float], dict[str, Any]]:  # fmt: skip
    """Table 4's simulator row on both splits: simulator trained on the training trajectories, one renderer fitted
    on frame 0 of each split's trajectories, rollouts from the initial mesh rendered at the scored frames.

    With a simulator learned from a reconstructed initial mesh every video runs on its own mesh and renderer instead:
    the training videos' from the pipeline, each unseen Generalization video's from stages 0-2 on its given frames
    0..gen_context-1 alone (its handles found in their motion). Then nothing of the ground truth is read."""
    cfg = ctx.config
    train_views = list(split_spec(ctx).train_views)
    train_cams = [store.cameras()[v] for v in train_views]
    if opts.sim_training == "mesh":  # refuse before training
        store.require_meshes(f"{WHERE}.sim_training=mesh (it trains the simulator on ground-truth meshes)")
    sim, timings, mode, recovered = train_simulator(ctx, opts.sim_training, list(split.train_ids), where=f"{WHERE}.sim_training")
    own = own_meshes(ctx, store, mode, recovered, split.train_ids, f"{WHERE}.num_train_trajectories")
    render_fit = render_s = rollout_s = 0.0
    rendered = steps = 0
    diverged: dict[str, int] = {}
    videos: Videos = {}
    for s in SPLITS:
        ids, given, frames = split.scored(s)
        t0 = time.perf_counter()
        if own:  # stage 1 per video, inside the pipeline: the training videos' cost is in the simulator's
            scene = recovered if s == "extrap" else recover_videos(ctx, list(ids), given)
            meshes: dict[int, Any] = {i: scene[i].mesh for i in ids}
            renderers = {i: scene[i].renderer for i in ids}
        else:
            meshes = {i: store.load_trajectory(i) for i in ids}
            first = np.stack([to_float(store.frames(i)[0, train_views]) for i in ids])
            renderer, stats = fit_renderer(ctx, list(meshes.values()), first, train_cams)
            timings.update({f"render_fit/{s}/{k}": float(v) for k, v in stats.items()})
            renderers = {i: renderer for i in ids}
        render_fit += time.perf_counter() - t0
        for i, traj in meshes.items():
            clip = _read(store, i, frames[-1] + 1, views)
            # Algorithm S2: from the initial mesh, as far as scored
            inp = own_rollout_input(traj, 0, frames[-1] + 1) if own else RolloutInput.from_trajectory(traj, frames[-1] + 1)
            t0 = time.perf_counter()
            mesh = rollout_checked(sim, inp, str(cfg.sim))
            rollout_s += time.perf_counter() - t0
            steps += inp.num_frames - 2
            bad = divergence_step(mesh)
            if bad is not None:  # a blown-up rollout is data: the last finite mesh stands in for the rest, and it is recorded
                diverged[f"{s}/{i}"] = bad
                mesh[bad:] = mesh[bad - 1]
            out = []
            for t in frames:
                t0 = time.perf_counter()
                with torch.no_grad(), plugin_call("renderer", str(cfg.renderer), "render", renderers[i]):
                    img = renderers[i].render(torch.from_numpy(mesh[t]), view_cams)
                render_s += time.perf_counter() - t0
                rendered += len(view_cams)
                img = as_images(img, (len(view_cams), *clip.shape[2:]), where=f"renderer '{cfg.renderer}', trajectory {i}, frame {t}")
                scores[s].add(i, t, img, clip[:, t])
                out.append(img)
            videos.setdefault(s, (i, clip[:, frames], np.stack(out, axis=1)))
    timings.update(
        {
            "fit_seconds": timings["sim_fit_seconds"] + render_fit,
            "render_fit_seconds": render_fit,
            "render_ms_per_frame": 1000.0 * render_s / max(rendered, 1),
            "rollout_ms_per_step": 1000.0 * rollout_s / max(steps, 1),
            "predict_ms_per_frame": 1000.0 * (rollout_s / max(steps, 1) / len(view_cams) + render_s / max(rendered, 1)),
        }
    )
    return videos, timings, {"diverged": diverged, "sim_training": mode, "mesh": "reconstructed (per video)" if own else "ground truth"}


def _write_videos(work: Path, opts: DvcMultiConfig, videos: Videos) -> list[str]:
    """Per split, a truth-above-prediction video of its first trajectory."""
    if opts.video_format == "none":
        return []
    return [
        str(write_video(work / f"dvc_multi_{s}_traj{i}.{opts.video_format}", video_frames(truth, pred), opts.video_fps))
        for s, (i, truth, pred) in videos.items()
    ]
