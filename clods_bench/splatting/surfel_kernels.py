"""Numba kernels of the 2DGS surfel renderer's 'cpu' backend (float64; nothing compiles at import).

Why: the plain-torch reference (`surfels.raster_reference`) needs dense (pixel x surfel) autograd graphs;
these kernels composite per pixel with constant memory and a hand-written backward.
Layout: per camera the surfels are depth sorted and binned into 16x16 tiles by their 3-sigma pixel boxes
(`fast_kernels.sort_and_bin`, shared with the 3D renderer; boxes from `surfels.project_surfels`). One tile
per parallel iteration, pixel by pixel: the forward walks the tile's list front to back (rules of the
`surfels` module docstring) and stores the final transmittance, the number of list entries processed and
the median contributor; the backward re-walks that prefix to rebuild each pixel's contributor list
(weights, depths), computes every contributor's d loss / d w_i and d loss / d z_i (distortion sums in
O(n^2) per pixel), sweeps back to front for d loss / d alpha_i (3DGS suffix sums) and chains to the
per-view surfel inputs (M, projected centre, centre depth, normal, colour, opacity). Each tile writes its
own rows of a per-intersection buffer that `reduce_grads` sums, so results do not depend on threads.
Per-pixel output channels: colour (3), alpha, accumulated depth sum w_i z_i, normal (3), distortion,
median depth.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from clods_bench.splatting.fast_kernels import tile_rect

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
MEDIAN_T = 0.5
CUTOFF2 = 9.0  # rho <= 3^2
FILTER_INV_SQUARE = 2.0  # 1 / (sqrt(2)/2)^2
DIST_NEAR, DIST_FAR = 0.2, 100.0
N_OUT = 10
PARALLEL_EPS = 1e-9
N_GRAD = 19  # M row-major (9), projected centre (2), centre depth, normal (3), colour (3), opacity


@njit(cache=True, nogil=True, inline="always")
def _eval(px, py, Mg, mx, my, zc, o, near):
    """(alpha, unclamped, G, use3, u, v, z) of the surfel with transform Mg (9,) at pixel centre (px, py)."""
    k0 = px * Mg[6] - Mg[0]
    k1 = px * Mg[7] - Mg[1]
    k2 = px * Mg[8] - Mg[2]
    l0 = py * Mg[6] - Mg[3]
    l1 = py * Mg[7] - Mg[4]
    l2 = py * Mg[8] - Mg[5]
    p0 = k1 * l2 - k2 * l1
    p1 = k2 * l0 - k0 * l2
    p2 = k0 * l1 - k1 * l0
    rho3d = math.inf
    u = 0.0
    v = 0.0
    zh = 0.0
    nw = math.sqrt(Mg[6] * Mg[6] + Mg[7] * Mg[7] + Mg[8] * Mg[8])
    kn = abs(px) * nw + math.sqrt(Mg[0] * Mg[0] + Mg[1] * Mg[1] + Mg[2] * Mg[2])  # |k| before cancellation
    ln = abs(py) * nw + math.sqrt(Mg[3] * Mg[3] + Mg[4] * Mg[4] + Mg[5] * Mg[5])
    if abs(p2) > PARALLEL_EPS * kn * ln:
        u = p0 / p2
        v = p1 / p2
        zh = u * Mg[6] + v * Mg[7] + Mg[8]
        if zh > near and math.isfinite(u) and math.isfinite(v):
            rho3d = u * u + v * v
    dx = mx - px
    dy = my - py
    rho2d = FILTER_INV_SQUARE * (dx * dx + dy * dy)
    use3 = rho3d <= rho2d
    rho = rho3d if use3 else rho2d
    z = zh if use3 else zc
    if rho > CUTOFF2:
        return 0.0, False, 0.0, use3, u, v, z
    G = math.exp(-0.5 * rho)
    raw = o * G
    alpha = min(ALPHA_MAX, raw)
    if alpha < ALPHA_MIN:
        return 0.0, False, G, use3, u, v, z
    return alpha, raw <= ALPHA_MAX, G, use3, u, v, z


@njit(cache=True, nogil=True, inline="always")
def _mapped(z):
    return DIST_FAR / (DIST_FAR - DIST_NEAR) * (1.0 - DIST_NEAR / z)


@njit(cache=True, nogil=True, inline="always")
def _in_box(boxes, cam, g, i, j):
    return boxes[cam, g, 0] <= i and i <= boxes[cam, g, 2] and boxes[cam, g, 1] <= j and j <= boxes[cam, g, 3]


@njit(cache=True, nogil=True, parallel=True)
def raster_fwd(Ms, means2d, depths, normals, colors, opac, boxes, offsets, ids, width, height, tile, tiles_x, tiles_y,
               near, out, t_final, n_last, med):  # fmt: skip
    """Front-to-back compositing of every pixel; fills out (C,H,W,N_OUT) and the backward's state."""
    per_cam = tiles_x * tiles_y
    for t in prange(offsets.shape[0] - 1):
        cam, x0, y0, x1, y1 = tile_rect(t, per_cam, tiles_x, tile, width, height)
        start, n = offsets[t], offsets[t + 1] - offsets[t]
        ws = np.empty(n)
        ms = np.empty(n)
        for j in range(y0, y1):
            for i in range(x0, x1):
                px, py = i + 0.5, j + 0.5
                T = 1.0
                acc = np.zeros(N_OUT)
                cnt = 0
                last = 0
                mi = -1
                for kk in range(n):
                    g = ids[start + kk]
                    if not _in_box(boxes, cam, g, i, j):
                        continue
                    alpha, _, _, _, _, _, z = _eval(px, py, Ms[cam, g], means2d[cam, g, 0], means2d[cam, g, 1],
                                                    depths[cam, g], opac[cam, g], near)  # fmt: skip
                    if alpha == 0.0:
                        continue
                    nt = T * (1.0 - alpha)
                    if nt < T_MIN:
                        break
                    w = alpha * T
                    for ch in range(3):
                        acc[ch] += w * colors[cam, g, ch]
                        acc[5 + ch] += w * normals[cam, g, ch]
                    acc[4] += w * z
                    m = _mapped(z)
                    d = 0.0
                    for q in range(cnt):
                        d += ws[q] * abs(m - ms[q])
                    acc[8] += 2.0 * w * d
                    ws[cnt] = w
                    ms[cnt] = m
                    cnt += 1
                    if mi < 0 and nt < MEDIAN_T:
                        mi = kk
                        acc[9] = z
                    T = nt
                    last = kk + 1
                acc[3] = 1.0 - T
                for q in range(N_OUT):
                    out[cam, j, i, q] = acc[q]
                t_final[cam, j, i] = T
                n_last[cam, j, i] = last
                med[cam, j, i] = mi


