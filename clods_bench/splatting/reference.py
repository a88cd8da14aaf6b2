"""Plain PyTorch tile rasterizer: the obviously correct oracle for the fast CPU backend (and its baseline).

Per camera and 16x16 tile: gather the Gaussians whose bounding box touches the tile, in ascending
depth (stable: ties by index), evaluate every (pixel, Gaussian) alpha densely and composite front to
back with a cumulative product; autograd does the backward pass. The rules match 3DGS / gsplat:
- sigma = 0.5 (a dx^2 + c dy^2) + b dx dy with d = pixel centre - mean2d; skip if sigma < 0;
- alpha = min(0.99, opacity * exp(-sigma)); skip if alpha < 1/255;
- stop before the Gaussian that would bring the transmittance below 1e-4 (it does not contribute).
Outputs are accumulated colour sum_i c_i w_i (no background), alpha sum_i w_i = 1 - T_final and
accumulated depth sum_i z_i w_i, with w_i = alpha_i T_i.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import torch
from torch import Tensor

from clods_bench.splatting.projection import ALPHA_MIN

ALPHA_MAX = 0.99  # alphas are clamped here so 1 - alpha stays invertible in the backward pass
T_MIN = 1e-4  # compositing stops before the transmittance would fall below this


def composite_tile(pix: Tensor, means2d: Tensor, conics: Tensor, colors: Tensor, opac: Tensor, depths: Tensor) -> Tensor:
    """(P,5) [colour(3), alpha, depth] of P pixel centres (P,2) over n depth-sorted Gaussians (n,...)."""
    d = pix[:, None, :] - means2d[None, :, :]  # (P,n,2)
    dx, dy = d[..., 0], d[..., 1]
    a, b, c = conics[:, 0], conics[:, 1], conics[:, 2]  # (n,)
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy  # (P,n)
    ok = sigma >= 0
    sigma = torch.where(ok, sigma, torch.zeros_like(sigma))
    alpha = torch.clamp(opac * torch.exp(-sigma), max=ALPHA_MAX)
    ok = ok & (alpha >= ALPHA_MIN)
    alpha = torch.where(ok, alpha, torch.zeros_like(alpha))
    with torch.no_grad():  # early termination: a prefix, since the transmittance never increases
        keep = torch.cumprod(1.0 - alpha, dim=1) >= T_MIN
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    trans = torch.cumprod(1.0 - alpha, dim=1)  # (P,n) transmittance after each Gaussian
    trans_before = torch.cat([torch.ones_like(trans[:, :1]), trans[:, :-1]], dim=1)
    w = alpha * trans_before  # (P,n)
    return torch.cat([w @ colors, w.sum(1, keepdim=True), w @ depths[:, None]], dim=1)



def tile_walk(depths: Tensor, bounds: Tensor, width: int, height: int, tile: int) -> Iterator[tuple[int, Tensor, Tensor, Tensor]]:
    """Every non-empty tile of every camera: (camera, its splats front to back (by `depths` (C,G)) whose tile box
    `bounds` (C,G,4) [x0, y0, x1, y1) covers it, pixel centres (P,2) (u, v) float64, flat pixel indices (P,))."""
    tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
    order = torch.argsort(depths.detach(), dim=1, stable=True)  # (C,G) front to back
    for cam in range(depths.shape[0]):
        b = bounds[cam, order[cam]]  # (G,4) in depth order
        for ty in range(tiles_y):
            in_row = (b[:, 1] <= ty) & (ty < b[:, 3])
            for tx in range(tiles_x):
                members = order[cam][in_row & (b[:, 0] <= tx) & (tx < b[:, 2])]
                if members.numel() == 0:
                    continue
                rows = torch.arange(ty * tile, min((ty + 1) * tile, height))
                cols = torch.arange(tx * tile, min((tx + 1) * tile, width))
                rr, cc = torch.meshgrid(rows, cols, indexing="ij")
                pix = torch.stack([cc.reshape(-1), rr.reshape(-1)], dim=1).to(torch.float64) + 0.5
                yield cam, members, pix, (cam * height + rr.reshape(-1)) * width + cc.reshape(-1)


def rasterize_reference(
    means2d: Tensor,  # (C,G,2)
    conics: Tensor,  # (C,G,3)
    colors: Tensor,  # (C,G,3)
    opacities: Tensor,  # (C,G)
    depths: Tensor,  # (C,G)
    bounds: Tensor,  # (C,G,4) int32 tile rectangles from projection.tile_bounds
    width: int,
    height: int,
    tile: int = 16,
    order: Tensor | None = None,  # (C,G) sort keys front to back (default: depths), e.g. `Projection.order`
) -> tuple[Tensor, Tensor, Tensor]:
    """Composite screen-space Gaussians tile by tile in torch; differentiable by autograd.

    Returns:
        colour (C,H,W,3) without background, alpha (C,H,W,1), accumulated depth (C,H,W,1).
    """
    C = means2d.shape[0]
    values, index = [], []
    for cam, members, pix, flat in tile_walk(depths if order is None else order, bounds, width, height, tile):
        values.append(
            composite_tile(
                pix.to(means2d.dtype), means2d[cam, members], conics[cam, members], colors[cam, members],
                opacities[cam, members], depths[cam, members],
            )  # fmt: skip
        )
        index.append(flat)
    out = torch.zeros(C * height * width, 5, dtype=means2d.dtype)
    if values:
        out = out.index_copy(0, torch.cat(index), torch.cat(values))
    else:  # nothing visible: keep the (zero) outputs attached to the inputs so backward still works
        out = out + 0.0 * sum(x.sum() for x in (means2d, conics, colors, opacities, depths))
    out = out.reshape(C, height, width, 5)
    return out[..., :3], out[..., 3:4], out[..., 4:5]
