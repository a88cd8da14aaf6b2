"""2D Gaussian splatting (2DGS, Huang et al. SIGGRAPH 2024) surfel renderer with depth, normal and distortion maps.

Why: stage 0 of CloDS fits surfels to the first frame and fuses their median-depth maps (TSDF) into the
initial cloth mesh; 2DGS gives view-consistent, geometrically accurate depth where 3D Gaussians do not.
Entry point `render_surfels` -> `SurfelOutput`, with backends 'cpu' (numba forward/backward,
`surfel_kernels`, one torch.autograd.Function), 'reference' (plain torch, autograd; small scenes only) and
'gsplat' (gsplat's 2DGS kernels on CUDA after the same projection; its differences in `surfel_gsplat`).
Both share the torch per-view preprocessing `project_surfels` (autograd carries its gradient to means,
quats and scales), so the numba backward only differentiates the per-pixel compositing.

Conventions (cameras as in `clods_bench.datasets.cameras`: OpenCV, x_cam = R x + t, pixel (r, c) centre at
(c + 0.5, r + 0.5)):
- a surfel is centre p, tangent axes t_u, t_v = columns 0, 1 of the rotation of the unit quaternion
  (w, x, y, z) (quats are normalised here; a zero quaternion is refused) scaled by std devs s_u, s_v;
  its normal t_w = column 2, flipped per camera to face the camera centre (sign from the centre, as 2DGS);
- per view, M = K [R | t] H (3x3) maps local homogeneous (u, v, 1) to pixel homogeneous (x w, y w, w),
  H = [[s_u t_u, s_v t_v, p], [0, 0, 1]]; rows Tu, Tv, Tw. A pixel (x, y) intersects the two planes
  k = x Tw - Tu, l = y Tw - Tv: (u, v) = (p0 / p2, p1 / p2) for p = k x l (2DGS eq. 8-10); the hit's
  camera z is Tw . (u, v, 1). The 3D branch is invalid where |p2| <= 1e-9 (|x| |Tw| + |Tu|) (|y| |Tw| + |Tv|)
  (the ray runs along or inside the plane: 2DGS only tests p2 = 0, which rounding defeats) or the hit is
  not beyond `near`;
- rho3d = u^2 + v^2, rho2d = 2 |pixel - projected centre|^2 (low-pass filter, sigma = sqrt(2)/2 px);
  rho = min of the two; alpha = min(0.99, opacity exp(-rho / 2)); a surfel contributes only where
  rho <= 9 (its 3-sigma footprint, which is what the 3-sigma bounding box of 2DGS bins) and alpha >= 1/255,
  so results never depend on tiles; per-pixel depth z_i is the hit's z where rho3d <= rho2d, else the
  centre's z (2DGS backward.cu / forward.cu rule), so edge-on surfels are drawn as the low-pass footprint;
- front-to-back compositing sorted by the centre's camera z (stable, ties by index), w_i = alpha_i T_i,
  stopping before a surfel that would bring T below 1e-4 (3DGS rule); surfels whose centre is not beyond
  `near` or whose 3-sigma disc reaches the camera plane z = 0 (hyperbolic footprint) are culled;
- outputs: rgb = sum w_i c_i + (1 - alpha) background; alpha = 1 - T_final; depth_expected =
  sum w_i z_i / alpha (0 where alpha = 0); depth_median = z_i of the first contributor after which T < 0.5,
  **0 where alpha <= 0.5** (no crossing; 0 is the 'no depth' value TSDF fusion skips); normal =
  sum w_i n_i in **world space**, not renormalised (as 2DGS renders it); distortion =
  sum_{i,j} w_i w_j |m_i - m_j| over all ordered pairs (2DGS paper eq. 13; the released CUDA code uses
  squared differences) with 2DGS's mapped depth m = f / (f - n) (1 - n / z), n = 0.2, f = 100.
Everything runs in float64 and returns the dtype of `means`. Gradients (both backends) reach means, quats,
scales, opacities, colours (and a background tensor) from every output, distortion and median depth
included (the median through the chosen surfel's depth; which surfel is chosen is piecewise constant).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError
from clods_bench.splatting.checks import background_tensor, check_cameras, check_finite, check_shape
from clods_bench.splatting.projection import quat_to_rotmat
from clods_bench.splatting.rasterize import camera_tensors
from clods_bench.splatting.reference import tile_walk

SurfelBackend = Literal["cpu", "reference", "gsplat"]
BACKENDS = ("cpu", "reference", "gsplat")

CUTOFF = 3.0  # footprint radius in local sigmas (rho <= CUTOFF^2); the bounding boxes cover it
FILTER_SIZE = math.sqrt(2.0) / 2.0  # low-pass filter std dev in px (2DGS FilterSize)
FILTER_INV_SQUARE = 1.0 / FILTER_SIZE**2  # = 2
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
MEDIAN_T = 0.5
DIST_NEAR, DIST_FAR = 0.2, 100.0  # 2DGS's depth mapping for the distortion term
BOX_MARGIN = 1e-3  # px added to every bounding box (rounding guard; the per-pixel rule decides)
TILE = 16
PARALLEL_EPS = 1e-9  # the 3D branch needs |p2| > this * (|x| |Tw| + |Tu|) (|y| |Tw| + |Tv|) (else the ray runs in the plane)
N_OUT = 10  # per-pixel raster outputs: colour (3), alpha, accumulated depth, normal (3), distortion, median depth


@dataclass
class SurfelOutput:
    """Rendered maps of C cameras (H x W); see the module docstring for the definitions."""

    rgb: Tensor  # (C,H,W,3) composited over the background
    alpha: Tensor  # (C,H,W,1) 1 - final transmittance
    depth_median: Tensor  # (C,H,W,1) camera z of the surfel where T first drops below 0.5; 0 where alpha <= 0.5
    depth_expected: Tensor  # (C,H,W,1) sum w_i z_i / alpha; 0 where alpha = 0
    normal: Tensor  # (C,H,W,3) world-space sum w_i n_i, normals facing the camera (length <= alpha)
    distortion: Tensor  # (C,H,W,1) sum_ij w_i w_j |m_i - m_j|


@dataclass
class SurfelProjection:
    """Per-view surfel quantities (C cameras x G surfels), float64; M..normals carry autograd."""

    M: Tensor  # (C,G,3,3) local (u, v, 1) -> pixel homogeneous (x w, y w, w)
    means2d: Tensor  # (C,G,2) projected centres (low-pass filter centre)
    depths: Tensor  # (C,G) camera z of the centres (sort key, low-pass depth)
    normals: Tensor  # (C,G,3) world-space unit normals facing the camera
    boxes: np.ndarray  # (C,G,4) int64 inclusive pixel ranges c0, r0, c1, r1 (c1 < c0: culled)
    valid: np.ndarray  # (C,G) bool


def project_surfels(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, cameras: Sequence[Camera], near: float
) -> SurfelProjection:
    """Per-view 2DGS transforms, projected centres, depths, oriented normals and conservative pixel boxes.

    The box is the union of the 3-sigma disc's image bounding box (2DGS `compute_aabb`: dual conic of
    u^2 + v^2 = 9 under M) and the low-pass footprint (3 FILTER_SIZE px around the projected centre).
    """
    f64 = torch.float64
    dev = means.device
    Ks, Rs, ts, centers = (x.to(dev) for x in camera_tensors(cameras, f64))
    W, H = int(cameras[0].width), int(cameras[0].height)
    p, s = means.to(f64), scales.to(f64)
    rot = quat_to_rotmat(quats.to(f64))  # (G,3,3)
    axes = rot[:, :, :2] * s[:, None, :]  # (G,3,2) s_u t_u, s_v t_v
    pc = torch.einsum("cij,gj->cgi", Rs, p) + ts[:, None, :]  # (C,G,3)
    ac = torch.einsum("cij,gjk->cgik", Rs, axes)  # (C,G,3,2)
    cols = torch.cat([ac, pc[..., None]], dim=-1)  # (C,G,3,3) camera-space columns
    M = torch.einsum("cij,cgjk->cgik", Ks, cols)  # (C,G,3,3)
    z = pc[..., 2]
    with torch.no_grad():
        ok_z = torch.isfinite(M).flatten(-2).all(-1) & (z > near)
    zs = torch.where(ok_z, z, torch.ones_like(z))
    means2d = torch.stack([M[..., 0, 2] / zs, M[..., 1, 2] / zs], dim=-1)
    n = rot[:, :, 2][None].expand(len(cameras), -1, -1)  # (C,G,3)
    with torch.no_grad():
        facing_away = (n * (p[None] - centers[:, None, :])).sum(-1) > 0
    normals = torch.where(facing_away[..., None], -n, n)

    Mn = M.detach().cpu().numpy()
    Tu, Tv, Tw = Mn[..., 0, :], Mn[..., 1, :], Mn[..., 2, :]
    c2 = CUTOFF * CUTOFF
    with np.errstate(all="ignore"):
        dist = c2 * (Tw[..., 0] ** 2 + Tw[..., 1] ** 2) - Tw[..., 2] ** 2  # < 0: the 3-sigma disc lies in z > 0
        px = (c2 * (Tu[..., 0] * Tw[..., 0] + Tu[..., 1] * Tw[..., 1]) - Tu[..., 2] * Tw[..., 2]) / dist
        py = (c2 * (Tv[..., 0] * Tw[..., 0] + Tv[..., 1] * Tw[..., 1]) - Tv[..., 2] * Tw[..., 2]) / dist
        ex = np.sqrt(np.maximum(1e-4, px * px - (c2 * (Tu[..., 0] ** 2 + Tu[..., 1] ** 2) - Tu[..., 2] ** 2) / dist))
        ey = np.sqrt(np.maximum(1e-4, py * py - (c2 * (Tv[..., 0] ** 2 + Tv[..., 1] ** 2) - Tv[..., 2] ** 2) / dist))
        m2 = means2d.detach().cpu().numpy()
        rl = CUTOFF * FILTER_SIZE
        x_lo = np.minimum(px - ex, m2[..., 0] - rl) - BOX_MARGIN
        x_hi = np.maximum(px + ex, m2[..., 0] + rl) + BOX_MARGIN
        y_lo = np.minimum(py - ey, m2[..., 1] - rl) - BOX_MARGIN
        y_hi = np.maximum(py + ey, m2[..., 1] + rl) + BOX_MARGIN
        valid = ok_z.cpu().numpy() & (dist < 0) & np.isfinite(x_lo + x_hi + y_lo + y_hi)
        valid &= (opacities.detach().to(f64).cpu().numpy() >= ALPHA_MIN)[None, :]
        lo_x = np.clip(np.nan_to_num(np.ceil(x_lo - 0.5)), 0, W)
        hi_x = np.clip(np.nan_to_num(np.floor(x_hi - 0.5)), -1, W - 1)
        lo_y = np.clip(np.nan_to_num(np.ceil(y_lo - 0.5)), 0, H)
        hi_y = np.clip(np.nan_to_num(np.floor(y_hi - 0.5)), -1, H - 1)
    boxes = np.stack([lo_x, lo_y, hi_x, hi_y], axis=-1).astype(np.int64)
    valid &= (boxes[..., 2] >= boxes[..., 0]) & (boxes[..., 3] >= boxes[..., 1])
    boxes[~valid] = np.array([0, 0, -1, -1])
    return SurfelProjection(M=M, means2d=means2d, depths=z, normals=normals, boxes=boxes, valid=valid)


def tile_rects(boxes: np.ndarray, tile: int = TILE) -> np.ndarray:
    """(C,G,4) int32 tile rectangles [tx0, ty0, tx1, ty1) of inclusive pixel boxes (empty where culled)."""
    rect = np.stack([boxes[..., 0] // tile, boxes[..., 1] // tile, boxes[..., 2] // tile + 1, boxes[..., 3] // tile + 1], -1)
    culled = (boxes[..., 2] < boxes[..., 0]) | (boxes[..., 3] < boxes[..., 1])
    rect[culled] = 0
    return np.ascontiguousarray(rect, dtype=np.int32)


# ---------------------------------------------------------------------------------------------------------
# plain-torch reference


def mapped_depth(z: Tensor) -> Tensor:
    """2DGS's distortion depth m = f / (f - n) (1 - n / z)."""
    return DIST_FAR / (DIST_FAR - DIST_NEAR) * (1.0 - DIST_NEAR / z)


