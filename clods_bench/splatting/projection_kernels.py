"""Numba twin of `projection.project_gaussians` (float64 EWA projection) with a hand-written backward, and depth
sorting plus tile binning, for the fast CPU backend (nothing compiles at import).

`project_fwd` reproduces the torch projection entry by entry (same culling, Jacobian clamp, 0.3 px^2
dilation, opacity-aware radii and tile rectangles); `project_bwd` is the chain rule of the same formulas
(checked against torch autograd in the tests), summed over cameras one Gaussian per parallel iteration,
so no two threads write the same memory. `sort_and_bin` sorts each camera's rendered Gaussians by depth
(stable: ties by index, as torch.argsort(stable=True)) and appends them to the tiles they touch.
Everything stays in float64 from the input Gaussians to the composited pixels: rounding depths or
centres to float32 between projection and compositing would reorder near-tied Gaussians and move
pixels across the 1/255 alpha threshold.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

ALPHA_MIN = 1.0 / 255.0  # same as projection.ALPHA_MIN
MAX_RADIUS = float(1 << 28)  # same as projection.MAX_RADIUS
N_CAM = 13  # camera row: fx, fy, cx, cy, R (9, row-major) -- t is passed separately


@njit(cache=True, nogil=True, inline="always")
def _clamp(v, lo, hi):
    """(clamped value, True if v was inside [lo, hi]) as torch.clamp's value and gradient mask."""
    if v < lo:
        return lo, False
    if v > hi:
        return hi, False
    return v, True


@njit(cache=True, nogil=True)
def _cov2d(S, T):
    """(a, b, c) of sym(T S T^T) for the (2,3) matrix T (a tuple, row-major) and (3,3) S."""
    ts0 = (T[0] * S[0, 0] + T[1] * S[1, 0] + T[2] * S[2, 0], T[0] * S[0, 1] + T[1] * S[1, 1] + T[2] * S[2, 1],
           T[0] * S[0, 2] + T[1] * S[1, 2] + T[2] * S[2, 2])  # fmt: skip
    ts1 = (T[3] * S[0, 0] + T[4] * S[1, 0] + T[5] * S[2, 0], T[3] * S[0, 1] + T[4] * S[1, 1] + T[5] * S[2, 1],
           T[3] * S[0, 2] + T[4] * S[1, 2] + T[5] * S[2, 2])  # fmt: skip
    m00 = ts0[0] * T[0] + ts0[1] * T[1] + ts0[2] * T[2]
    m01 = ts0[0] * T[3] + ts0[1] * T[4] + ts0[2] * T[5]
    m10 = ts1[0] * T[0] + ts1[1] * T[1] + ts1[2] * T[2]
    m11 = ts1[0] * T[3] + ts1[1] * T[4] + ts1[2] * T[5]
    return m00, 0.5 * (m01 + m10), m11


@njit(cache=True, nogil=True)
def _jacobian(x, y, z, cam, lims):
    """(T, tx, ty, x inside the clamp, y inside the clamp): T = J R (2x3, a row-major tuple) at the camera-space centre."""
    fx, fy = cam[0], cam[1]
    cx_, okx = _clamp(x / z, -lims[0], lims[1])
    cy_, oky = _clamp(y / z, -lims[2], lims[3])
    tx, ty = z * cx_, z * cy_
    J00, J02 = fx / z, -fx * tx / (z * z)
    J11, J12 = fy / z, -fy * ty / (z * z)
    T = (J00 * cam[4] + J02 * cam[10], J00 * cam[5] + J02 * cam[11], J00 * cam[6] + J02 * cam[12],
         J11 * cam[7] + J12 * cam[10], J11 * cam[8] + J12 * cam[11], J11 * cam[9] + J12 * cam[12])  # fmt: skip
    return T, tx, ty, okx, oky


