"""Surfel backend 'gsplat': our float64 2DGS projection, then gsplat's 2DGS tile binning and compositing on CUDA.

gsplat is imported lazily; without gsplat or CUDA `render_surfels(backend="gsplat")` raises a ClodsError saying
what to install.
As for 3D Gaussians (`gsplat_backend`), the projection is ours (`surfels.project_surfels`, float64 torch,
autograd for its backward), so both backends composite the same per-view transforms: gsplat's
`ray_transforms` are exactly our M = K [R | t] H (rows Tu, Tv, Tw; checked against gsplat's own torch
projection in the tests). Its kernels then bin (`isect_tiles` over radii that cover our pixel boxes) and
composite (`rasterize_to_pixels_2dgs`) in float32. Channels passed as colours (`CHANNELS`): RGB, the
centre's camera z, three zeros and its 2DGS-mapped depth m; m is the last channel, which gsplat's distortion
and median read, and the median z is mapped back from m (m is monotone in z).

Differences from the CPU backends (so agreement holds for opacities up to about 0.35 and, for depth,
median and distortion, surfels facing the camera; `tests/splatting/test_surfel_gsplat.py`):
- depth is the surfel centre's camera z at every pixel it covers (gsplat carries depth as a per-surfel
  channel); the CPU backends use the ray-splat hit's z, which differs by the surfel's slope across it;
- no 3-sigma cut: gsplat composites every surfel with alpha >= 1/255 in the tiles its radii cover, which
  reaches beyond rho = 9 where opacity exp(-4.5) >= 1/255 (opacity > 0.35); alpha is clamped at 0.999
  (not 0.99) and a pixel stops at T <= 1e-4 (not < 1e-4);
- a ray (nearly) in a surfel's plane is skipped only where the cross product's z is exactly 0, and hits
  are not tested against the near plane; compositing runs in float32.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from clods_bench.splatting.gsplat_backend import order_keys

CHANNELS = 8
"""Channels handed to gsplat: RGB, z, three zeros, m. gsplat 1.5.3 has 2DGS kernels for 1-4, 8, 16, ... channels and
pads any other count before the last channel with `torch.empty` (uninitialised memory). The forward drops those
channels, but its backward multiplies them by their zero incoming gradient inside the alpha gradient, so garbage
that happens to be NaN or inf made the opacity, ray-transform and mean gradients NaN (stage 0 stopped at its first
backward on an H200). Zeros of our own keep every value finite."""


def box_radii(means2d: Tensor, boxes: Tensor) -> Tensor:
    """(C,G,2) int32 radii about `means2d` whose tiles (gsplat: floor/ceil of (mean -/+ radius) / tile) cover the
    inclusive pixel boxes (c0, r0, c1, r1); 0 where a box is empty (culled)."""
    lo = boxes[..., 0:2].to(means2d.dtype)
    hi = boxes[..., 2:4].to(means2d.dtype) + 1.0
    r = torch.ceil(torch.maximum(means2d - lo, hi - means2d)).clamp(min=1.0)
    culled = (boxes[..., 2] < boxes[..., 0]) | (boxes[..., 3] < boxes[..., 1])
    r = torch.where(culled[..., None], torch.zeros_like(r), r)
    return r.to(torch.int32).contiguous()


def raster_surfels_gsplat(
    M: Tensor,  # (C,G,3,3) float64
    means2d: Tensor,  # (C,G,2)
    depths: Tensor,  # (C,G)
    mapped: Tensor,  # (C,G) 2DGS-mapped depth m of the centres
    normals: Tensor,  # (C,G,3) world space
    colors: Tensor,  # (G,3)
    opacities: Tensor,  # (G,)
    boxes: Tensor,  # (C,G,4) int64 inclusive pixel boxes
    width: int,
    height: int,
    tile: int,
) -> dict[str, Tensor]:
    """gsplat's 2DGS compositing of projected surfels on the GPU of `M`: {'color' (C,H,W,3) without background,
    'depth_acc' sum w z, 'mapped_median' m of the median surfel, 'alpha', 'normal' (world), 'distortion'}, float32.
    Called by `surfels.render_surfels`, which has checked that gsplat and CUDA are there."""
    from gsplat.cuda._wrapper import isect_offset_encode, isect_tiles, rasterize_to_pixels_2dgs

    f32 = torch.float32
    C, G = depths.shape
    tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
    m2 = means2d.to(f32).contiguous()
    radii = box_radii(means2d.detach(), boxes.to(means2d.device))
    _, isect_ids, flatten_ids = isect_tiles(m2.detach(), radii, order_keys(depths), tile, tiles_x, tiles_y)  # float64 order
    offsets = isect_offset_encode(isect_ids, C, tiles_x, tiles_y)
    zeros = torch.zeros(C, G, CHANNELS - 5, dtype=f32, device=m2.device)  # our own zero padding: see CHANNELS
    feats = torch.cat([colors.to(f32)[None].expand(C, G, 3), depths.to(f32)[..., None], zeros, mapped.to(f32)[..., None]], dim=-1)
    densify = torch.zeros(C, G, 2, dtype=f32, device=m2.device)
    render, alpha, normal, distort, median = rasterize_to_pixels_2dgs(
        m2, M.to(f32).contiguous(), feats.contiguous(), opacities.to(f32)[None].expand(C, G).contiguous(),
        normals.to(f32).contiguous(), densify, width, height, tile, offsets, flatten_ids, distloss=True,
    )  # fmt: skip
    return {"color": render[..., 0:3], "depth_acc": render[..., 3:4], "mapped_median": median, "alpha": alpha,
            "normal": normal, "distortion": distort}  # fmt: skip

