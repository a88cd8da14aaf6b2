"""Mesh extraction (CloDS stages 1-2 alone): how well the renderer recovers the cloth meshes from video.

The paper's ablations of the SMGS opacity inputs (Fig. 6b) and of the edge loss (appendix figure
'Error accumulation in mesh extraction') measure this quantity, E-GT: the RMSE of the extracted
against the true mesh per frame. Here the same stages the CDG task runs (cached, shared with it)
are scored without training a simulator, so camera counts, Gaussian densities and noise settings
can be swept at the cost of the extraction alone. Each seed is an extraction seed (stage-1
initialisation, initial-mesh noise): `task_config.clods.extraction_seed` is ignored here.

A dataset without meshes (imported from video) has no E-GT: with `task_config.clods.initial_mesh=reconstructed`
stages 0-2 run on video alone and are scored in images instead. Each video's extracted meshes (frames 1..interp)
are rendered by the renderer stage 1 fitted on its frame 0 and compared with the frames of the held-out cameras,
which stages 0-2 never see, so a wrong depth shows (`psnr`, `ssim`, `lpips`, `rmse`), and of the training cameras
stage 2 fitted (`train/...`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from clods_bench.benchmark.core.descriptors import TaskContext, TaskResult
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.benchmark.outputs.mesh_pictures import save_mesh_sample
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

WHERE = "task_config.extract"


@dataclass(frozen=True)
class ExtractConfig:
    """Options of the extract task (`task_config.extract.*`); the extraction itself is `task_config.clods.*`."""

    num_trajectories: int | None = None
    """Extract the first k videos of the row's training set (`train_subset`); None: all of them."""
    lpips: bool = True
    """A dataset without meshes: compute LPIPS of the re-rendered extraction when its weights are installed."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when it is out of range."""
        if self.num_trajectories is not None and self.num_trajectories < 1:
            raise ClodsError(f"must be >= 1 or null, got {self.num_trajectories}", where=f"{WHERE}.num_trajectories")


def extract_config(ctx: TaskContext) -> ExtractConfig:
    """The run's `task_config.extract` as a checked ExtractConfig."""
    opts: ExtractConfig = dataclass_from_dict(ExtractConfig, dict(ctx.config.task_config.get("extract", {})), where=WHERE, prefix="extract.")
    opts.validate()
    return opts


def _seeded(ctx: TaskContext) -> TaskContext:
    """`ctx` whose CloDS options take the extraction seed from the run's seed."""
    cfg = ctx.config
    clods = {**cfg.task_config.get("clods", {}), "extraction_seed": None}
    return dataclasses.replace(ctx, config=dataclasses.replace(cfg, task_config={**cfg.task_config, "clods": clods}))