@njit(cache=True, nogil=True, parallel=True)
def project_fwd(means, covars, opac, cams, ts, lims, width, height, near, eps2d, tile,
                means2d, depths, conics, radii, bounds, thresholds):  # fmt: skip
    """Project every (camera, Gaussian); culled entries get radii 0, empty bounds and zero conics.

    thresholds (C,G): log(255 opacity), the largest sigma whose alpha reaches 1/255 (the kernels' row ranges).
    """
    C, G = depths.shape
    tiles_x, tiles_y = (width + tile - 1) // tile, (height + tile - 1) // tile
    for cg in prange(C * G):
        cam, g = cg // G, cg % G
        S = covars[g]
        m = means[g]
        cr = cams[cam]
        x = cr[4] * m[0] + cr[5] * m[1] + cr[6] * m[2] + ts[cam, 0]
        y = cr[7] * m[0] + cr[8] * m[1] + cr[9] * m[2] + ts[cam, 1]
        z = cr[10] * m[0] + cr[11] * m[1] + cr[12] * m[2] + ts[cam, 2]
        depths[cam, g] = z
        finite = True
        for i in range(3):
            finite = finite and math.isfinite(m[i])
            for j in range(3):
                finite = finite and math.isfinite(S[i, j])
        means2d[cam, g, 0] = 0.0
        means2d[cam, g, 1] = 0.0
        conics[cam, g, 0] = conics[cam, g, 1] = conics[cam, g, 2] = 0.0
        radii[cam, g, 0] = radii[cam, g, 1] = 0
        bounds[cam, g, 0] = bounds[cam, g, 1] = bounds[cam, g, 2] = bounds[cam, g, 3] = 0
        thresholds[cam, g] = -1.0
        if not (finite and z > near):
            continue
        u = cr[0] * x / z + cr[2]
        v = cr[1] * y / z + cr[3]
        means2d[cam, g, 0], means2d[cam, g, 1] = u, v
        T, _, _, _, _ = _jacobian(x, y, z, cr, lims[cam])
        a, b, c = _cov2d(S, T)
        a += eps2d
        c += eps2d
        det = a * c - b * b
        if not (math.isfinite(det) and det > 0):
            continue
        o = opac[cam, g]
        if not o >= ALPHA_MIN:
            continue
        log_o = math.log(o / ALPHA_MIN)  # sigma where alpha falls to 1/255: the radius here, the row ranges' threshold
        k = math.sqrt(2.0 * log_o)
        rx, ry = k * math.sqrt(max(a, 0.0)), k * math.sqrt(max(c, 0.0))
        rx = min(math.ceil(rx), MAX_RADIUS) if math.isfinite(rx) else (MAX_RADIUS if rx > 0 else 0.0)
        ry = min(math.ceil(ry), MAX_RADIUS) if math.isfinite(ry) else (MAX_RADIUS if ry > 0 else 0.0)
        if not (rx > 0 and ry > 0 and u + rx > 0 and u - rx < width and v + ry > 0 and v - ry < height):
            continue
        conics[cam, g, 0], conics[cam, g, 1], conics[cam, g, 2] = c / det, -b / det, a / det
        radii[cam, g, 0], radii[cam, g, 1] = int(rx), int(ry)
        bounds[cam, g, 0] = int(min(max(math.floor((u - rx) / tile), 0.0), tiles_x))
        bounds[cam, g, 1] = int(min(max(math.floor((v - ry) / tile), 0.0), tiles_y))
        bounds[cam, g, 2] = int(min(max(math.ceil((u + rx) / tile), 0.0), tiles_x))
        bounds[cam, g, 3] = int(min(max(math.ceil((v + ry) / tile), 0.0), tiles_y))
        thresholds[cam, g] = log_o


@njit(cache=True, nogil=True, inline="always")
def _vt_row(p, q, T, S):
    """One row of V T (S + S^T): the row (p T[0:3] + q T[3:6]) times S + S^T, summed over k in order 0, 1, 2."""
    r0, r1, r2 = p * T[0] + q * T[3], p * T[1] + q * T[4], p * T[2] + q * T[5]
    out0 = r0 * (S[0, 0] + S[0, 0]) + r1 * (S[1, 0] + S[0, 1]) + r2 * (S[2, 0] + S[0, 2])
    out1 = r0 * (S[0, 1] + S[1, 0]) + r1 * (S[1, 1] + S[1, 1]) + r2 * (S[2, 1] + S[1, 2])
    out2 = r0 * (S[0, 2] + S[2, 0]) + r1 * (S[1, 2] + S[2, 1]) + r2 * (S[2, 2] + S[2, 2])
    return out0, out1, out2


