"""TSDF fusion of per-view depth maps and marching-cubes surface extraction (paper appendix, "Initial mesh extraction").

The first frame of a multi-view video gives one depth map per view (from a fitted 2DGS / NeRF-style model, or
rendered from a known mesh in tests). `fuse_depth_maps` fuses them into a truncated signed distance field on a
voxel grid: every voxel centre is projected into every view; where the pixel holds a valid depth, the projective
signed distance `depth - z_cam` (positive in front of the surface) is truncated at `trunc` and averaged over the
views with the views' weights (a mask or alpha per pixel, optional). Voxels further than `trunc` behind the surface
seen by a view are not updated by that view (they may be anything: inside an object, or free space behind a thin
sheet). `extract_surface` runs marching cubes at level 0 on the voxels some view updated, and returns world
coordinates. `backproject` lifts the depth maps to a world point cloud (also what `bounds=None` is computed from).

Thin cloth: a sheet seen from both sides has no inside; with the plain TSDF, a voxel just in front of the sheet for
one camera is just behind it for a camera on the other side, the two average to about zero, and the zero level set
is a noisy two-sided shell within `trunc` of the sheet. `orient` signs each pixel's contribution by the side of the
sheet it sees (the depth map's normal against a reference direction, by default the points' least-variance PCA
axis), so every view agrees on the sign and the zero level set is the open sheet itself (as long as the cloth does
not fold over itself along that direction: see `sheet_mesh`). Either way the extracted surface is not a simulation
mesh; `sheet_mesh.sheet_from_points` turns its points into one.

Why numba + scikit-image rather than Open3D's ScalableTSDFVolume: the project's geometry already runs on a pure
numpy / numba stack (rasteriser, solver, obstacle kernels) and scikit-image is already a dependency, so the fusion
is ~100 lines with nothing new to install; Open3D is a large optional binary dependency (not installed in the
project's environment: `import open3d` fails there), ties itself to specific Python versions, and would need
conversion of our OpenCV-convention cameras anyway. The kernel is a direct loop over voxels x views, fast enough for
the grids used here (a 2 m flag at 2 cm voxels is ~0.25 M voxels: under 0.1 s for 6 views once compiled).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numba
import numpy as np

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError

MAX_VOXELS = 200_000_000
"""Largest grid `fuse_depth_maps` builds (float32 tsdf + weight: 1.6 GB); larger asks for a coarser voxel size."""


@dataclass
class TsdfVolume:
    """A fused TSDF: voxel (i, j, k) has its centre at `origin + voxel_size * (i, j, k)`.

    `tsdf` (X,Y,Z) float32 is the weighted mean of the views' truncated signed distances divided by `trunc` (in
    [-1, 1], positive in front of the surface; 1 where no view updated the voxel) and `weight` (X,Y,Z) float32 the
    sum of the weights of the views that updated it (0: unobserved).
    """

    tsdf: np.ndarray
    weight: np.ndarray
    origin: np.ndarray
    voxel_size: float
    trunc: float

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(s) for s in self.tsdf.shape)  # type: ignore[return-value]

    def voxel_centers(self) -> np.ndarray:
        """(X,Y,Z,3) world coordinates of the voxel centres."""
        axes = [self.origin[d] + self.voxel_size * np.arange(n) for d, n in enumerate(self.shape)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def _check_inputs(depths: np.ndarray, cameras: Sequence[Camera], weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """float64 depths (C,H,W) with non-finite or non-positive pixels as inf, float64 weights (C,H,W)."""
    d = np.asarray(depths)
    if d.ndim != 3:
        raise ClodsError(f"depths has shape {tuple(d.shape)}, expected (C, H, W): one depth map per camera", where="depths")
    if not np.issubdtype(d.dtype, np.floating):
        raise ClodsError(f"depths has dtype {d.dtype}, expected floats (inf on background)", where="depths")
    cams = list(cameras)
    if len(cams) != d.shape[0]:
        raise ClodsError(f"{d.shape[0]} depth maps but {len(cams)} cameras", where="cameras", hint="one camera per depth map")
    for i, cam in enumerate(cams):
        if not isinstance(cam, Camera):
            raise ClodsError(f"cameras[{i}] is a {type(cam).__name__}, expected a Camera", where="cameras")
        cam.validate(f"cameras[{i}]")
        if (cam.height, cam.width) != d.shape[1:]:
            raise ClodsError(
                f"depth map {i} is {d.shape[2]}x{d.shape[1]} (W x H) but cameras[{i}] is {cam.width}x{cam.height}",
                where="depths",
            )
    nan = np.isnan(d)
    if nan.any():
        first = tuple(int(i) for i in np.argwhere(nan)[0])
        raise ClodsError(f"{int(nan.sum())} NaN depths, first at {first}", where="depths", hint="mark missing depth with inf")
    if np.any(d < 0):
        raise ClodsError(f"{int(np.sum(d < 0))} negative depths (camera-z depth is positive)", where="depths")
    d = np.where(np.isfinite(d) & (d > 0), d, np.inf).astype(np.float64)
    if weights is None:
        w = np.ones(d.shape, dtype=np.float64)
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != d.shape:
            raise ClodsError(f"weights has shape {w.shape}, expected the depths' {d.shape}", where="weights")
        if not np.isfinite(w).all() or np.any(w < 0):
            raise ClodsError("weights must be finite and non-negative (a mask or alpha per pixel)", where="weights")
    if not np.isfinite(d).any():
        raise ClodsError("no pixel of any depth map holds a depth", where="depths")
    return d, w


def _camera_points(depth: np.ndarray, cam: Camera) -> np.ndarray:
    """(H,W,3) camera-frame points of the pixel centres (inf where the depth is invalid)."""
    h, w = depth.shape
    K = np.asarray(cam.K, dtype=np.float64)
    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5, indexing="xy")
    x = (cols - K[0, 2]) / K[0, 0] * depth
    y = (rows - K[1, 2]) / K[1, 1] * depth
    return np.stack([x, y, depth], axis=-1)


def backproject(depths: np.ndarray, cameras: Sequence[Camera], weights: np.ndarray | None = None) -> np.ndarray:
    """(N,3) world points of every pixel with a finite positive depth (and a positive weight, if given)."""
    d, w = _check_inputs(depths, cameras, weights)
    out = []
    for i, cam in enumerate(cameras):
        pc = _camera_points(d[i], cam)
        ok = np.isfinite(d[i]) & (w[i] > 0)
        p = pc[ok]
        out.append((p - np.asarray(cam.t, float)) @ np.asarray(cam.R, float))  # R^T (x_cam - t)
    return np.concatenate(out, axis=0)


def _one_sided(p: np.ndarray, axis: int) -> np.ndarray:
    """Difference of neighbouring points along `axis`: central where both neighbours are valid, else one-sided."""
    fwd = np.full_like(p, np.nan)
    bwd = np.full_like(p, np.nan)
    sl = [slice(None)] * 3
    a, b = list(sl), list(sl)
    a[axis], b[axis] = slice(1, None), slice(None, -1)
    diff = p[tuple(a)] - p[tuple(b)]
    fwd[tuple(b)] = diff  # p[i+1] - p[i] stored at i
    bwd[tuple(a)] = diff  # p[i] - p[i-1] stored at i
    fwd[~np.isfinite(fwd)] = np.nan
    bwd[~np.isfinite(bwd)] = np.nan
    central = 0.5 * (fwd + bwd)
    out = np.where(np.isfinite(central), central, np.where(np.isfinite(fwd), fwd, bwd))
    return out


def pixel_sides(depths: np.ndarray, cameras: Sequence[Camera], axis: np.ndarray, min_cos: float = 0.05) -> np.ndarray:
    """(C,H,W) float64: +1 where a pixel sees the side of the surface facing `axis`, -1 the other side, 0 unknown.

    The side is the sign of the depth map's normal (turned to face the camera) against `axis`; pixels without two
    valid neighbours, or whose normal is within acos(min_cos) of perpendicular to `axis`, get 0 (not fused).
    """
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    out = np.zeros(np.shape(depths), dtype=np.float64)
    for i, cam in enumerate(cameras):
        pc = _camera_points(np.asarray(depths[i], dtype=np.float64), cam)
        pc[~np.isfinite(pc)] = np.nan
        du, dv = _one_sided(pc, 1), _one_sided(pc, 0)
        n = np.cross(du, dv)
        facing = np.sum(n * pc, axis=-1)  # n . (p - camera centre); camera centre is the origin: want it negative
        n = np.where((facing > 0)[..., None], -n, n)
        nw = n @ np.asarray(cam.R, float)  # R^T n: world frame
        norm = np.linalg.norm(nw, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = (nw @ axis) / norm
        side = np.where(np.isfinite(cos) & (np.abs(cos) >= min_cos), np.sign(cos), 0.0)
        out[i] = side
    return out


@numba.njit(cache=True)
def _sample_depth(depth: np.ndarray, u: float, v: float, spread: float) -> float:
    """Depth at image point (u, v): bilinear between the 4 nearest pixel centres when all hold depths within `spread`
    of each other (no silhouette between them), else the pixel containing (u, v); inf if that one has none."""
    h, w = depth.shape
    col, row = int(np.floor(u)), int(np.floor(v))
    if col < 0 or row < 0 or col >= w or row >= h:
        return np.inf
    nearest = depth[row, col]
    uu, vv = u - 0.5, v - 0.5
    c0, r0 = int(np.floor(uu)), int(np.floor(vv))
    if c0 < 0 or r0 < 0 or c0 + 1 >= w or r0 + 1 >= h:
        return nearest
    a, b, c, d = depth[r0, c0], depth[r0, c0 + 1], depth[r0 + 1, c0], depth[r0 + 1, c0 + 1]
    lo = min(min(a, b), min(c, d))
    hi = max(max(a, b), max(c, d))
    if not np.isfinite(hi) or hi - lo > spread:
        return nearest
    fu, fv = uu - c0, vv - r0
    return (1 - fv) * ((1 - fu) * a + fu * b) + fv * ((1 - fu) * c + fu * d)


@numba.njit(cache=True)
def _fuse_kernel(depths, weights, sides, Ks, Rs, ts, origin, voxel_size, dims, trunc, tsdf, wsum):  # pragma: no cover - numba
    n_cam = depths.shape[0]
    for i in range(dims[0]):
        x = origin[0] + voxel_size * i
        for j in range(dims[1]):
            y = origin[1] + voxel_size * j
            for k in range(dims[2]):
                z = origin[2] + voxel_size * k
                acc = 0.0
                wacc = 0.0
                for c in range(n_cam):
                    R = Rs[c]
                    xc = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + ts[c, 0]
                    yc = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + ts[c, 1]
                    zc = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + ts[c, 2]
                    if zc <= 1e-9:
                        continue
                    u = Ks[c, 0, 0] * xc / zc + Ks[c, 0, 2]
                    v = Ks[c, 1, 1] * yc / zc + Ks[c, 1, 2]
                    if not (u >= 0.0 and v >= 0.0 and u < depths.shape[2] and v < depths.shape[1]):
                        continue
                    col, row = int(u), int(v)
                    w = weights[c, row, col]
                    s = sides[c, row, col]
                    if w <= 0.0 or s == 0.0:
                        continue
                    d = _sample_depth(depths[c], u, v, trunc)
                    if not np.isfinite(d):
                        continue
                    sdf = d - zc
                    if sdf < -trunc:
                        continue  # far behind the surface this view sees: unknown
                    if sdf > trunc:
                        sdf = trunc
                    acc += w * s * sdf / trunc
                    wacc += w
                if wacc > 0.0:
                    tsdf[i, j, k] = acc / wacc
                    wsum[i, j, k] = wacc


def fuse_depth_maps(
    depths: np.ndarray,
    cameras: Sequence[Camera],
    bounds: tuple[np.ndarray, np.ndarray] | None,
    voxel_size: float,
    trunc: float | None = None,
    weights: np.ndarray | None = None,
    orient: bool | np.ndarray = False,
) -> TsdfVolume:
    """Fuse (C,H,W) camera-z depth maps (inf: no depth) seen by `cameras` into a TSDF over `bounds` (lo, hi) in metres.

    bounds=None: the back-projected points' bounding box grown by `trunc` plus one voxel. `trunc` defaults to 3
    voxels. `weights` (C,H,W) >= 0 weighs each pixel's contribution (a foreground mask or alpha; 0: ignored).
    `orient`: False for closed surfaces (plain TSDF); True or a world direction for an open thin sheet: each pixel's
    distance is signed by the side of the sheet it sees (see the module docstring; True: the direction of least
    variance of the back-projected points).
    """
    d, w = _check_inputs(depths, cameras, weights)
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise ClodsError(f"voxel_size must be a positive number of metres, got {voxel_size}", where="voxel_size")
    trunc = 3.0 * float(voxel_size) if trunc is None else float(trunc)
    if not (np.isfinite(trunc) and trunc > 0):
        raise ClodsError(f"trunc must be a positive number of metres, got {trunc}", where="trunc")
    points = None
    if bounds is None:
        points = backproject(d, cameras, w)
        lo, hi = points.min(axis=0) - trunc - voxel_size, points.max(axis=0) + trunc + voxel_size
    else:
        try:
            lo, hi = (np.asarray(b, dtype=np.float64).reshape(3) for b in bounds)
        except (TypeError, ValueError) as exc:
            raise ClodsError(f"bounds must be a pair (lo, hi) of 3-vectors: {exc}", where="bounds") from exc
        if not (np.isfinite(lo).all() and np.isfinite(hi).all() and np.all(hi > lo)):
            raise ClodsError(f"bounds must be finite with hi > lo on every axis, got lo={lo}, hi={hi}", where="bounds")
    dims = np.floor((hi - lo) / voxel_size).astype(np.int64) + 1
    if int(np.prod(dims)) > MAX_VOXELS:
        raise ClodsError(
            f"a {dims[0]}x{dims[1]}x{dims[2]} grid has more than {MAX_VOXELS} voxels", where="voxel_size", hint="use a larger voxel size"
        )
    if orient is False or orient is None:
        sides = np.ones(d.shape, dtype=np.float64)
    else:
        if orient is True:
            if points is None:
                points = backproject(d, cameras, w)
            centred = points - points.mean(axis=0)
            axis = np.linalg.eigh(centred.T @ centred)[1][:, 0]
        else:
            axis = np.asarray(orient, dtype=np.float64).reshape(-1)
            if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
                raise ClodsError(f"orient must be True, False or a non-zero 3-vector, got {orient!r}", where="orient")
        sides = pixel_sides(d, cameras, axis)
    Ks = np.stack([np.asarray(c.K, np.float64) for c in cameras])
    Rs = np.stack([np.asarray(c.R, np.float64) for c in cameras])
    ts = np.stack([np.asarray(c.t, np.float64) for c in cameras])
    tsdf = np.ones(tuple(dims), dtype=np.float32)
    wsum = np.zeros(tuple(dims), dtype=np.float32)
    _fuse_kernel(d, w, sides, Ks, Rs, ts, lo.astype(np.float64), float(voxel_size), dims, trunc, tsdf, wsum)
    return TsdfVolume(tsdf, wsum, lo.astype(np.float64), float(voxel_size), trunc)


def extract_surface(volume: TsdfVolume, min_weight: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes at level 0 over the voxels with weight > `min_weight`: (V,3) float64 world vertices, (F,3) int64 faces."""
    from skimage.measure import marching_cubes

    if min(volume.shape) < 2:
        raise ClodsError(f"the volume is {volume.shape} voxels; marching cubes needs at least 2 per axis", where="volume")
    seen = volume.weight > min_weight
    # skimage (0.2x) tests one mask entry per cube, at its last corner (the cube between voxels i and i+1 reads
    # mask[i+1]): mark a cube valid when all 8 of its corners were seen, so unseen voxels (tsdf 1 by convention)
    # next to negative ones make no spurious surface (checked by test_reconstruct's sphere test)
    mask = np.zeros_like(seen)
    mask[1:, 1:, 1:] = np.logical_and.reduce(
        [seen[a : a + seen.shape[0] - 1, b : b + seen.shape[1] - 1, c : c + seen.shape[2] - 1]
         for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    )  # fmt: skip
    vals = volume.tsdf[seen]
    if vals.size == 0 or not (vals.min() < 0.0 < vals.max()):
        raise ClodsError("the fused volume has no zero crossing: no surface to extract", where="volume",
                         hint="check the bounds, the cameras and the depth maps' units")  # fmt: skip
    verts, faces, _, _ = marching_cubes(volume.tsdf, level=0.0, spacing=(volume.voxel_size,) * 3, mask=mask)
    return verts.astype(np.float64) + volume.origin, faces.astype(np.int64)


def trim_to_support(verts: np.ndarray, faces: np.ndarray, support: np.ndarray, max_distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Drop the vertices further than `max_distance` from every `support` point (N,3) (the back-projected depths), and
    the faces using them: the zero level set of a thin sheet runs on past the cloth's edges by up to `trunc`
    (voxels beyond an edge still get one sign from the views that see the cloth behind them); the depth maps do not.
    Returns the kept (V',3) vertices and (F',3) faces, re-indexed."""
    from scipy.spatial import cKDTree

    v = np.asarray(verts, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    s = np.asarray(support, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 3 or s.shape[0] == 0 or not np.isfinite(s).all():
        raise ClodsError(f"support has shape {s.shape}, expected (N>0, 3) finite points", where="support")
    if not (np.isfinite(max_distance) and max_distance > 0):
        raise ClodsError(f"max_distance must be a positive number of metres, got {max_distance}", where="max_distance")
    keep = cKDTree(s).query(v, distance_upper_bound=max_distance)[0] <= max_distance
    remap = np.full(v.shape[0], -1, dtype=np.int64)
    remap[keep] = np.arange(int(keep.sum()))
    f2 = remap[f]
    return v[keep], f2[(f2 >= 0).all(axis=1)]
