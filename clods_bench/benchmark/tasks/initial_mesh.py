"""Initial mesh (CloDS stage 0): how well the first frame's images alone give the cloth mesh CloDS starts from.

Stage 0 (`clods.stage0`: 2DGS surfels on frame 0 of the training cameras, median depth, TSDF fusion, a
simulation-ready sheet) runs on each of the row's training videos; its mesh has its own topology, so it is
scored across topologies (`cross_topology`): each true node's distance to the reconstructed surface (the
attached-point RMSE at frame 0) and the symmetric Chamfer distance between the true and reconstructed nodes. A
dataset without meshes (imported from video) scores it by its silhouette in the held-out cameras, which stage 0
never sees (`heldout_iou`: the intersection over union with the cloth's pixels, 1 is a perfect outline).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from clods_bench.benchmark.clods.config import clods_config
from clods_bench.benchmark.clods.reconstructed import stage0_mesh
from clods_bench.benchmark.clods.stage0 import Stage0Config, foreground_masks
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.builders import split_spec
from clods_bench.benchmark.core.descriptors import TaskContext, TaskResult
from clods_bench.benchmark.outputs.mesh_pictures import save_mesh_sample
from clods_bench.benchmark.scoring.cross_topology import attach, chamfer
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.rasterizer import render_depth
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import ClothMesh
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

WHERE = "task_config.initial_mesh"


def initial_mesh_device_options(cfg: Any) -> dict[str, type]:
    """The task's `TaskSpec.device_options`: its stage-0 options (`task_config.initial_mesh`, the surfel backend)."""
    return {"initial_mesh": Stage0Config}


def initial_mesh_config(ctx: TaskContext) -> Stage0Config:
    """The run's `task_config.initial_mesh` as a checked Stage0Config; the run's seed seeds it unless it sets one."""
    raw = dict(ctx.config.task_config.get("initial_mesh", {}))
    cfg: Stage0Config = dataclass_from_dict(Stage0Config, raw, where=WHERE, prefix="initial_mesh.")
    if "seed" not in raw:
        cfg = dataclasses.replace(cfg, seed=int(ctx.seed))
    cfg.validate()
    return cfg


def run_initial_mesh(ctx: TaskContext) -> TaskResult:
    """One seed: stage 0 on frame 0 of every training video (training cameras only), scored against the true mesh,
    or, on a dataset without meshes, by its silhouette in the held-out cameras."""
    cfg = ctx.config
    opts = initial_mesh_config(ctx)
    store = DatasetStore.open(cfg.data.dataset_dir())
    if not store.has_meshes and opts.num_nodes is None:
        raise ClodsError("the dataset has no meshes to take the node count from", where=f"{WHERE}.num_nodes", hint=f"set it, e.g. {WHERE}.num_nodes=300")
    splits = split_spec(ctx)
    views = list(splits.train_views)
    rig = store.cameras()
    cameras = [rig[v] for v in views]
    ids = list(splits.train if cfg.train_subset == "all" else splits.first_half)
    rmse, cham, iou, seconds, nodes, per_traj = [], [], [], [], [], {}
    sample = None
    for i in ids:
        truth = store.load_trajectory(i) if store.has_meshes else None
        images = store.frames(i).read([0], views)[0]
        mesh, stats = stage0_mesh(ctx, clods_config(cfg), opts, i, images, cameras, opts.num_nodes or truth.num_nodes)
        seconds.append(stats["stage0_cost_seconds"])  # a mesh another row reconstructed from these images is shared
        stage_digests.record("extraction", [mesh.rest_pos, mesh.cells])
        nodes.append(mesh.num_nodes)
        per_traj[str(i)] = {"nodes": mesh.num_nodes, **stats}
        if truth is not None:
            gt = truth.world_pos[0].astype(np.float64)
            att = attach(gt, mesh.rest_pos, mesh.cells)
            rmse.append(float(np.sqrt(np.mean(att.distance**2))))
            cham.append(chamfer(gt, mesh.rest_pos))
            per_traj[str(i)].update({"attached_rmse": rmse[-1], "chamfer": cham[-1]})
        elif splits.test_views:  # no truth: the silhouette in the cameras stage 0 never saw
            held = list(splits.test_views)
            iou.append(silhouette_iou(mesh, store.frames(i).read([0], held)[0], [rig[v] for v in held], opts.background_threshold))
            per_traj[str(i)]["heldout_iou"] = iou[-1]
        if sample is None:
            sample = (i, truth, mesh)
    metrics = {"nodes": float(np.mean(nodes))}
    extra: dict[str, Any] = {"trajectories": ids, "views": views, "per_trajectory": per_traj}
    if rmse:
        size = float(np.ptp(sample[1].world_pos[0], axis=0).max())  # the first video's cloth extent at frame 0
        metrics.update({"attached_rmse": float(np.mean(rmse)), "attached_rmse_rel": float(np.mean(rmse)) / size, "chamfer": float(np.mean(cham))})
        extra["cloth_size"] = size
    if iou:
        metrics["heldout_iou"] = float(np.mean(iou))
        extra["heldout_views"] = list(splits.test_views)
    timings = {"fit_seconds": float(np.sum(seconds)), "seconds_per_mesh": float(np.mean(seconds))}
    i, truth, mesh = sample
    save_mesh_sample(ctx.work_dir / "initial_mesh.npz", mesh.cells, {"reconstructed (stage 0)": mesh.rest_pos[None].astype(np.float32)},
                     title=f"{cfg.label or 'stage 0'}: initial mesh from the frame-0 images of trajectory {i}, seed {ctx.seed}")  # fmt: skip
    return TaskResult(metrics=metrics, timings=timings, curves={}, extra=extra)


def silhouette_iou(mesh: ClothMesh, images: np.ndarray, cameras: Sequence[Camera], threshold: float) -> float:
    """Mean over `cameras` of the intersection over union of the mesh's silhouette (pixel centres it covers) and the
    cloth's (pixels away from the white background by more than `threshold`, as stage 0 reads them) in `images`."""
    img = np.asarray(images, np.float64) / 255.0
    masks = foreground_masks(img, (1.0, 1.0, 1.0), threshold)
    scores = []
    for mask, cam in zip(masks, cameras):
        drawn = np.isfinite(render_depth(mesh.rest_pos, mesh.cells, cam))
        union = int((drawn | mask).sum())
        scores.append(float((drawn & mask).sum()) / union if union else 1.0)
    return float(np.mean(scores))
