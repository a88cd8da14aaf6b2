"""Numba kernels of the fast CPU splatting backend (float64 throughout; nothing compiles at import).

Layout: per camera, Gaussians are visited in ascending depth and appended to every tile their
bounding box touches (`bin_gaussians`), so each tile's list is already depth sorted. Forward and
backward run one tile per parallel iteration; inside a tile each Gaussian only visits the pixels of
its own bounding box (it is invisible elsewhere by construction of the opacity-aware radii), with
per-pixel state for the front-to-back order. The compositing rules are exactly those of
`reference.py` (3DGS / gsplat). The forward keeps each visit's pixel and exponential (`visit_bounds`
sizes the buffer); the backward pass walks each tile back to front from the stored final transmittance
and last-contributor count (3DGS algorithm), over those visits instead of the row ranges, and writes
each Gaussian's per-tile gradient into its own row of a per-intersection buffer, which `reduce_grads`
sums per Gaussian: no two threads ever write the same memory, and results do not depend on the thread
count.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
BOX_MARGIN = 1e-3  # px; guards the per-Gaussian pixel box against rounding at its exact edge
SIGMA_SLACK = 1e-6  # row ranges reach sigma = log(255 o) + this, so rounding never drops a visible pixel
N_GRAD = 10  # per-intersection gradient row: mean2d (2), conic (3), colour (3), opacity, depth


EXP_STEPS = 256  # exp(-s) = EXP_HI[k >> 4] * EXP_LO[k & 15] * poly(s - k / 256) with k = floor(256 s)
EXP_HI = np.exp(-np.arange(16 * 48) / 16.0)  # exp(-j / 16) for s < 48 (exp(-48) ~ 1e-21: beyond, libm)
EXP_LO = np.exp(-np.arange(16) / 256.0)


@njit(cache=True, nogil=True, inline="always")
def exp_neg(s):
    """exp(-s) for s >= 0 within about 2 ulp of math.exp, inlined: two table factors and a degree-5 polynomial
    on [0, 1/256) (truncation (1/256)^6 / 720 ~ 5e-18), so the compiler can interleave it with the pixel loop."""
    k = int(s * EXP_STEPS)
    if k >= EXP_HI.shape[0] * 16:
        return math.exp(-s)
    r = s - k * (1.0 / EXP_STEPS)
    r2 = r * r
    p = (1.0 - r) + r2 * (0.5 - r * (1.0 / 6.0)) + r2 * r2 * ((1.0 / 24.0) - r * (1.0 / 120.0))
    return EXP_HI[k >> 4] * EXP_LO[k & 15] * p


RADIX_BITS = 11  # 2048 buckets: six passes cover a 64-bit key


@njit(cache=True, nogil=True)
def stable_argsort_positive(key):
    """argsort(key, kind="stable") of finite positive float64 keys by an LSD radix sort of their bit patterns.

    For positive IEEE doubles the unsigned bit pattern orders like the value, and LSD radix sort is stable, so
    ties keep index order exactly as a stable comparison sort; passes whose digit is the same for every key
    (the sign and most exponent bits of depths) are skipped. About 3x numba's mergesort at 15k keys.
    """
    n = key.shape[0]
    bits = key.view(np.uint64)
    perm = np.arange(n)
    tmp = np.empty(n, dtype=np.int64)
    counts = np.empty((1 << RADIX_BITS) + 1, dtype=np.int64)
    mask = np.uint64((1 << RADIX_BITS) - 1)
    for shift in range(0, 64, RADIX_BITS):
        sh = np.uint64(shift)
        counts[:] = 0
        for k in range(n):
            counts[((bits[k] >> sh) & mask) + 1] += 1
        if n == 0 or counts[((bits[0] >> sh) & mask) + 1] == n:
            continue  # one digit value for all keys: this pass would not move anything
        for d in range(1 << RADIX_BITS):
            counts[d + 1] += counts[d]
        for k in range(n):
            src = perm[k]
            d = (bits[src] >> sh) & mask
            tmp[counts[d]] = src
            counts[d] += 1
        perm, tmp = tmp, perm
    return perm


@njit(cache=True, nogil=True, parallel=True)
def sort_and_bin(depths, bounds, tiles_x, tiles_y):
    """Tile lists: offsets (C*ty*tx+1,) into ids (n_isect,) of Gaussians, each list in ascending depth.

    Per camera (in parallel) the Gaussians with a non-empty tile rectangle are sorted stably by depth (ties
    by index, as torch.argsort(stable=True)), counted per tile, and after a prefix sum appended to their tiles.
    """
    C, G = depths.shape
    per_cam = tiles_x * tiles_y
    order = np.empty((C, G), dtype=np.int64)
    n_vis = np.zeros(C, dtype=np.int64)
    counts = np.zeros(C * per_cam + 1, dtype=np.int64)
    for c in prange(C):
        n = 0
        for g in range(G):
            if bounds[c, g, 2] > bounds[c, g, 0] and bounds[c, g, 3] > bounds[c, g, 1]:
                order[c, n] = g
                n += 1
        key = np.empty(n)
        for k in range(n):
            key[k] = depths[c, order[c, k]]
        perm = stable_argsort_positive(key)
        idx = order[c, :n].copy()
        for k in range(n):
            g = idx[perm[k]]
            order[c, k] = g
            for ty in range(bounds[c, g, 1], bounds[c, g, 3]):
                for tx in range(bounds[c, g, 0], bounds[c, g, 2]):
                    counts[c * per_cam + ty * tiles_x + tx + 1] += 1
        n_vis[c] = n
    offsets = np.cumsum(counts)
    ids = np.empty(offsets[-1], dtype=np.int32)
    for c in prange(C):
        fill = offsets[c * per_cam : (c + 1) * per_cam].copy()
        for k in range(n_vis[c]):
            g = order[c, k]
            for ty in range(bounds[c, g, 1], bounds[c, g, 3]):
                for tx in range(bounds[c, g, 0], bounds[c, g, 2]):
                    t = ty * tiles_x + tx
                    ids[fill[t]] = g
                    fill[t] += 1
    return offsets, ids


@njit(cache=True, nogil=True, inline="always")
def _pixel_box(mean, r, lo, hi):
    """Inclusive pixel index range [i0, i1] within [lo, hi) whose centres lie within r of mean."""
    a = max(float(lo), math.ceil(mean - r - BOX_MARGIN - 0.5))
    b = min(float(hi - 1), math.floor(mean + r + BOX_MARGIN - 0.5))
    return int(a), int(b)


@njit(cache=True, nogil=True, inline="always")
def _ellipse(a, b, c, thr):
    """Per-Gaussian constants of `_row_range`: (2 a (thr + slack), a c - b^2, 1 / a, b / a), computed once, not per row."""
    inv_a = 1.0 / a
    return 2.0 * a * (thr + SIGMA_SLACK), a * c - b * b, inv_a, b * inv_a


@njit(cache=True, nogil=True, inline="always")
def _row_range(mx, my, ell, j, i0, i1):
    """Pixels [lo, hi] of row j within [i0, i1] whose centres may have sigma <= thr: the ellipse's chord, widened.

    Solves 0.5 a dx^2 + b dy dx + 0.5 c dy^2 = thr + SIGMA_SLACK for dx (a > 0 for a positive definite conic),
    with `ell` = `_ellipse(a, b, c, thr)`; pixels outside have alpha < 1/255 and are skipped by the exact test
    anyway, so this only saves work (rounding here moves a chord end by ~1e-12 px, far inside BOX_MARGIN).
    """
    dy = j + 0.5 - my
    disc = ell[0] - dy * dy * ell[1]
    if disc < 0.0:
        return i0, i0 - 1
    half = math.sqrt(disc) * ell[2]
    mid = mx - dy * ell[3] - 0.5
    lo = math.ceil(mid - half - BOX_MARGIN)
    hi = math.floor(mid + half + BOX_MARGIN)
    return max(i0, int(lo)), min(i1, int(hi))


@njit(cache=True, nogil=True, inline="always")
def _alpha(px, py, mx, my, a, b, c, o):
    """(alpha, vis = exp(-sigma), dx, dy, unclamped) at pixel centre (px, py); alpha 0 means skipped.

    vis is returned so that the forward can keep it for the backward (`raster_fwd`'s `vis_buf`).
    """
    dx = px - mx
    dy = py - my
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    if sigma < 0.0:
        return 0.0, 0.0, dx, dy, False
    vis = exp_neg(sigma)
    raw = o * vis
    alpha = min(ALPHA_MAX, raw)
    if alpha < ALPHA_MIN:
        return 0.0, vis, dx, dy, False
    return alpha, vis, dx, dy, raw <= ALPHA_MAX


@njit(cache=True, nogil=True, inline="always")
def tile_rect(t, per_cam, tiles_x, tile, width, height):
    """Camera and pixel rectangle [x0, x1) x [y0, y1) of tile t of the binning (tiles numbered camera by camera, row-major)."""
    cam, rem = t // per_cam, t % per_cam
    x0, y0 = (rem % tiles_x) * tile, (rem // tiles_x) * tile
    return cam, x0, y0, min(x0 + tile, width), min(y0 + tile, height)


@njit(cache=True, nogil=True, parallel=True)
def raster_fwd(means2d, conics, colors, opac, depths, radii, thresh, offsets, ids, width, height, tile, tiles_x, tiles_y,
               out_rgb, out_alpha, out_depth, t_final, n_last, vis_buf, vis_ij, vis_span, tile_buf):  # fmt: skip
    """Front-to-back compositing of every tile; fills the outputs and the state the backward needs.

    With a non-empty `vis_buf` it also keeps, for the backward, every visit to a pixel not yet saturated: its
    exp(-sigma) in `vis_buf` and its pixel in the tile (column, row) in `vis_ij`, in visit order from `tile_buf[t]`
    on, intersection k's visits being `vis_span[k, 0]` to `vis_span[k, 1]`. The backward then walks those visits
    instead of the row ranges and reads the exponentials instead of recomputing them (the same numbers, so the
    same gradients).
    """
    per_cam = tiles_x * tiles_y
    keep = vis_buf.shape[0] > 0
    for t in prange(offsets.shape[0] - 1):
        cam, x0, y0, x1, y1 = tile_rect(t, per_cam, tiles_x, tile, width, height)
        tw = x1 - x0
        npx = tw * (y1 - y0)
        T = np.ones(npx)
        acc = np.zeros((npx, 4))
        last = np.zeros(npx, dtype=np.int32)
        done = np.zeros(npx, dtype=np.bool_)
        n_done = 0
        start = offsets[t]
        cur = tile_buf[t]
        for k in range(start, offsets[t + 1]):
            if n_done == npx:
                break
            if keep:
                vis_span[k, 0] = cur
            g = ids[k]
            mx, my = means2d[cam, g, 0], means2d[cam, g, 1]
            a, b, c, o = conics[cam, g, 0], conics[cam, g, 1], conics[cam, g, 2], opac[cam, g]
            cr, cg, cb, z = colors[cam, g, 0], colors[cam, g, 1], colors[cam, g, 2], depths[cam, g]
            i0, i1 = _pixel_box(mx, radii[cam, g, 0], x0, x1)
            j0, j1 = _pixel_box(my, radii[cam, g, 1], y0, y1)
            ell = _ellipse(a, b, c, thresh[cam, g])
            for j in range(j0, j1 + 1):
                r0, r1 = _row_range(mx, my, ell, j, i0, i1)
                for i in range(r0, r1 + 1):
                    p = (j - y0) * tw + (i - x0)
                    if done[p]:
                        continue
                    alpha, vis, _, _, _ = _alpha(i + 0.5, j + 0.5, mx, my, a, b, c, o)
                    if keep:
                        vis_buf[cur] = vis
                        vis_ij[cur, 0] = i - x0
                        vis_ij[cur, 1] = j - y0
                        cur += 1
                    if alpha == 0.0:
                        continue
                    nt = T[p] * (1.0 - alpha)
                    if nt < T_MIN:
                        done[p] = True
                        n_done += 1
                        continue
                    w = alpha * T[p]
                    acc[p, 0] += w * cr
                    acc[p, 1] += w * cg
                    acc[p, 2] += w * cb
                    acc[p, 3] += w * z
                    T[p] = nt
                    last[p] = k - start + 1
            if keep:
                vis_span[k, 1] = cur
        for p in range(npx):
            j, i = y0 + p // tw, x0 + p % tw
            out_rgb[cam, j, i, 0] = acc[p, 0]
            out_rgb[cam, j, i, 1] = acc[p, 1]
            out_rgb[cam, j, i, 2] = acc[p, 2]
            out_alpha[cam, j, i] = 1.0 - T[p]
            out_depth[cam, j, i] = acc[p, 3]
            t_final[cam, j, i] = T[p]
            n_last[cam, j, i] = last[p]


@njit(cache=True, nogil=True, inline="always")
def _visit_grad(p, alpha, vis, dx, dy, unclamped, T, T_end, vc, suffix, cr, cg, cb, z, a, b, c, o):
    """One visit of the backward: steps pixel p's transmittance and colour suffix back over this Gaussian and
    returns the visit's share of its gradient row (mean2d, conic, colour, opacity, depth)."""
    inv = 1.0 / (1.0 - alpha)
    Ti = T[p] * inv  # transmittance in front of this Gaussian
    T[p] = Ti
    w = alpha * Ti
    v0, v1, v2, v3, v4 = vc[p, 0], vc[p, 1], vc[p, 2], vc[p, 3], vc[p, 4]
    s0, s1, s2, s3 = suffix[p, 0], suffix[p, 1], suffix[p, 2], suffix[p, 3]
    v_a = (v0 * (cr * Ti - s0 * inv) + v1 * (cg * Ti - s1 * inv)
           + v2 * (cb * Ti - s2 * inv) + v4 * (z * Ti - s3 * inv)
           + v3 * T_end[p] * inv)  # fmt: skip
    suffix[p, 0] = s0 + cr * w
    suffix[p, 1] = s1 + cg * w
    suffix[p, 2] = s2 + cb * w
    suffix[p, 3] = s3 + z * w
    if not unclamped:
        return 0.0, 0.0, 0.0, 0.0, 0.0, w * v0, w * v1, w * v2, 0.0, w * v4
    v_s = -o * vis * v_a  # d loss / d sigma
    return (-(v_s * (a * dx + b * dy)), -(v_s * (b * dx + c * dy)), v_s * 0.5 * dx * dx, v_s * dx * dy,
            v_s * 0.5 * dy * dy, w * v0, w * v1, w * v2, vis * v_a, w * v4)  # fmt: skip


@njit(cache=True, nogil=True, parallel=True)
def raster_bwd(means2d, conics, colors, opac, depths, radii, thresh, offsets, ids, width, height, tile, tiles_x, tiles_y,
               t_final, n_last, vis_buf, vis_ij, vis_span, v_rgb, v_alpha, v_depth, g_isect):  # fmt: skip
    """Back-to-front gradient pass; row k of g_isect (n_isect, N_GRAD) gets intersection k's gradient.

    With the forward's kept visits (`vis_buf` non-empty) each Gaussian walks its own visits and reads their
    exponentials (on the `bench render` scene about a third of this pass's time saved); without them (the forward
    kept nothing: too many visits for the memory budget) it walks its row ranges and recomputes them.
    """
    per_cam = tiles_x * tiles_y
    kept = vis_buf.shape[0] > 0
    for t in prange(offsets.shape[0] - 1):
        cam, x0, y0, x1, y1 = tile_rect(t, per_cam, tiles_x, tile, width, height)
        tw = x1 - x0
        npx = tw * (y1 - y0)
        T = np.empty(npx)
        T_end = np.empty(npx)
        last = np.empty(npx, dtype=np.int32)
        vc = np.empty((npx, 5))  # d loss / d (r, g, b, alpha, depth) of each pixel
        suffix = np.zeros((npx, 4))  # sum over later Gaussians of (colour, depth) * w
        kmax = 0
        for p in range(npx):
            j, i = y0 + p // tw, x0 + p % tw
            T[p] = t_final[cam, j, i]
            T_end[p] = T[p]
            last[p] = n_last[cam, j, i]
            kmax = max(kmax, last[p])
            for ch in range(3):
                vc[p, ch] = v_rgb[cam, j, i, ch]
            vc[p, 3] = v_alpha[cam, j, i]
            vc[p, 4] = v_depth[cam, j, i]
        start = offsets[t]
        for kk in range(kmax - 1, -1, -1):
            k = start + kk
            g = ids[k]
            mx, my = means2d[cam, g, 0], means2d[cam, g, 1]
            a, b, c, o = conics[cam, g, 0], conics[cam, g, 1], conics[cam, g, 2], opac[cam, g]
            cr, cg, cb, z = colors[cam, g, 0], colors[cam, g, 1], colors[cam, g, 2], depths[cam, g]
            # the gradient row in scalars (registers), not an array: the same sums in the same order
            g0 = g1 = g2 = g3 = g4 = g5 = g6 = g7 = g8 = g9 = 0.0
            if kept:
                for e in range(vis_span[k, 0], vis_span[k, 1]):
                    li, lj = vis_ij[e, 0], vis_ij[e, 1]
                    p = lj * tw + li
                    if kk >= last[p]:
                        continue
                    vis = vis_buf[e]  # the forward's exp(-sigma) here (`_alpha`'s rules, without the exponential)
                    raw = o * vis
                    alpha = min(ALPHA_MAX, raw)
                    if alpha < ALPHA_MIN:
                        continue
                    d = _visit_grad(p, alpha, vis, x0 + li + 0.5 - mx, y0 + lj + 0.5 - my, raw <= ALPHA_MAX,
                                    T, T_end, vc, suffix, cr, cg, cb, z, a, b, c, o)  # fmt: skip
                    g0, g1, g2, g3, g4 = g0 + d[0], g1 + d[1], g2 + d[2], g3 + d[3], g4 + d[4]
                    g5, g6, g7, g8, g9 = g5 + d[5], g6 + d[6], g7 + d[7], g8 + d[8], g9 + d[9]
            else:
                i0, i1 = _pixel_box(mx, radii[cam, g, 0], x0, x1)
                j0, j1 = _pixel_box(my, radii[cam, g, 1], y0, y1)
                ell = _ellipse(a, b, c, thresh[cam, g])
                for j in range(j0, j1 + 1):
                    r0, r1 = _row_range(mx, my, ell, j, i0, i1)
                    for i in range(r0, r1 + 1):
                        p = (j - y0) * tw + (i - x0)
                        if kk >= last[p]:
                            continue
                        alpha, vis, dx, dy, unclamped = _alpha(i + 0.5, j + 0.5, mx, my, a, b, c, o)
                        if alpha == 0.0:
                            continue
                        d = _visit_grad(p, alpha, vis, dx, dy, unclamped, T, T_end, vc, suffix, cr, cg, cb, z, a, b, c, o)
                        g0, g1, g2, g3, g4 = g0 + d[0], g1 + d[1], g2 + d[2], g3 + d[3], g4 + d[4]
                        g5, g6, g7, g8, g9 = g5 + d[5], g6 + d[6], g7 + d[7], g8 + d[8], g9 + d[9]
            g_isect[k, 0], g_isect[k, 1], g_isect[k, 2], g_isect[k, 3], g_isect[k, 4] = g0, g1, g2, g3, g4
            g_isect[k, 5], g_isect[k, 6], g_isect[k, 7], g_isect[k, 8], g_isect[k, 9] = g5, g6, g7, g8, g9
        for k in range(start + kmax, offsets[t + 1]):  # behind every pixel's last contributor: no gradient
            for q in range(N_GRAD):
                g_isect[k, q] = 0.0


@njit(cache=True, nogil=True, parallel=True)
def visit_bounds(means2d, radii, offsets, ids, width, height, tile, tiles_x, tiles_y):
    """(n_tiles+1,) start of each tile's share of the kept-exponential buffer: the prefix sum over tiles of their
    Gaussians' pixel boxes clipped to the tile, a bound on the visits `raster_fwd` makes there."""
    per_cam = tiles_x * tiles_y
    n_tiles = offsets.shape[0] - 1
    sizes = np.zeros(n_tiles + 1, dtype=np.int64)
    for t in prange(n_tiles):
        cam, x0, y0, x1, y1 = tile_rect(t, per_cam, tiles_x, tile, width, height)
        n = 0
        for k in range(offsets[t], offsets[t + 1]):
            g = ids[k]
            i0, i1 = _pixel_box(means2d[cam, g, 0], radii[cam, g, 0], x0, x1)
            j0, j1 = _pixel_box(means2d[cam, g, 1], radii[cam, g, 1], y0, y1)
            n += max(0, i1 - i0 + 1) * max(0, j1 - j0 + 1)
        sizes[t + 1] = n
    return np.cumsum(sizes)


@njit(cache=True, nogil=True, parallel=True)
def reduce_grads(offsets, ids, g_isect, per_cam, out):
    """Sum per-intersection gradient rows into out (C,G,N_GRAD), which it zeroes first (so it may come from
    np.empty: each thread then touches its own camera's pages); one camera per parallel iteration."""
    for cam in prange(out.shape[0]):
        out[cam] = 0.0
        for t in range(cam * per_cam, (cam + 1) * per_cam):
            for k in range(offsets[t], offsets[t + 1]):
                g = ids[k]
                for q in range(N_GRAD):
                    out[cam, g, q] += g_isect[k, q]
