"""Refinement of the stage-0 sheet against the frame-0 images: silhouettes and multi-view photo-consistency.

The sheet built from the surfels' fused depth maps inherits their error (at `ci`, 4 views of 64 px, its nodes lie
2.7 % of the cloth's size from the truth; with perfect depth maps 1.0 %). This step moves the sheet's nodes so that
  1. its surface projects inside every view's silhouette and covers it: surface samples outside the mask pay the
     mask's distance transform, mask pixels pay their distance to the nearest projected sample (a 2D Chamfer; an
     edge-on view's silhouette is the cloth's profile, the depth a face-on view cannot see);
  2. each surface point shows the same colour in every view that sees it (the variance across views of colours
     sampled from the lightly blurred images; visibility from a z-buffer of the current sheet). No colour is fitted,
     so colours cannot absorb the geometry error, as the fitted colours of a renderer did (README, "Stage 0");
with the sheet's edge lengths and Laplacian tied to the start's: weakly tied (weights 0.1), the nodes slid 9-12 cm
along the cloth at `ci` and turned a twentieth of the triangles into slivers (5th percentile of the smallest angle
19-30 degrees before, 5-7 after), so the Laplacian's weight is 10 and the edge lengths' 1 (17-29 degrees after).
Adam on the node positions, float64.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import torch
from scipy.ndimage import distance_transform_edt, gaussian_filter
from scipy.spatial import cKDTree

from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.rasterizer import render_depth
from clods_bench.datasets.types import edges_from_cells
from clods_bench.errors import ClodsError

VISIBILITY_EVERY = 10
"""Iterations between z-buffer updates of the visibility (the sheet moves by millimetres per iteration)."""


@dataclass(frozen=True)
class RefineOptions:
    """Weights and steps of `refine_sheet` (from `Stage0Config.refine_*`; defaults measured at `ci`, README)."""

    iterations: int = 150
    lr: float = 0.01
    silhouette_weight: float = 1.0
    photo_weight: float = 10.0
    edge_weight: float = 1.0
    laplacian_weight: float = 10.0
    blur: float = 0.5
    visibility: float = 0.4
    subdivisions: int = 4


def face_samples(subdivisions: int) -> np.ndarray:
    """(S,3) barycentric coordinates of a triangle's points on a regular grid of `subdivisions` steps per side."""
    n = int(subdivisions)
    return np.array([(i / n, j / n, 1.0 - (i + j) / n) for i in range(n + 1) for j in range(n + 1 - i)])