def intersect_reference(pix: Tensor, M: Tensor, near: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Ray-splat intersection of pixel centres (P,2) with n surfels (n,3,3): (u, v, z_hit, valid), each (P,n)."""
    Tu, Tv, Tw = M[:, 0], M[:, 1], M[:, 2]  # (n,3)
    k = pix[:, 0, None, None] * Tw[None] - Tu[None]  # (P,n,3)
    l = pix[:, 1, None, None] * Tw[None] - Tv[None]
    p = torch.linalg.cross(k, l, dim=-1)
    with torch.no_grad():  # ray (nearly) parallel to, or inside, the plane: no usable hit
        kn = pix[:, 0, None].abs() * Tw.norm(dim=-1)[None] + Tu.norm(dim=-1)[None]  # |k| before cancellation
        ln = pix[:, 1, None].abs() * Tw.norm(dim=-1)[None] + Tv.norm(dim=-1)[None]
        ok = p[..., 2].abs() > PARALLEL_EPS * kn * ln
    p2 = torch.where(ok, p[..., 2], torch.ones_like(p[..., 2]))
    u, v = p[..., 0] / p2, p[..., 1] / p2
    z = u * Tw[None, :, 0] + v * Tw[None, :, 1] + Tw[None, :, 2]
    ok = ok & (z > near) & torch.isfinite(u) & torch.isfinite(v)
    return u, v, z, ok


def composite_surfels_reference(
    pix: Tensor, M: Tensor, means2d: Tensor, depths: Tensor, normals: Tensor, colors: Tensor, opac: Tensor, near: float
) -> Tensor:
    """(P, N_OUT) raster outputs of P pixel centres over n centre-depth-sorted surfels (dense, autograd)."""
    u, v, zhit, ok3 = intersect_reference(pix, M, near)
    rho3d = torch.where(ok3, u * u + v * v, torch.full_like(u, math.inf))
    d = means2d[None] - pix[:, None, :]  # (P,n,2)
    rho2d = FILTER_INV_SQUARE * (d * d).sum(-1)
    use3 = rho3d <= rho2d
    rho = torch.where(use3, rho3d, rho2d)
    z = torch.where(use3, zhit, depths[None].expand_as(zhit))
    alpha = torch.clamp(opac[None] * torch.exp(-0.5 * rho), max=ALPHA_MAX)
    ok = (rho <= CUTOFF * CUTOFF) & (alpha >= ALPHA_MIN)
    alpha = torch.where(ok, alpha, torch.zeros_like(alpha))
    with torch.no_grad():  # early termination: a prefix, the transmittance never increases
        keep = torch.cumprod(1.0 - alpha, dim=1) >= T_MIN
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    contrib = alpha > 0
    t_after = torch.cumprod(1.0 - alpha, dim=1)
    t_before = torch.cat([torch.ones_like(t_after[:, :1]), t_after[:, :-1]], dim=1)
    w = alpha * t_before  # (P,n)
    z = torch.where(contrib, z, torch.ones_like(z))
    m = torch.where(contrib, mapped_depth(z), torch.zeros_like(z))
    ms, order = torch.sort(m, dim=1, stable=True)  # sum_ij w_i w_j |m_i - m_j| = 2 sum_k w_k (m_k W_<k - WM_<k)
    ws = w.gather(1, order)
    w_before = torch.cumsum(ws, 1) - ws
    wm_before = torch.cumsum(ws * ms, 1) - ws * ms
    dist = 2.0 * (ws * (ms * w_before - wm_before)).sum(1)
    with torch.no_grad():
        crossed = t_after < MEDIAN_T
        has = crossed.any(1)
        idx = crossed.to(torch.int64).argmax(1)
    zmed = torch.where(has, z.gather(1, idx[:, None])[:, 0], torch.zeros_like(dist))
    cols = [w @ colors, w.sum(1, keepdim=True), (w * z).sum(1, keepdim=True), w @ normals, dist[:, None], zmed[:, None]]
    return torch.cat(cols, dim=1)


def raster_reference(proj: SurfelProjection, colors: Tensor, opac: Tensor, width: int, height: int, near: float) -> Tensor:
    """(C,H,W,N_OUT) raster outputs, tile by tile in torch (tiles only limit the work; results do not depend on them)."""
    C = proj.M.shape[0]
    values, index = [], []
    for cam, members, pix, flat in tile_walk(proj.depths, torch.from_numpy(tile_rects(proj.boxes)), width, height, TILE):
        values.append(
            composite_surfels_reference(
                pix, proj.M[cam, members], proj.means2d[cam, members], proj.depths[cam, members],
                proj.normals[cam, members], colors[members], opac[members], near,
            )  # fmt: skip
        )
        index.append(flat)
    out = torch.zeros(C * height * width, N_OUT, dtype=torch.float64)
    if values:
        out = out.index_copy(0, torch.cat(index), torch.cat(values))
    out = out + 0.0 * (proj.M.sum() + proj.normals.sum() + colors.sum() + opac.sum())  # keep attached when empty
    return out.reshape(C, height, width, N_OUT)


# ---------------------------------------------------------------------------------------------------------
# numba backend


def _np(x: Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().numpy(), dtype=np.float64)


class _SurfelRasterCPU(torch.autograd.Function):
    """Per-pixel compositing of projected surfels by the numba kernels, with their hand-written backward."""

    @staticmethod
    def forward(ctx, M, means2d, depths, normals, colors, opac, boxes, width, height, near):  # noqa: D102
        from clods_bench.splatting import fast_kernels as FK, surfel_kernels as SK

        C, G = depths.shape
        tiles_x, tiles_y = math.ceil(width / TILE), math.ceil(height / TILE)
        zc = _np(depths)
        offsets, ids = FK.sort_and_bin(zc, tile_rects(boxes), tiles_x, tiles_y)
        cg = (np.ascontiguousarray(np.broadcast_to(_np(colors), (C, G, 3))), np.ascontiguousarray(np.broadcast_to(_np(opac), (C, G))))
        args = (_np(M).reshape(C, G, 9), _np(means2d), zc, _np(normals), cg[0], cg[1], np.ascontiguousarray(boxes),
                offsets, ids, width, height, TILE, tiles_x, tiles_y, float(near))  # fmt: skip
        out = np.zeros((C, height, width, N_OUT))
        t_final = np.empty((C, height, width))
        n_last = np.empty((C, height, width), dtype=np.int32)
        med = np.empty((C, height, width), dtype=np.int32)
        SK.raster_fwd(*args, out, t_final, n_last, med)
        ctx.args, ctx.state = args, (t_final, n_last, med)
        return torch.from_numpy(out)

    @staticmethod
    @once_differentiable
    def backward(ctx, v_out):  # noqa: D102
        from clods_bench.splatting import surfel_kernels as SK

        args, (t_final, n_last, med) = ctx.args, ctx.state
        offsets, ids = args[7], args[8]
        C, G = args[2].shape
        g_isect = np.empty((ids.shape[0], SK.N_GRAD))
        SK.raster_bwd(*args, t_final, n_last, med, _np(v_out), g_isect)
        grads = np.zeros((C, G, SK.N_GRAD))
        SK.reduce_grads(offsets, ids, g_isect, args[12] * args[13], grads)
        g = torch.from_numpy(grads)
        g_col = g[..., 15:18].sum(0)
        g_opac = g[..., 18].sum(0)
        return (g[..., 0:9].reshape(C, G, 3, 3), g[..., 9:11], g[..., 11], g[..., 12:15], g_col, g_opac,
                None, None, None, None)  # fmt: skip


# ---------------------------------------------------------------------------------------------------------
# public API


def _check_inputs(means, quats, scales, opacities, colors) -> int:
    check_shape(means, (None, 3), "means")
    G = means.shape[0]
    check_shape(quats, (G, 4), "quats")
    check_shape(scales, (G, 2), "scales")
    check_shape(opacities, (G,), "opacities")
    check_shape(colors, (G, 3), "colors")
    for x, name in ((means, "means"), (quats, "quats"), (scales, "scales"), (opacities, "opacities"), (colors, "colors")):
        check_finite(x, name)
    bad = torch.nonzero(quats.detach().norm(dim=-1) < 1e-12)
    if bad.numel():
        i = int(bad[0, 0])
        raise ClodsError("zero quaternion: cannot normalise it to a rotation", where=f"quats[{i}]",
                         hint="quaternions (w, x, y, z) need not be unit length (they are normalised) but must be non-zero")  # fmt: skip
    bad = torch.nonzero(scales.detach() <= 0)
    if bad.numel():
        i = int(bad[0, 0])
        raise ClodsError(f"scales must be positive std devs, got {scales[i].detach().tolist()}", where=f"scales[{i}]")
    bad = torch.nonzero((opacities.detach() < 0) | (opacities.detach() > 1))
    if bad.numel():
        i = int(bad[0, 0])
        raise ClodsError(f"opacity must be in [0, 1], got {float(opacities[i])}", where=f"opacities[{i}]")
    return G


def render_surfels(
    means: Tensor,  # (G,3) world-space centres
    quats: Tensor,  # (G,4) rotations (w, x, y, z), normalised here; tangent axes = columns 0, 1
    scales: Tensor,  # (G,2) tangent std devs s_u, s_v (> 0)
    opacities: Tensor,  # (G,) in [0, 1]
    colors: Tensor,  # (G,3) RGB
    cameras: Sequence[Camera],
    *,
    background: Sequence[float] | Tensor = (1.0, 1.0, 1.0),
    backend: SurfelBackend = "cpu",
    near: float = 0.01,
) -> SurfelOutput:
    """Differentiably render 2DGS surfels into every camera (rules in the module docstring).

    Args:
        means, quats, scales, opacities, colors: the surfels; wrong shapes, NaN/inf, zero quaternions,
            non-positive scales or opacities outside [0, 1] raise ClodsError naming the argument.
        cameras: C pinhole cameras sharing one image size.
        background: (3,) or (C,3) colour behind the surfels; a tensor gets gradients.
        backend: 'cpu' (numba kernels), 'reference' (plain torch; small scenes) or 'gsplat' (gsplat's 2DGS
            kernels on CUDA, differences in `surfel_gsplat`; inputs may be on the CPU or a GPU).
        near: surfels with centre z <= near are culled; ray hits must lie beyond it.

    Returns:
        SurfelOutput of (C,H,W,.) maps in the dtype and on the device of `means`.
    """
    if backend not in BACKENDS:
        raise ClodsError(f"unknown backend '{backend}'; known: {', '.join(BACKENDS)}", where="backend")
    if not (isinstance(near, (int, float)) and math.isfinite(near) and near > 0):
        raise ClodsError(f"near plane must be a positive number, got {near}", where="near")
    _check_inputs(means, quats, scales, opacities, colors)
    if backend != "gsplat":
        for x, name in ((means, "means"), (quats, "quats"), (scales, "scales"), (opacities, "opacities"), (colors, "colors")):
            if x.device.type != "cpu":
                raise ClodsError(f"backend '{backend}' runs on the CPU, got tensors on {x.device}", where=name,
                                 hint="use backend='gsplat' for CUDA tensors")  # fmt: skip
    width, height = check_cameras(cameras)
    f64 = torch.float64
    if backend == "gsplat":
        return _render_gsplat(means, quats, scales, opacities, colors, cameras, background, near, width, height)
    bg = background_tensor(background, len(cameras), f64)
    proj = project_surfels(means, quats, scales, opacities, cameras, near)
    col, opac = colors.to(f64), opacities.to(f64)
    if backend == "cpu":
        raster = _SurfelRasterCPU.apply(proj.M, proj.means2d, proj.depths, proj.normals, col, opac, proj.boxes,
                                        width, height, float(near))  # fmt: skip
    else:
        raster = raster_reference(proj, col, opac, width, height, float(near))
    return _output(raster[..., 0:3], raster[..., 3:4], raster[..., 4:5], raster[..., 9:10], raster[..., 5:8],
                   raster[..., 8:9], bg, means)  # fmt: skip


def _output(color: Tensor, alpha: Tensor, depth_acc: Tensor, median: Tensor, normal: Tensor, distortion: Tensor,
            bg: Tensor, means: Tensor) -> SurfelOutput:  # fmt: skip
    """The SurfelOutput of raster maps (colour without background, sum w z, ...): background composited, expected
    depth normalised, every map in the dtype and on the device of `means` (autograd follows)."""
    maps = {"rgb": color + (1.0 - alpha) * bg[:, None, None, :], "alpha": alpha, "depth_median": median,
            "depth_expected": depth_acc / alpha.clamp(min=1e-10), "normal": normal, "distortion": distortion}  # fmt: skip
    return SurfelOutput(**{k: v.to(device=means.device, dtype=means.dtype) for k, v in maps.items()})


def unmapped_depth(m: Tensor) -> Tensor:
    """Camera z of a 2DGS-mapped depth m (inverse of `mapped_depth`)."""
    return DIST_NEAR / (1.0 - m * (DIST_FAR - DIST_NEAR) / DIST_FAR)


def _render_gsplat(means, quats, scales, opacities, colors, cameras, background, near, width, height) -> SurfelOutput:
    """render_surfels through gsplat's 2DGS kernels (`surfel_gsplat`), maps returned like the CPU backends'."""
    from clods_bench.splatting import gsplat_backend
    from clods_bench.splatting.surfel_gsplat import raster_surfels_gsplat

    ok, why = gsplat_backend.gsplat_available()
    if not ok:
        raise ClodsError(gsplat_backend.INSTALL_HINT, where="render_surfels(backend='gsplat')", hint=why)
    f64 = torch.float64
    dev = gsplat_backend.gpu_for(means)
    m, q, s, o, c = (x.to(dev) for x in (means, quats, scales, opacities, colors))
    bg = background_tensor(background, len(cameras), f64).to(dev)
    proj = project_surfels(m, q, s, o, cameras, near)
    valid = torch.from_numpy(proj.valid).to(dev)
    mapped = mapped_depth(torch.where(valid, proj.depths, torch.ones_like(proj.depths)))  # culled: never read
    r = raster_surfels_gsplat(proj.M, proj.means2d, proj.depths, mapped, proj.normals, c.to(f64), o.to(f64),
                              torch.from_numpy(proj.boxes), width, height, TILE)  # fmt: skip
    r = {k: v.to(f64) for k, v in r.items()}
    median = torch.where(r["alpha"] > MEDIAN_T, unmapped_depth(r["mapped_median"]), torch.zeros_like(r["alpha"]))
    return _output(r["color"], r["alpha"], r["depth_acc"], median, r["normal"], r["distortion"], bg, means)
