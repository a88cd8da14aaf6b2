"""Stage 0 of CloDS: the initial cloth mesh from the first frame's multi-view images alone.

The paper's appendix algorithm ("Initial mesh extraction from first-frame NeRF-style data using 2D Gaussian
Splatting"): fit 2DGS surfels to frame 0 of the training cameras, render their median-depth maps, fuse them
by TSDF and extract the surface; then the step the paper leaves out, a simulation-ready sheet (one open
manifold mesh of a chosen node count, rest coordinates from a flattening; `sheet_mesh`). The surfels start
on the visual hull of the cloth's silhouettes (foreground = pixels away from the known background colour),
carved on a voxel grid around the point the cameras look at: nothing of the ground-truth mesh is used.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Literal, Sequence

import numpy as np
import torch

from clods_bench.benchmark.clods.sheet_mesh import sheet_from_points, with_rest_positions
from clods_bench.benchmark.clods.sheet_refine import RefineOptions, refine_sheet
from clods_bench.benchmark.clods.sheet_uv import PARAMETERIZATIONS
from clods_bench.benchmark.clods.tsdf import backproject, extract_surface, fuse_depth_maps, trim_to_support
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.types import ClothMesh
from clods_bench.errors import ClodsError
from clods_bench.splatting.surfel_fit import fit_surfels, surfel_depth_maps

WHERE = "task_config.initial_mesh"


@dataclass(frozen=True)
class Stage0Config:
    """Options of the initial-mesh reconstruction (`task_config.initial_mesh`).

    Defaults measured at `ci` (4 views of 64 px, the flag's frame 0): 300 iterations without D-SSIM take 11 s a
    frame; with D-SSIM (2DGS's 0.2) 36 s for the same error; 600 iterations or 3000 surfels did not help (README)."""

    num_surfels: int = 1500
    """Surfels fitted to frame 0 (sampled from the visual hull)."""
    iterations: int = 300
    """Adam iterations of the surfel fit."""
    hull_resolution: int = 64
    """Voxels per side of the visual-hull grid (a cube around the cameras' look-at point)."""
    background_threshold: float = 0.08
    """A pixel is cloth when a channel differs from the background colour by more than this (images in [0, 1])."""
    voxel_size: float | None = None
    """TSDF voxel (m); None: the hull grid's cell size / 2."""
    num_nodes: int | None = None
    """Nodes of the sheet mesh; None: the ground-truth mesh's count where one exists (else an error)."""
    lambda_dssim: float = 0.0
    """Weight of the D-SSIM term of the surfel fit (2DGS uses 0.2; at ci it triples the time and changes nothing)."""
    seed: int = 0
    """Seed of the surfel initialisation and the hull sampling."""
    backend: Literal["cpu", "gsplat"] = "cpu"
    """Surfel renderer of the fit: 'cpu' (numba) or 'gsplat' (gsplat's 2DGS kernels on a CUDA GPU; depth is then
    each surfel's centre depth, see `splatting/surfel_gsplat.py`)."""
    sheet: str = "isomap"
    """Parameterisation of the sheet mesh (`sheet_mesh.sheet_from_points`): 'isomap' (geodesic: a flag whose free end
    curls over itself unrolls) or 'plane' (a height field over the points' best-fit plane; the layers of a curl are
    averaged). At ci, 2.69 % against 2.98 % of the cloth's size over the 4 training videos (README)."""
    refine_iterations: int = 150
    """Adam iterations of the sheet's refinement against the frame-0 images (`sheet_refine`: silhouettes and
    multi-view photo-consistency); 0 keeps the sheet as fused. At ci it takes the sheet from 2.7 % to 1.8 % (README)."""
    refine_lr: float = 0.01
    """Adam step of the refinement (metres)."""
    refine_silhouette_weight: float = 1.0
    """Weight of the silhouette term (squared pixels)."""
    refine_photo_weight: float = 10.0
    """Weight of the photo-consistency term (colour variance across the views that see a point; colours in [0, 1])."""
    refine_edge_weight: float = 1.0
    """Weight of the edge lengths' tie to the fused sheet's (relative to the mean edge length, squared)."""
    refine_laplacian_weight: float = 10.0
    """Weight of the Laplacian's tie to the fused sheet's (relative to the mean edge length, squared): it keeps the
    triangles' shapes (at 0.1 the nodes slid along the cloth into slivers, README)."""
    refine_blur: float = 0.5
    """Gaussian blur (pixels) of the images the photo-consistency term samples."""
    refine_visibility: float = 0.4
    """A point is seen by a view when it lies within this many mean edge lengths behind the sheet's z-buffer there."""

    def refine_options(self) -> RefineOptions:
        """The `refine_*` fields as the options of `sheet_refine.refine_sheet`."""
        return RefineOptions(
            iterations=self.refine_iterations, lr=self.refine_lr, silhouette_weight=self.refine_silhouette_weight,
            photo_weight=self.refine_photo_weight, edge_weight=self.refine_edge_weight,
            laplacian_weight=self.refine_laplacian_weight, blur=self.refine_blur, visibility=self.refine_visibility,
        )  # fmt: skip

    def validate(self) -> None:
        """Raise ClodsError naming the first field out of range."""
        for name, ok in (
            ("num_surfels", self.num_surfels >= 16),
            ("iterations", self.iterations >= 1),
            ("hull_resolution", self.hull_resolution >= 8),
            ("background_threshold", 0 < self.background_threshold < 1),
            ("voxel_size", self.voxel_size is None or self.voxel_size > 0),
            ("num_nodes", self.num_nodes is None or self.num_nodes >= 4),
            ("lambda_dssim", 0 <= self.lambda_dssim <= 1),
            ("backend", self.backend in ("cpu", "gsplat")),
            ("sheet", self.sheet in PARAMETERIZATIONS),
            ("refine_iterations", self.refine_iterations >= 0),
            ("refine_lr", self.refine_lr > 0),
            ("refine_silhouette_weight", self.refine_silhouette_weight >= 0),
            ("refine_photo_weight", self.refine_photo_weight >= 0),
            ("refine_edge_weight", self.refine_edge_weight >= 0),
            ("refine_laplacian_weight", self.refine_laplacian_weight >= 0),
            ("refine_blur", self.refine_blur >= 0),
            ("refine_visibility", self.refine_visibility > 0),
        ):
            if not ok:
                raise ClodsError(f"value {getattr(self, name)!r} is out of range", where=f"{WHERE}.{name}")


def foreground_masks(images: np.ndarray, background: Sequence[float], threshold: float) -> np.ndarray:
    """(C,H,W) bool: pixels whose colour differs from `background` by more than `threshold` in some channel."""
    img = np.asarray(images, np.float64)
    return (np.abs(img - np.asarray(background, np.float64)[None, None, None, :]) > threshold).any(axis=-1)


def look_at_point(cameras: Sequence[Camera]) -> np.ndarray:
    """The least-squares closest point to every camera's optical axis (where a rig looks)."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        R, t = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64).reshape(3)
        centre, axis = -R.T @ t, R[2]  # camera centre and its +z axis in world coordinates
        proj = np.eye(3) - np.outer(axis, axis)
        a += proj
        b += proj @ centre
    return np.linalg.lstsq(a, b, rcond=None)[0]


def visual_hull(masks: np.ndarray, cameras: Sequence[Camera], centre: np.ndarray, half_extent: float, resolution: int) -> np.ndarray:
    """Centres (N,3) of the voxels of a cube (side 2 half_extent around `centre`) that project onto the cloth in
    every camera whose image they fall in, and fall in all but at most one image (a cloth partly out of one view
    keeps that part; space seen by fewer views is not kept)."""
    axis = np.linspace(-half_extent, half_extent, resolution)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3) + centre[None, :]
    keep = np.ones(grid.shape[0], dtype=bool)
    seen = np.zeros(grid.shape[0], dtype=np.int64)
    for mask, cam in zip(masks, cameras):
        pix, z = cam.project(grid)
        col, row = np.floor(pix[:, 0]).astype(np.int64), np.floor(pix[:, 1]).astype(np.int64)
        inside = (z > 0) & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
        hit = np.zeros(grid.shape[0], dtype=bool)
        hit[inside] = mask[row[inside], col[inside]]
        keep &= hit | ~inside
        seen += inside
    return grid[keep & (seen >= max(len(cameras) - 1, 1))]


def reconstruct_initial_mesh(
    images: np.ndarray, cameras: Sequence[Camera], cfg: Stage0Config, num_nodes: int, background: Sequence[float] = (1.0, 1.0, 1.0)
) -> tuple[ClothMesh, dict[str, Any]]:
    """The cloth mesh of frame 0 from its images (C,H,W,3) uint8 or float in [0,1] seen by `cameras`; and timings."""
    cfg.validate()
    img = np.asarray(images)
    if img.ndim != 4 or img.shape[-1] != 3 or img.shape[0] != len(cameras):
        raise ClodsError(f"images have shape {img.shape}, expected ({len(cameras)}, H, W, 3)", where="stage 0 images")
    img = img.astype(np.float64) / 255.0 if img.dtype == np.uint8 else img.astype(np.float64)
    t0 = time.perf_counter()
    masks = foreground_masks(img, background, cfg.background_threshold)
    if not masks.any(axis=(1, 2)).all():
        empty = int(np.flatnonzero(~masks.any(axis=(1, 2)))[0])
        raise ClodsError(f"camera {empty} sees no cloth in frame 0 (every pixel is background)", where="stage 0 images",
                         hint="check the frames and task_config.clods.stage0.background_threshold")  # fmt: skip
    centre = look_at_point(cameras)
    dist = np.median([np.linalg.norm(-np.asarray(c.R).T @ np.asarray(c.t).reshape(3) - centre) for c in cameras])
    half = 0.4 * float(dist)
    hull = visual_hull(masks, cameras, centre, half, cfg.hull_resolution)
    if hull.shape[0] < 16:
        raise ClodsError(f"the visual hull holds {hull.shape[0]} voxels", where="stage 0", hint="are the cameras and frames consistent?")
    rng = np.random.default_rng(cfg.seed)
    cell = 2.0 * half / (cfg.hull_resolution - 1)
    pick = rng.choice(hull.shape[0], size=min(cfg.num_surfels, hull.shape[0]), replace=False)
    points = hull[pick] + rng.uniform(-0.5 * cell, 0.5 * cell, (pick.size, 3))
    t_hull = time.perf_counter() - t0
    params, history = fit_surfels(torch.from_numpy(img), list(cameras), torch.from_numpy(points), None, cfg.iterations,
                                  background=tuple(background), lambda_dssim=cfg.lambda_dssim, seed=cfg.seed,
                                  backend=cfg.backend)  # fmt: skip
    depth, alpha = (a.cpu().numpy() for a in surfel_depth_maps(params, list(cameras), backend=cfg.backend))
    depth = np.where((alpha > 0.5) & (depth > 0) & masks, depth, np.inf)  # inside the silhouettes only: no floaters
    t_fit = time.perf_counter() - t0 - t_hull
    voxel = cfg.voxel_size or 0.5 * cell
    volume = fuse_depth_maps(depth, list(cameras), None, voxel, orient=True)
    verts, faces = extract_surface(volume)
    support = backproject(depth, list(cameras))
    verts, faces = trim_to_support(verts, faces, support, 2.0 * voxel)
    if verts.shape[0] < 4:
        raise ClodsError("the fused surface is empty", where="stage 0")
    mesh = sheet_from_points(verts, int(num_nodes), parameterization=cfg.sheet)
    refined: dict[str, Any] = {}
    if cfg.refine_iterations > 0:
        rest, refined = refine_sheet(mesh.rest_pos, mesh.cells, img, masks, list(cameras), cfg.refine_options())
        mesh = with_rest_positions(mesh, rest)
    stats = {
        "stage0_seconds": time.perf_counter() - t0,
        "stage0_hull_voxels": float(hull.shape[0]),
        "stage0_fit_seconds": t_fit,
        "stage0_final_loss": float(history["loss"][-1]) if history.get("loss") else float("nan"),
        "stage0_surface_vertices": float(verts.shape[0]),
        "stage0_nodes": float(mesh.num_nodes),
        "stage0_voxel_size": float(voxel),
        **refined,
    }
    return mesh, stats