def run_extract(ctx: TaskContext) -> TaskResult:
    """One seed: stages 1-2 on the row's training videos; E-GT over the frames (mean, at the end, per phase)."""
    from clods_bench.benchmark.clods.pipeline import extract_meshes, video_train_ids
    from clods_bench.datasets.store import DatasetStore

    store = DatasetStore.open(ctx.config.data.dataset_dir())
    opts = extract_config(ctx)
    ctx = _seeded(ctx)
    ids = video_train_ids(ctx)
    if opts.num_trajectories is not None:
        ids = ids[: opts.num_trajectories]
    ext = extract_meshes(ctx, ids)
    if ext.egt is None:  # no meshes: scored in images
        return _scored_in_images(ctx, opts, store, ids, ext)
    egt = ext.egt  # (B, frames); frame 0 is the given initial mesh
    half = max(1, egt.shape[1] // 2)
    same = [m.world_pos.shape[1:] == t.world_pos.shape[1:] for m, t in zip(ext.meshes, ext.truth)]  # else a reconstructed mesh
    strain = [_max_strain(m.world_pos, t.world_pos[0] if s else m.world_pos[0], m.cells) for m, t, s in zip(ext.meshes, ext.truth, same)]
    metrics = {
        "egt_avg": float(egt[:, 1:].mean()),
        "egt_end": float(egt[:, -1].mean()),
        "egt_first_half": float(egt[:, 1:half + 1].mean()),
        "egt_second_half": float(egt[:, half + 1 :].mean()) if egt.shape[1] > half + 1 else float("nan"),
        "edge_strain_max": float(max(strain)),
    }
    timings = _timings(ext.stats)
    curves = {"egt": egt.mean(axis=0).tolist()}
    label = ctx.config.label or "extracted"
    save_mesh_sample(ctx.work_dir / "extraction_meshes.npz", ext.meshes[0].cells, {"extracted (stage 2)": ext.meshes[0].world_pos},
                     truth=ext.truth[0].world_pos if same[0] else None, title=f"{label}: meshes extracted from video {ids[0]}, seed {ctx.seed}")  # fmt: skip
    extra = {"trajectories": list(ids), "egt_per_trajectory": {str(i): float(c[1:].mean()) for i, c in zip(ids, egt)}, "cache": ext.key}
    return TaskResult(metrics=metrics, timings=timings, curves=curves, extra=extra)


def _timings(stats: dict[str, float]) -> dict[str, float]:
    """Cost of stages 1-2 (cached parts at their recorded cost; a stage-1 cache without one counts 0)."""
    stage1 = float(stats.get("stage1_cost_seconds", 0.0))
    stage1 = stage1 if np.isfinite(stage1) else 0.0
    return {
        "fit_seconds": stage1 + float(stats["stage2_seconds"]),
        "stage1_seconds": stage1,
        "stage2_seconds": float(stats["stage2_seconds"]),
        "stage2_ms_per_frame": float(stats["stage2_ms_per_frame"]),
        "stage2_iterations_per_frame": float(stats["stage2_iterations_per_frame"]),
    }


def _scored_in_images(ctx: TaskContext, opts: ExtractConfig, store: Any, ids: list[int], ext: Any) -> TaskResult:
    """Stages 0-2 on a dataset without meshes: the extracted meshes of frames 1..interp rendered by each video's
    stage-1 renderer, scored against the held-out cameras' frames (unseen by stages 0-2) and the training ones'."""
    import torch

    from clods_bench.benchmark.clods.video_runs import ImageScores, to_float
    from clods_bench.benchmark.core.builders import as_images, split_spec
    from clods_bench.benchmark.scoring.image_metrics import LpipsMetric, LpipsUnavailable, load_lpips, lpips_for

    splits, rig = split_spec(ctx), store.cameras()
    groups = {"": list(splits.test_views), "train/": list(splits.train_views)}
    groups = {k: v for k, v in groups.items() if v}
    h, w = rig[0].height, rig[0].width
    lpips: LpipsMetric | LpipsUnavailable = load_lpips() if opts.lpips else LpipsUnavailable(f"LPIPS switched off ({WHERE}.lpips=false)")
    lpips = lpips_for((h, w), lpips)
    scores = {k: ImageScores(lpips if isinstance(lpips, LpipsMetric) else None) for k in groups}
    frames = list(range(1, ext.meshes[0].num_steps))
    for i, mesh, renderer in zip(ids, ext.meshes, ext.renderers):
        for prefix, views in groups.items():
            cams = [rig[v] for v in views]
            clip = store.frames(i).select(slice(0, mesh.num_steps), views)  # lazy: one frame at a time (paper videos are GBs)
            for t in frames:
                with torch.no_grad(), plugin_call("renderer", str(ctx.config.renderer), "render", renderer):
                    out = renderer.render(torch.from_numpy(np.ascontiguousarray(mesh.world_pos[t])), cams)
                img = as_images(out, (len(cams), h, w, 3), where=f"renderer '{ctx.config.renderer}', trajectory {i}, frame {t}")
                scores[prefix].add(i, t, img, to_float(clip[t]))
    metrics: dict[str, float] = {}
    for prefix, sc in scores.items():
        metrics.update(sc.means(None, prefix=prefix))
    metrics["edge_strain_max"] = float(max(_max_strain(m.world_pos, m.world_pos[0], m.cells) for m in ext.meshes))
    first = next(iter(scores))
    curves = {f"{first}psnr": scores[first].curves(frames)["psnr"]}  # per frame, the scored cameras first
    label = ctx.config.label or "extracted"
    save_mesh_sample(ctx.work_dir / "extraction_meshes.npz", ext.meshes[0].cells, {"extracted (stage 2)": ext.meshes[0].world_pos},
                     title=f"{label}: meshes extracted from video {ids[0]}, seed {ctx.seed}")  # fmt: skip
    extra = {
        "trajectories": list(ids), "cache": ext.key, "scored_views": {k or "held-out": v for k, v in groups.items()},
        "lpips_unavailable": lpips.reason if isinstance(lpips, LpipsUnavailable) else None,
        "nodes": [m.num_nodes for m in ext.meshes], "handles": [int(np.sum(m.node_type != 0)) for m in ext.meshes],
    }  # fmt: skip
    return TaskResult(metrics=metrics, timings=_timings(ext.stats), curves=curves, extra=extra)


def _max_strain(frames: np.ndarray, first: np.ndarray, cells: np.ndarray) -> float:
    """Largest |l / l_first - 1| over the mesh edges and frames: how far the extraction stretched the cloth."""
    from clods_bench.datasets.types import edges_from_cells

    e = edges_from_cells(np.asarray(cells))
    x = np.asarray(frames, np.float64)
    l0 = np.linalg.norm(np.asarray(first, np.float64)[e[:, 0]] - np.asarray(first, np.float64)[e[:, 1]], axis=1)
    lengths = np.linalg.norm(x[:, e[:, 0]] - x[:, e[:, 1]], axis=2)
    return float(np.abs(lengths / np.maximum(l0, 1e-12) - 1.0).max())
