"""The 2DGS regularisers of a surfel render (`surfels.render_surfels`): depth maps back to world points, normals of
the median depth by central differences, and the normal-consistency and distortion losses (Huang et al. 2024)."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor

from clods_bench.datasets.cameras import Camera
from clods_bench.splatting.rasterize import camera_tensors
from clods_bench.splatting.surfels import SurfelOutput


def depth_points(depth: Tensor, cameras: Sequence[Camera]) -> Tensor:
    """(C,H,W,3) world points of (C,H,W) or (C,H,W,1) camera-z depth maps (pixel centres)."""
    d = depth[..., 0] if depth.dim() == 4 else depth
    C, H, W = d.shape
    Ks, Rs, ts, _ = (x.to(d.device) for x in camera_tensors(cameras, d.dtype))
    cc, rr = torch.meshgrid(torch.arange(W, dtype=d.dtype, device=d.device) + 0.5,
                            torch.arange(H, dtype=d.dtype, device=d.device) + 0.5, indexing="xy")  # fmt: skip
    x = (cc[None] - Ks[:, 0, 2, None, None]) / Ks[:, 0, 0, None, None]
    y = (rr[None] - Ks[:, 1, 2, None, None]) / Ks[:, 1, 1, None, None]
    pc = torch.stack([x, y, torch.ones_like(x)], dim=-1) * d[..., None]  # (C,H,W,3) camera space
    return torch.einsum("cji,chwj->chwi", Rs, pc - ts[:, None, None, :])  # R^T (x_cam - t)


def depth_normals(depth: Tensor, cameras: Sequence[Camera]) -> tuple[Tensor, Tensor]:
    """World normals N_depth (C,H,W,3) of the depth maps by central differences (2DGS `depth_to_normal`),
    facing the camera, and the (C,H,W) mask where they are defined (the pixel and its 4 neighbours have depth > 0)."""
    d = depth[..., 0] if depth.dim() == 4 else depth
    X = depth_points(d, cameras)
    n = torch.zeros_like(X)
    du = X[:, 2:, 1:-1] - X[:, :-2, 1:-1]  # along rows (down)
    dv = X[:, 1:-1, 2:] - X[:, 1:-1, :-2]  # along columns (right)
    n[:, 1:-1, 1:-1] = torch.nn.functional.normalize(torch.linalg.cross(du, dv, dim=-1), dim=-1)
    pos = d > 0
    valid = torch.zeros_like(pos)
    valid[:, 1:-1, 1:-1] = pos[:, 1:-1, 1:-1] & pos[:, 2:, 1:-1] & pos[:, :-2, 1:-1] & pos[:, 1:-1, 2:] & pos[:, 1:-1, :-2]
    return n, valid


def surfel_losses(out: SurfelOutput, cameras: Sequence[Camera]) -> dict[str, Tensor]:
    """2DGS regularisers of a render: {'normal': mean (1 - n . N_depth), 'distortion': mean distortion}.

    'normal' averages 1 - (rendered normal) . N_depth over the pixels where N_depth (central differences of
    the median-depth points, see `depth_normals`) is defined (0 if none); gradients reach both sides.
    'distortion' is the mean of the per-pixel distortion map over all pixels.
    """
    N, valid = depth_normals(out.depth_median, cameras)
    err = 1.0 - (out.normal * N).sum(-1)
    vf = valid.to(err.dtype)
    normal = (err * vf).sum() / vf.sum().clamp(min=1.0)
    return {"normal": normal, "distortion": out.distortion.mean()}