@njit(cache=True, nogil=True, parallel=True)
def project_bwd(means, covars, cams, ts, lims, eps2d, radii, v_means2d, v_conics, v_depths, v_means, v_covars):
    """Chain rule of `project_fwd` from d loss / d (means2d, conics, depths) to means (G,3) and covars (G,3,3)."""
    C, G = v_depths.shape
    for g in prange(G):
        S = covars[g]
        m = means[g]
        for cam in range(C):
            if radii[cam, g, 0] <= 0:
                continue
            cr = cams[cam]
            x = cr[4] * m[0] + cr[5] * m[1] + cr[6] * m[2] + ts[cam, 0]
            y = cr[7] * m[0] + cr[8] * m[1] + cr[9] * m[2] + ts[cam, 1]
            z = cr[10] * m[0] + cr[11] * m[1] + cr[12] * m[2] + ts[cam, 2]
            fx, fy = cr[0], cr[1]
            T, tx, ty, okx, oky = _jacobian(x, y, z, cr, lims[cam])
            a, b, c = _cov2d(S, T)
            a, c = a + eps2d, c + eps2d  # conic (c/D, -b/D, a/D) of the dilated covariance
            det = a * c - b * b
            v0, v1, v2 = v_conics[cam, g, 0], v_conics[cam, g, 1], v_conics[cam, g, 2]
            vD = -(v0 * c - v1 * b + v2 * a) / (det * det)
            va = v2 / det + vD * c
            vc = v0 / det + vD * a
            vb = -v1 / det - 2.0 * vD * b
            # V = d loss / d sym(T S T^T) as a symmetric matrix [[va, vb/2], [vb/2, vc]]
            V00, V01, V11 = va, 0.5 * vb, vc
            # d loss / d S = T^T V T
            for i in range(3):
                for j in range(3):
                    v_covars[g, i, j] += (T[0 + i] * (V00 * T[0 + j] + V01 * T[3 + j])
                                          + T[3 + i] * (V01 * T[0 + j] + V11 * T[3 + j]))  # fmt: skip
            # d loss / d T = V T (S + S^T), row-major in scalars (a per-Gaussian array here cost an allocation each)
            vT0, vT1, vT2 = _vt_row(V00, V01, T, S)
            vT3, vT4, vT5 = _vt_row(V01, V11, T, S)
            # T = J R: d loss / d J = vT R^T; only J00, J02, J11, J12 depend on the centre
            vJ00 = vT0 * cr[4] + vT1 * cr[5] + vT2 * cr[6]
            vJ02 = vT0 * cr[10] + vT1 * cr[11] + vT2 * cr[12]
            vJ11 = vT3 * cr[7] + vT4 * cr[8] + vT5 * cr[9]
            vJ12 = vT3 * cr[10] + vT4 * cr[11] + vT5 * cr[12]
            z2, z3 = z * z, z * z * z
            vx, vy = 0.0, 0.0
            vz = v_depths[cam, g] - vJ00 * fx / z2 - vJ11 * fy / z2 + vJ02 * 2.0 * fx * tx / z3 + vJ12 * 2.0 * fy * ty / z3
            vtx, vty = -vJ02 * fx / z2, -vJ12 * fy / z2
            if okx:
                vx += vtx
            else:
                vz += vtx * tx / z
            if oky:
                vy += vty
            else:
                vz += vty * ty / z
            vu, vv = v_means2d[cam, g, 0], v_means2d[cam, g, 1]
            vx += vu * fx / z
            vy += vv * fy / z
            vz -= (vu * fx * x + vv * fy * y) / z2
            for i in range(3):  # pc = R m + t
                v_means[g, i] += cr[4 + i] * vx + cr[7 + i] * vy + cr[10 + i] * vz
