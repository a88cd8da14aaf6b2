"""Fast CPU splatting backend: a torch.autograd.Function whose forward and backward are numba kernels.

Same inputs, outputs and compositing rules as `reference.rasterize_reference`; the kernels work in
float64 whatever the input dtype and results are cast back. Importing this module compiles nothing:
the kernels compile on first use (then load from numba's on-disk cache).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from clods_bench.plugins.splatting import fast_kernels as K


def _np(x: Tensor, dtype=np.float64) -> np.ndarray:
    """Detached, contiguous numpy copy of a tensor in `dtype`."""
    return np.ascontiguousarray(x.detach().cpu().numpy(), dtype=dtype)


class _RasterizeFast(torch.autograd.Function):
    """Tile rasterization with a hand-written backward (gradients to means2d, conics, colours, opacities, depths)."""

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, radii, bounds, width, height, tile):  # noqa: D102
        C, G = means2d.shape[:2]
        tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
        order = torch.argsort(depths.detach(), dim=1, stable=True)  # (C,G) front to back, ties by index
        offsets, ids = K.bin_gaussians(_np(bounds, np.int32), _np(order, np.int64), tiles_x, tiles_y)
        args = (
            _np(means2d), _np(conics), _np(colors), _np(opacities), _np(depths), _np(radii),
            offsets, ids, width, height, tile, tiles_x, tiles_y,
        )  # fmt: skip
        rgb = np.zeros((C, height, width, 3))
        alpha, depth, t_final = (np.zeros((C, height, width)) for _ in range(3))
        n_last = np.zeros((C, height, width), dtype=np.int32)
        with numba.parallel_chunksize(1):  # tiles differ a lot in cost: hand them out one by one
            K.raster_fwd(*args, rgb, alpha, depth, t_final, n_last)
        ctx.args, ctx.state, ctx.dtype = args, (t_final, n_last), means2d.dtype
        out = (torch.from_numpy(rgb), torch.from_numpy(alpha)[..., None], torch.from_numpy(depth)[..., None])
        return tuple(x.to(means2d.dtype) for x in out)

    @staticmethod
    @once_differentiable
    def backward(ctx, v_rgb, v_alpha, v_depth):  # noqa: D102
        args, (t_final, n_last) = ctx.args, ctx.state
        offsets, ids = args[6], args[7]
        C, G = args[0].shape[:2]
        g_isect = np.zeros((ids.shape[0], K.N_GRAD))
        with numba.parallel_chunksize(1):
            K.raster_bwd(*args, t_final, n_last, _np(v_rgb), _np(v_alpha[..., 0]), _np(v_depth[..., 0]), g_isect)
        grads = np.zeros((C, G, K.N_GRAD))
        K.reduce_grads(offsets, ids, g_isect, args[11] * args[12], grads)
        g = torch.from_numpy(grads).to(ctx.dtype)
        # mean2d (2), conic (3), colour (3), opacity, depth; no gradient for radii, bounds, sizes
        return g[..., 0:2], g[..., 2:5], g[..., 5:8], g[..., 8], g[..., 9], None, None, None, None, None


def rasterize_fast(
    means2d: Tensor,  # (C,G,2)
    conics: Tensor,  # (C,G,3)
    colors: Tensor,  # (C,G,3)
    opacities: Tensor,  # (C,G)
    depths: Tensor,  # (C,G)
    radii: Tensor,  # (C,G,2) int32 from projection
    bounds: Tensor,  # (C,G,4) int32 tile rectangles from projection.tile_bounds
    width: int,
    height: int,
    tile: int = 16,
) -> tuple[Tensor, Tensor, Tensor]:
    """Composite screen-space Gaussians with the numba kernels; differentiable (custom backward).

    Returns:
        colour (C,H,W,3) without background, alpha (C,H,W,1), accumulated depth (C,H,W,1).
    """
    return _RasterizeFast.apply(means2d, conics, colors, opacities, depths, radii, bounds, width, height, tile)
