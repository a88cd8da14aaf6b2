"""Fast CPU splatting backend: one torch.autograd.Function whose forward and backward are numba kernels.

Forward: EWA projection (`projection_kernels.project_fwd`, the numba twin of `projection.project_gaussians`),
depth sort and tile binning (`fast_kernels.sort_and_bin`), front-to-back compositing (`raster_fwd`).
Backward: back-to-front compositing gradients (`raster_bwd`, over the visits the forward kept, `_keep_visits`),
summed per Gaussian (`reduce_grads`), then
the projection's chain rule (`project_bwd`) to the world-space means and covariances. Same inputs,
outputs and compositing rules as projection + `reference.rasterize_reference`. Everything between the
input Gaussians and the output pixels is float64 whatever the input dtype (results are cast back), so a
float32 render equals the float64 render of the same values to float32 rounding of the outputs.
Importing this module compiles nothing: the kernels compile on first use (then load from numba's
on-disk cache). The whole fixed cost of a render is a few numpy allocations and five kernel calls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from clods_bench.splatting import fast_kernels as K, projection_kernels as PK
from clods_bench.splatting.projection import EPS2D, FOV_CLAMP

KEEP_BYTES = 1 << 30  # at most this much memory for the visits the forward keeps for the backward (else recompute)
VISIT_BYTES = 8 + 2 * 2  # per kept visit: exp(-sigma) (float64) and the pixel in its tile (2 x int16)


def _np(x: Tensor) -> np.ndarray:
    """Detached, contiguous float64 numpy view (or copy) of a CPU tensor."""
    return np.ascontiguousarray(x.detach().numpy(), dtype=np.float64)


@dataclass(frozen=True)
class CameraArrays:
    """The cameras as the projection kernels read them (float64, C rows each)."""

    cams: np.ndarray  # (C,13) fx, fy, cx, cy and R row-major
    ts: np.ndarray  # (C,3) world-to-camera translations
    lims: np.ndarray  # (C,4) Jacobian clamp of x/z and y/z: -lower x, upper x, -lower y, upper y
    width: int
    height: int

    @classmethod
    def from_tensors(cls, Ks: Tensor, Rs: Tensor, ts: Tensor, width: int, height: int) -> "CameraArrays":
        """From (C,3,3) intrinsics, (C,3,3) rotations and (C,3) translations (projection.project_gaussians' inputs)."""
        Kn, Rn = _np(Ks), _np(Rs)
        fx, fy, cx, cy = Kn[:, 0, 0], Kn[:, 1, 1], Kn[:, 0, 2], Kn[:, 1, 2]
        cams = np.concatenate([np.stack([fx, fy, cx, cy], axis=1), Rn.reshape(-1, 9)], axis=1)
        margin = FOV_CLAMP - 1.0  # the same expressions as projection.project_gaussians
        lims = np.stack([cx / fx + margin * 0.5 * width / fx, (width - cx) / fx + margin * 0.5 * width / fx,
                         cy / fy + margin * 0.5 * height / fy, (height - cy) / fy + margin * 0.5 * height / fy], axis=1)  # fmt: skip
        return cls(np.ascontiguousarray(cams), _np(ts), np.ascontiguousarray(lims), int(width), int(height))


class _SplatFast(torch.autograd.Function):
    """Projection + compositing with a hand-written backward (gradients to means, covars, opacities, colours)."""

    @staticmethod
    def forward(ctx, means, covars, opacities, colors, cams: CameraArrays, near: float, tile: int):  # noqa: D102
        C, G = opacities.shape
        W, H = cams.width, cams.height
        tiles_x, tiles_y = math.ceil(W / tile), math.ceil(H / tile)
        m, S, o = _np(means), _np(covars), _np(opacities)
        means2d, conics = np.empty((C, G, 2)), np.empty((C, G, 3))
        depths, thresh = np.empty((C, G)), np.empty((C, G))
        radii, bounds = np.empty((C, G, 2), dtype=np.int32), np.empty((C, G, 4), dtype=np.int32)
        PK.project_fwd(m, S, o, cams.cams, cams.ts, cams.lims, W, H, near, EPS2D, tile,
                       means2d, depths, conics, radii, bounds, thresh)  # fmt: skip
        offsets, ids = K.sort_and_bin(depths, bounds, tiles_x, tiles_y)
        args = (means2d, conics, _np(colors), o, depths, radii, thresh, offsets, ids, W, H, tile, tiles_x, tiles_y)
        out_dtype = np.float32 if means.dtype == torch.float32 else np.float64  # the kernel rounds once, as .to() would
        rgb = np.empty((C, H, W, 3), dtype=out_dtype)
        alpha, depth = np.empty((C, H, W), dtype=out_dtype), np.empty((C, H, W), dtype=out_dtype)
        t_final = np.empty((C, H, W))
        n_last = np.empty((C, H, W), dtype=np.int32)
        keep = _keep_visits(ctx, means2d, radii, offsets, ids, W, H, tile, tiles_x, tiles_y)
        with numba.parallel_chunksize(1):  # tiles differ a lot in cost: hand them out one by one
            K.raster_fwd(*args, rgb, alpha, depth, t_final, n_last, *keep)
        ctx.args, ctx.state, ctx.proj = args, (t_final, n_last, *keep[:3]), (m, S, cams)
        ctx.dtype = means.dtype
        r = torch.from_numpy(radii)
        ctx.mark_non_differentiable(r)
        out = (torch.from_numpy(rgb), torch.from_numpy(alpha)[..., None], torch.from_numpy(depth)[..., None])
        return (*(x.to(means.dtype) for x in out), r)  # no copy unless means is neither float32 nor float64

    @staticmethod
    @once_differentiable
    def backward(ctx, v_rgb, v_alpha, v_depth, _v_radii):  # noqa: D102
        args, state, (m, S, cams) = ctx.args, ctx.state, ctx.proj
        offsets, ids, radii = args[7], args[8], args[5]
        C, G = args[3].shape
        g_isect = np.empty((ids.shape[0], K.N_GRAD))
        with numba.parallel_chunksize(1):  # the pixel gradients are read in their own dtype (float32 widens exactly)
            K.raster_bwd(*args, *state, _pixels(v_rgb), _pixels(v_alpha[..., 0]), _pixels(v_depth[..., 0]), g_isect)
        grads = np.empty((C, G, K.N_GRAD))  # zeroed by reduce_grads, camera by camera in parallel
        K.reduce_grads(offsets, ids, g_isect, args[12] * args[13], grads)
        v_means, v_covars = np.zeros((G, 3)), np.zeros((G, 3, 3))
        if ctx.needs_input_grad[0] or ctx.needs_input_grad[1]:  # strided views of grads: numba reads them in place
            PK.project_bwd(m, S, cams.cams, cams.ts, cams.lims, EPS2D, radii, grads[..., 0:2], grads[..., 2:5], grads[..., 9], v_means, v_covars)
        to = ctx.dtype
        g = torch.from_numpy(grads[..., 5:9]).to(to)  # colour and opacity only (the rest went to project_bwd); they
        g_opac, g_col = g[..., 3], g[..., 0:3]  # stay views of it, and torch sums them over cameras next
        return torch.from_numpy(v_means).to(to), torch.from_numpy(v_covars).to(to), g_opac, g_col, None, None, None


def _keep_visits(ctx, means2d: np.ndarray, radii: np.ndarray, offsets: np.ndarray, ids: np.ndarray, W: int, H: int, tile: int,
                 tiles_x: int, tiles_y: int) -> tuple[np.ndarray, ...]:  # fmt: skip
    """(vis_buf, vis_ij, vis_span, tile_buf) for `raster_fwd`: room for every visit when a backward will run and the
    visits' bound fits `KEEP_BYTES` (`bench render`: 2.2 million visits, 26 MB); else empty arrays, and the backward
    recomputes (a paper-size render, 30 views of 800 px, makes about 0.3 billion visits). Pages past the visits the
    forward makes (the bound counts whole pixel boxes) are never touched."""
    if any(ctx.needs_input_grad[:4]) and tile <= np.iinfo(np.int16).max:
        tile_buf = K.visit_bounds(means2d, radii, offsets, ids, W, H, tile, tiles_x, tiles_y)
        if tile_buf[-1] * VISIT_BYTES <= KEEP_BYTES:
            n = int(tile_buf[-1])
            return np.empty(n), np.empty((n, 2), dtype=np.int16), np.empty((ids.shape[0], 2), dtype=np.int64), tile_buf
    return np.empty(0), np.empty((0, 2), dtype=np.int16), np.empty((0, 2), dtype=np.int64), np.zeros(offsets.shape[0], dtype=np.int64)


def _pixels(x: Tensor) -> np.ndarray:
    """A per-pixel gradient as numpy in its own float dtype (float32 stays float32: the kernel widens it exactly)."""
    x = x.detach()
    if x.dtype not in (torch.float32, torch.float64):
        x = x.double()
    return np.ascontiguousarray(x.numpy())


TILE_SIZES = (64, 32, 16)  # largest first: fewer Gaussian-tile intersections, less per-intersection setup
MIN_TILES = 16  # enough tiles that handing them out one by one keeps 2 threads busy


def auto_tile(num_cameras: int, width: int, height: int) -> int:
    """The largest tile of `TILE_SIZES` that still cuts the rig into `MIN_TILES` tiles (else the smallest).

    Results do not depend on the tile, up to the order in which a Gaussian's per-tile gradients are summed; so that
    they do not depend on the thread count either, the choice looks at the rig alone. On the `bench render` scene
    (8 views of 128 px: 64 px tiles) it cuts forward+backward by about 7 % against 16 px tiles (fewer intersections
    to set up); at `ci` size (4 views of 64 px) it takes 32 px, as 64 px tiles would leave 4 tiles for 2 threads.
    """
    for size in TILE_SIZES:
        if num_cameras * math.ceil(width / size) * math.ceil(height / size) >= MIN_TILES:
            return size
    return TILE_SIZES[-1]


def splat_fast(
    means: Tensor,  # (G,3) world-space centres
    covars: Tensor,  # (G,3,3) world-space covariances
    opacities: Tensor,  # (C,G) per-view opacities
    colors: Tensor,  # (C,G,3) per-view colours
    cameras: CameraArrays,
    near: float = 0.01,
    tile: int | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Project and composite Gaussians with the numba kernels; differentiable w.r.t. means, covars, opacities, colours.

    tile: binning tile in pixels (None: `auto_tile`); results do not depend on it.

    Returns:
        colour (C,H,W,3) without background, alpha (C,H,W,1), accumulated depth (C,H,W,1), radii (C,G,2) int32.
    """
    tile = auto_tile(opacities.shape[0], cameras.width, cameras.height) if tile is None else tile
    return _SplatFast.apply(means, covars, opacities, colors, cameras, near, tile)
