"""Where stage 0's error comes from, per training video of a preset: the surfels' depth, or the sheet step.

For frame 0 of each training trajectory, seen by the training cameras (as `run initial_mesh` does), prints the
attached RMSE (% of the cloth's size) of the sheet (isomap / plane parameterisation, `sheet_mesh`) built from
  1. the fitted surfels' median-depth maps (stage 0 as it runs, Stage0Config defaults, seed 0), and that isomap
     sheet after its refinement against the images (`sheet_refine`, the default step of stage 0),
  2. perfect depth maps (the true mesh rasterised into the same views), with the RMSE of the fused points to the
     true surface beside it (what the TSDF gives the sheet step),
  3. 20,000 points sampled on the true surface (no views at all: the sheet step's own floor),
and how far the cloth turns over: the largest cosine between a true face normal and the normal of the points'
best-fit plane, once the normals are signed to agree with that plane normal on average (above 0 somewhere: the cloth folds
over itself relative to the plane, which a height field over that plane cannot hold).

    python examples/studies/stage0_error_sources.py [preset]    # default ci; needs `data generate --preset <preset>`
"""

from __future__ import annotations

import sys
import time

import numpy as np
import torch
from scipy.spatial import cKDTree

from clods_bench.benchmark.clods import stage0 as S
from clods_bench.benchmark.clods.sheet_mesh import sheet_from_points
from clods_bench.benchmark.clods.sheet_refine import refine_sheet
from clods_bench.benchmark.clods.sheet_uv import best_plane
from clods_bench.benchmark.clods.tsdf import backproject, extract_surface, fuse_depth_maps, trim_to_support
from clods_bench.benchmark.core.builders import data_splits
from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.scoring.cross_topology import attach
from clods_bench.datasets.rasterizer import render_depth
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import ClothMesh
from clods_bench.splatting.surfel_fit import fit_surfels, surfel_depth_maps


def sample_surface(verts: np.ndarray, cells: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """n points uniformly (by area) on the triangles."""
    rng = np.random.default_rng(seed)
    tri = verts[cells]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    f = rng.choice(len(cells), n, p=area / area.sum())
    return np.einsum("nkx,nk->nx", tri[f], rng.dirichlet(np.ones(3), n))


def sheet_error(points: np.ndarray, gt: np.ndarray, num_nodes: int) -> tuple[float, float, ClothMesh]:
    """Attached RMSE (m) of the true nodes to the sheet made from `points`: (isomap sheet, plane sheet, the isomap sheet)."""
    out, meshes = [], []
    for par in ("isomap", "plane"):
        meshes.append(sheet_from_points(points, num_nodes, parameterization=par))
        out.append(float(np.sqrt(np.mean(attach(gt, meshes[-1].rest_pos, meshes[-1].cells).distance ** 2))))
    return out[0], out[1], meshes[0]


def fused_points(depth: np.ndarray, cameras, voxel: float) -> np.ndarray:
    """TSDF fusion + marching cubes + trimming, as stage 0 does: the points the sheet step receives."""
    verts, faces = extract_surface(fuse_depth_maps(depth, cameras, None, voxel, orient=True))
    return trim_to_support(verts, faces, backproject(depth, cameras), 2.0 * voxel)[0]


def main(preset: str) -> None:
    torch.set_num_threads(1)
    cfg = load_config(preset)
    store = DatasetStore.open(cfg.data.dataset_dir())
    splits = data_splits(cfg.data)
    rig = store.cameras()
    cams = [rig[v] for v in splits.train_views]
    opts = S.Stage0Config()
    print(f"preset {preset}: trajectories {list(splits.train)}, views {list(splits.train_views)}")
    print("traj | refined % | surfels % | perfect depth % (fused points to truth, m) | true points % | max signed cos   (% as isomap / plane sheet)")
    for i in splits.train:
        truth = store.load_trajectory(i)
        gt = truth.world_pos[0].astype(np.float64)
        cells = np.asarray(truth.cells, np.int64)
        size = float(np.ptp(gt, axis=0).max())
        img = store.frames(i).read([0], list(splits.train_views))[0].astype(np.float64) / 255.0
        masks = S.foreground_masks(img, (1.0, 1.0, 1.0), opts.background_threshold)
        centre = S.look_at_point(cams)
        dist = np.median([np.linalg.norm(-np.asarray(c.R).T @ np.asarray(c.t).reshape(3) - centre) for c in cams])
        half = 0.4 * float(dist)
        cell = 2.0 * half / (opts.hull_resolution - 1)
        hull = S.visual_hull(masks, cams, centre, half, opts.hull_resolution)
        rng = np.random.default_rng(opts.seed)
        pick = rng.choice(hull.shape[0], size=min(opts.num_surfels, hull.shape[0]), replace=False)
        init = hull[pick] + rng.uniform(-0.5 * cell, 0.5 * cell, (pick.size, 3))
        t0 = time.perf_counter()
        params, _ = fit_surfels(torch.from_numpy(img), cams, torch.from_numpy(init), None, opts.iterations,
                                background=(1.0, 1.0, 1.0), lambda_dssim=opts.lambda_dssim, seed=opts.seed)  # fmt: skip
        depth, alpha = (a.numpy() for a in surfel_depth_maps(params, cams))
        fit_s = time.perf_counter() - t0
        surf = np.where((alpha > 0.5) & (depth > 0) & masks, depth, np.inf)
        voxel = 0.5 * cell
        *e_surf, sheet = sheet_error(fused_points(surf, cams, voxel), gt, truth.num_nodes)
        refined, _ = refine_sheet(sheet.rest_pos, sheet.cells, img, masks, cams, opts.refine_options())
        e_refined = float(np.sqrt(np.mean(attach(gt, refined, sheet.cells).distance ** 2)))
        true_depth = np.stack([render_depth(gt, cells, c) for c in cams])
        perfect = np.where(np.isfinite(true_depth) & masks, true_depth, np.inf)
        pts = fused_points(perfect, cams, voxel)
        e_perfect = sheet_error(pts, gt, truth.num_nodes)[:2]
        dense = sample_surface(gt, cells, 20000)
        on_truth = float(np.sqrt(np.mean(cKDTree(dense).query(pts)[0] ** 2)))
        e_true = sheet_error(dense, gt, truth.num_nodes)[:2]
        _, axes = best_plane(dense)
        tri = gt[cells]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        cos = (n / np.linalg.norm(n, axis=1, keepdims=True)) @ axes[2]
        cos *= -1.0 if cos.mean() > 0 else 1.0  # sign so that the plane's normal side is negative on average
        pct = lambda e: f"{100 * e[0] / size:.2f} / {100 * e[1] / size:.2f}"  # noqa: E731
        print(f"{i} | {100 * e_refined / size:.2f} | {pct(e_surf)} (fit {fit_s:.0f} s) | {pct(e_perfect)} ({on_truth:.4f}) | {pct(e_true)} | {cos.max():+.2f}",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "ci")