@njit(cache=True, nogil=True, parallel=True)
def raster_bwd(Ms, means2d, depths, normals, colors, opac, boxes, offsets, ids, width, height, tile, tiles_x, tiles_y,
               near, t_final, n_last, med, v_out, g_isect):  # fmt: skip
    """Gradients of sum(v_out * out); row k of g_isect (n_isect, N_GRAD) gets intersection k's gradient."""
    per_cam = tiles_x * tiles_y
    for t in prange(offsets.shape[0] - 1):
        cam, x0, y0, x1, y1 = tile_rect(t, per_cam, tiles_x, tile, width, height)
        start, n = offsets[t], offsets[t + 1] - offsets[t]
        gt = np.zeros((n, N_GRAD))
        lk = np.empty(n, dtype=np.int64)
        la = np.empty(n)
        lT = np.empty(n)
        lw = np.empty(n)
        lz = np.empty(n)
        lm = np.empty(n)
        for j in range(y0, y1):
            for i in range(x0, x1):
                nl = n_last[cam, j, i]
                if nl == 0:
                    continue
                px, py = i + 0.5, j + 0.5
                v = v_out[cam, j, i]
                T = 1.0
                cnt = 0
                for kk in range(nl):
                    g = ids[start + kk]
                    if not _in_box(boxes, cam, g, i, j):
                        continue
                    alpha, _, _, _, _, _, z = _eval(px, py, Ms[cam, g], means2d[cam, g, 0], means2d[cam, g, 1],
                                                    depths[cam, g], opac[cam, g], near)  # fmt: skip
                    if alpha == 0.0:
                        continue
                    lk[cnt] = kk
                    la[cnt] = alpha
                    lT[cnt] = T
                    lw[cnt] = alpha * T
                    lz[cnt] = z
                    lm[cnt] = _mapped(z)
                    cnt += 1
                    T *= 1.0 - alpha
                Tf = t_final[cam, j, i]
                mi = med[cam, j, i]
                S = 0.0  # sum over later contributors of a_i w_i
                for q in range(cnt - 1, -1, -1):
                    kk = lk[q]
                    g = ids[start + kk]
                    w, alpha, z, m = lw[q], la[q], lz[q], lm[q]
                    s_abs = 0.0
                    s_sgn = 0.0
                    for r in range(cnt):
                        dm = m - lm[r]
                        s_abs += lw[r] * abs(dm)
                        if dm > 0.0:
                            s_sgn += lw[r]
                        elif dm < 0.0:
                            s_sgn -= lw[r]
                    a = v[4] * z + v[8] * 2.0 * s_abs
                    for ch in range(3):
                        a += v[ch] * colors[cam, g, ch] + v[5 + ch] * normals[cam, g, ch]
                    gz = w * v[4] + v[8] * 2.0 * w * s_sgn * DIST_FAR * DIST_NEAR / ((DIST_FAR - DIST_NEAR) * z * z)
                    if kk == mi:
                        gz += v[9]
                    inv = 1.0 / (1.0 - alpha)
                    ga = a * lT[q] - S * inv + v[3] * Tf * inv
                    S += a * w
                    row = gt[kk]
                    for ch in range(3):
                        row[12 + ch] += w * v[5 + ch]
                        row[15 + ch] += w * v[ch]
                    Mg = Ms[cam, g]
                    mx, my, o = means2d[cam, g, 0], means2d[cam, g, 1], opac[cam, g]
                    _, unclamped, G, use3, u, vv, _ = _eval(px, py, Mg, mx, my, depths[cam, g], o, near)
                    g_rho = 0.0
                    if unclamped:
                        row[18] += G * ga
                        g_rho = -0.5 * o * G * ga
                    if use3:
                        gu = 2.0 * u * g_rho + Mg[6] * gz
                        gv = 2.0 * vv * g_rho + Mg[7] * gz
                        row[6] += u * gz
                        row[7] += vv * gz
                        row[8] += gz
                        k0, k1, k2 = px * Mg[6] - Mg[0], px * Mg[7] - Mg[1], px * Mg[8] - Mg[2]
                        l0, l1, l2 = py * Mg[6] - Mg[3], py * Mg[7] - Mg[4], py * Mg[8] - Mg[5]
                        p2 = k0 * l1 - k1 * l0
                        q0, q1 = gu / p2, gv / p2
                        q2 = -(gu * u + gv * vv) / p2
                        gk0, gk1, gk2 = l1 * q2 - l2 * q1, l2 * q0 - l0 * q2, l0 * q1 - l1 * q0  # l x gp
                        gl0, gl1, gl2 = q1 * k2 - q2 * k1, q2 * k0 - q0 * k2, q0 * k1 - q1 * k0  # gp x k
                        row[0] -= gk0
                        row[1] -= gk1
                        row[2] -= gk2
                        row[3] -= gl0
                        row[4] -= gl1
                        row[5] -= gl2
                        row[6] += px * gk0 + py * gl0
                        row[7] += px * gk1 + py * gl1
                        row[8] += px * gk2 + py * gl2
                    else:
                        row[9] += 2.0 * FILTER_INV_SQUARE * (mx - px) * g_rho
                        row[10] += 2.0 * FILTER_INV_SQUARE * (my - py) * g_rho
                        row[11] += gz
        for kk in range(n):
            for q in range(N_GRAD):
                g_isect[start + kk, q] = gt[kk, q]


@njit(cache=True, nogil=True, parallel=True)
def reduce_grads(offsets, ids, g_isect, per_cam, out):
    """Sum per-intersection gradient rows into out (C,G,N_GRAD); one camera per parallel iteration."""
    for cam in prange(out.shape[0]):
        for t in range(cam * per_cam, (cam + 1) * per_cam):
            for k in range(offsets[t], offsets[t + 1]):
                g = ids[k]
                for q in range(N_GRAD):
                    out[cam, g, q] += g_isect[k, q]
