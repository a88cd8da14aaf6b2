"""Initial mesh (CloDS stage 0): how well the first frame's images alone give the cloth mesh CloDS starts from.

Stage 0 (`clods.stage0`: 2DGS surfels on frame 0 of the training cameras, median depth, TSDF fusion, a
simulation-ready sheet) runs on each of the row's training videos; its mesh has its own topology, so it is
scored across topologies (`cross_topology`): each true node's distance to the reconstructed surface (the
attached-point RMSE at frame 0) and the symmetric Chamfer distance between the true and reconstructed nodes.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from clods_bench.benchmark.builders import split_spec
from clods_bench.benchmark.clods.stage0 import Stage0Config, reconstruct_initial_mesh
from clods_bench.benchmark.config import dataclass_from_dict
from clods_bench.benchmark.cross_topology import attach, chamfer
from clods_bench.benchmark.descriptors import TaskContext, TaskResult
from clods_bench.benchmark.mesh_pictures import save_mesh_sample
from clods_bench.datasets.store import DatasetStore

WHERE = "task_config.initial_mesh"


def initial_mesh_config(ctx: TaskContext) -> Stage0Config:
    """The run's `task_config.initial_mesh` as a checked Stage0Config; the run's seed seeds it unless it sets one."""
    raw = dict(ctx.config.task_config.get("initial_mesh", {}))
    cfg: Stage0Config = dataclass_from_dict(Stage0Config, raw, where=WHERE, prefix="initial_mesh.")
    if "seed" not in raw:
        cfg = dataclasses.replace(cfg, seed=int(ctx.seed))
    cfg.validate()
    return cfg


def run_initial_mesh(ctx: TaskContext) -> TaskResult:
    """One seed: stage 0 on frame 0 of every training video (training cameras only), scored against the true mesh."""
    cfg = ctx.config
    opts = initial_mesh_config(ctx)
    store = DatasetStore.open(cfg.data.dataset_dir())
    store.require_meshes("task initial_mesh (scored against the true frame-0 mesh)")
    splits = split_spec(ctx)
    views = list(splits.train_views)
    rig = store.cameras()
    cameras = [rig[v] for v in views]
    ids = list(splits.train if cfg.train_subset == "all" else splits.first_half)
    rmse, cham, seconds, nodes, per_traj = [], [], [], [], {}
    sample = None
    for i in ids:
        truth = store.load_trajectory(i)
        images = store.frames(i).read([0], views)[0]
        t0 = time.perf_counter()
        mesh, stats = reconstruct_initial_mesh(images, cameras, opts, opts.num_nodes or truth.num_nodes)
        seconds.append(time.perf_counter() - t0)
        gt = truth.world_pos[0].astype(np.float64)
        att = attach(gt, mesh.rest_pos, mesh.cells)
        rmse.append(float(np.sqrt(np.mean(att.distance**2))))
        cham.append(chamfer(gt, mesh.rest_pos))
        nodes.append(mesh.num_nodes)
        per_traj[str(i)] = {"attached_rmse": rmse[-1], "chamfer": cham[-1], "nodes": mesh.num_nodes, **stats}
        if sample is None:
            sample = (i, truth, mesh)
    size = float(np.ptp(sample[1].world_pos[0], axis=0).max())  # the first video's cloth extent at frame 0
    metrics = {
        "attached_rmse": float(np.mean(rmse)),
        "attached_rmse_rel": float(np.mean(rmse)) / size,
        "chamfer": float(np.mean(cham)),
        "nodes": float(np.mean(nodes)),
    }
    timings = {"fit_seconds": float(np.sum(seconds)), "seconds_per_mesh": float(np.mean(seconds))}
    i, truth, mesh = sample
    save_mesh_sample(ctx.work_dir / "initial_mesh.npz", mesh.cells, {"reconstructed (stage 0)": mesh.rest_pos[None].astype(np.float32)},
                     title=f"{cfg.label or 'stage 0'}: initial mesh from the frame-0 images of trajectory {i}, seed {ctx.seed}")  # fmt: skip
    extra = {"trajectories": ids, "views": views, "per_trajectory": per_traj, "cloth_size": size}
    return TaskResult(metrics=metrics, timings=timings, curves={}, extra=extra)