def project(points: torch.Tensor, cam: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """(N,3) world points to (N,2) pixel coordinates (pixel (r, c) covers [c, c+1) x [r, r+1)) and (N,) depths."""
    R = torch.as_tensor(np.asarray(cam.R, np.float64), dtype=points.dtype)
    t = torch.as_tensor(np.asarray(cam.t, np.float64).reshape(3), dtype=points.dtype)
    pc = points @ R.T + t
    z = pc[:, 2].clamp(min=1e-9)
    K = np.asarray(cam.K, np.float64)
    return torch.stack([K[0, 0] * pc[:, 0] / z + K[0, 2], K[1, 1] * pc[:, 1] / z + K[1, 2]], dim=1), pc[:, 2]


def sample_image(image: torch.Tensor, pix: torch.Tensor) -> torch.Tensor:
    """Bilinear values of `image` (C,H,W), pixel centres at (c+0.5, r+0.5), at pixel coordinates `pix` (N,2): (N,C)."""
    h, w = image.shape[1:]
    grid = torch.stack([pix[:, 0] / w * 2.0 - 1.0, pix[:, 1] / h * 2.0 - 1.0], dim=1)[None, None]
    out = torch.nn.functional.grid_sample(image[None], grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out[0, :, 0].T


def silhouette_loss(pix: torch.Tensor, outside_distance: torch.Tensor, mask_pixels: torch.Tensor) -> torch.Tensor:
    """Squared pixel distances (beyond half a pixel) of the samples `pix` (N,2) outside the mask, read from the
    mask's distance transform (1,H,W), plus those of the mask's pixel centres `mask_pixels` (M,2) to their
    nearest sample: zero when the samples fill the silhouette and stay inside it."""
    out = torch.relu(sample_image(outside_distance, pix)[:, 0] - 0.5) ** 2
    with torch.no_grad():
        nearest = torch.as_tensor(cKDTree(pix.detach().numpy()).query(mask_pixels.numpy())[1])
    cover = torch.relu((mask_pixels - pix[nearest]).norm(dim=1) - 0.5) ** 2
    return out.mean() + cover.mean()


def photo_loss(colours: torch.Tensor, visible: torch.Tensor) -> torch.Tensor:
    """Mean over (point, view) pairs of the squared difference between a point's colour in a view (C,N,3) and its
    mean over the views that see it (`visible` (C,N) float 0/1); points seen by fewer than two views do not count."""
    n = visible.sum(dim=0)
    seen = n >= 2
    if not bool(seen.any()):
        return colours.sum() * 0.0
    mean = (colours * visible[..., None]).sum(dim=0) / n.clamp(min=1.0)[:, None]
    spread = (((colours - mean) ** 2).sum(dim=-1) * visible).sum(dim=0)
    return spread[seen].sum() / n[seen].sum()


def _visibility(points: np.ndarray, verts: np.ndarray, cells: np.ndarray, masks: np.ndarray, cams: Sequence[Camera], tol: float) -> np.ndarray:
    """(C,N) 0/1: the points in front of (within `tol` of) the sheet's z-buffer in each view, inside its silhouette."""
    out = np.zeros((len(cams), points.shape[0]))
    for k, (mask, cam) in enumerate(zip(masks, cams)):
        zbuf = render_depth(verts, cells, cam)
        pix, z = cam.project(points)
        col, row = np.floor(pix[:, 0]).astype(np.int64), np.floor(pix[:, 1]).astype(np.int64)
        ok = (z > 0) & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
        vis = np.zeros(points.shape[0], dtype=bool)
        vis[ok] = (z[ok] <= zbuf[row[ok], col[ok]] + tol) & mask[row[ok], col[ok]]
        out[k] = vis
    return out


def refine_sheet(
    rest: np.ndarray, cells: np.ndarray, images: np.ndarray, masks: np.ndarray, cameras: Sequence[Camera], opts: RefineOptions
) -> tuple[np.ndarray, dict[str, Any]]:
    """New node positions (V,3) of the sheet (`rest`, `cells`) fitted to the views' `images` (C,H,W,3) in [0,1] and
    cloth `masks` (C,H,W) bool (see the module docstring); and statistics (losses before and after, seconds).
    Runs on one torch thread: its tensors are small, and a thread pool on a busy machine made it 10x slower."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _refine(rest, cells, images, masks, cameras, opts)
    finally:
        torch.set_num_threads(threads)


def _refine(
    rest: np.ndarray, cells: np.ndarray, images: np.ndarray, masks: np.ndarray, cameras: Sequence[Camera], opts: RefineOptions
) -> tuple[np.ndarray, dict[str, Any]]:
    """`refine_sheet` on the calling thread count."""
    t0 = time.perf_counter()
    cells = np.asarray(cells, np.int64)
    x0 = torch.tensor(np.asarray(rest, np.float64))
    if x0.ndim != 2 or x0.shape[1] != 3 or not torch.isfinite(x0).all():
        raise ClodsError(f"sheet positions of shape {tuple(x0.shape)} with non-finite values or not (V,3)", where="stage 0 refinement")
    cells_t = torch.as_tensor(cells)
    bary = torch.tensor(face_samples(opts.subdivisions))
    edges = torch.as_tensor(edges_from_cells(cells))
    len0 = (x0[edges[:, 0]] - x0[edges[:, 1]]).norm(dim=1)
    scale = float(len0.mean())
    ones = torch.ones(edges.shape[0], dtype=torch.float64)
    degree = torch.zeros(x0.shape[0], dtype=torch.float64).index_add_(0, edges[:, 0], ones).index_add_(0, edges[:, 1], ones)

    def laplacian(x: torch.Tensor) -> torch.Tensor:
        s = torch.zeros_like(x).index_add_(0, edges[:, 0], x[edges[:, 1]]).index_add_(0, edges[:, 1], x[edges[:, 0]])
        return s / degree[:, None] - x

    lap0 = laplacian(x0)
    views = []
    for image, mask in zip(images, masks):
        dist = torch.tensor(distance_transform_edt(~mask), dtype=torch.float64)[None]
        rows, cols = np.nonzero(mask)
        pixels = torch.tensor(np.stack([cols + 0.5, rows + 0.5], axis=1), dtype=torch.float64)
        planes = np.moveaxis(np.asarray(image, np.float64), -1, 0)  # (3, H, W)
        blurred = np.stack([gaussian_filter(p, opts.blur) for p in planes]) if opts.blur > 0 else planes
        views.append((dist, pixels, torch.tensor(blurred)))

    def losses(x: torch.Tensor, visible: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        pts = torch.einsum("fkx,sk->fsx", x[cells_t], bary).reshape(-1, 3)
        sil = x.new_zeros(())
        colours = []
        for (dist, pixels, blurred), cam in zip(views, cameras):
            pix, _ = project(pts, cam)
            sil = sil + silhouette_loss(pix, dist, pixels)
            colours.append(sample_image(blurred, pix))
        photo = photo_loss(torch.stack(colours), visible)
        edge = (((x[edges[:, 0]] - x[edges[:, 1]]).norm(dim=1) - len0) / scale).pow(2).mean()
        lap = ((laplacian(x) - lap0) / scale).pow(2).sum(dim=1).mean()
        return sil / len(views), photo, edge, lap

    def visible_at(x: torch.Tensor) -> torch.Tensor:
        pts = torch.einsum("fkx,sk->fsx", x[cells_t], bary).reshape(-1, 3).numpy()
        return torch.tensor(_visibility(pts, x.numpy(), cells, masks, cameras, opts.visibility * scale))

    with torch.no_grad():
        visible = visible_at(x0)
        start = [float(v) for v in losses(x0, visible)]
    x = x0.clone().requires_grad_(True)
    optim = torch.optim.Adam([x], lr=opts.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(optim, max(opts.iterations, 1))
    for it in range(opts.iterations):
        if it % VISIBILITY_EVERY == 0 and it > 0:
            visible = visible_at(x.detach())
        optim.zero_grad()
        sil, photo, edge, lap = losses(x, visible)
        loss = opts.silhouette_weight * sil + opts.photo_weight * photo + opts.edge_weight * edge + opts.laplacian_weight * lap
        loss.backward()
        optim.step()
        sched.step()
    out = x.detach()
    if not torch.isfinite(out).all():
        raise ClodsError("the refined sheet has non-finite node positions", where="stage 0 refinement",
                         hint="refine_iterations=0 (under task_config.initial_mesh or task_config.clods.stage0) keeps the unrefined sheet")  # fmt: skip
    with torch.no_grad():
        end = [float(v) for v in losses(out, visible_at(out))]
    stats = {
        "stage0_refine_seconds": time.perf_counter() - t0,
        "stage0_refine_silhouette_start": start[0],
        "stage0_refine_silhouette_end": end[0],
        "stage0_refine_photo_start": start[1],
        "stage0_refine_photo_end": end[1],
        "stage0_refine_moved_rms": float((out - x0).norm(dim=1).pow(2).mean().sqrt()),
    }
    return out.numpy(), stats
