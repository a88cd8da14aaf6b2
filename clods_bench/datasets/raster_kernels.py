"""Numba kernels of the ground-truth mesh rasterizer (no Gaussian-splatting code shared).

Pipeline per view, on an s*W x s*H sample grid (sample (R, C) centre at (C+0.5, R+0.5)):
1. near-plane clipping of each triangle in camera space (z >= near kept, Sutherland-Hodgman);
2. rasterisation of the (up to two) fan triangles with float64 edge functions. Every edge is
   evaluated with its endpoints in a canonical (lexicographic) order and then negated, so the
   two triangles sharing an edge get bit-identical values of opposite sign; together with the
   top-left rule (a sample exactly on an edge belongs to the triangle whose inward edge normal
   points to +x, or to +y for horizontal edges) every sample is claimed by exactly one of them;
3. z-buffer on camera z with perspective-correct barycentrics w.r.t. the *original* triangle
   (clipped vertices carry their 3D barycentric weights), so shading is deferred to visible samples;
4. shading: bilinear, wrapping texture lookup, optional two-sided Lambertian with smooth normals and
   cast shadows (a point farther from the light than the frame's shadow map gets only the ambient term);
5. s x s box filter down to W x H.
Nothing here compiles at import: kernels are lazily compiled on first call and cached on disk.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from clods_bench.datasets import shadow_kernels as sk


@njit(cache=True, nogil=True)
def vertex_normals(verts: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(V,3) unit area-weighted vertex normals (zero where a vertex has no area around it)."""
    n = np.zeros(verts.shape, dtype=np.float64)
    for f in range(cells.shape[0]):
        a, b, c = cells[f, 0], cells[f, 1], cells[f, 2]
        e1 = verts[b] - verts[a]
        e2 = verts[c] - verts[a]
        fn = np.cross(e1, e2)
        for k in range(3):
            n[a, k] += fn[k]
            n[b, k] += fn[k]
            n[c, k] += fn[k]
    for i in range(n.shape[0]):
        norm = math.sqrt(n[i, 0] ** 2 + n[i, 1] ** 2 + n[i, 2] ** 2)
        if norm > 0.0:
            n[i] /= norm
    return n


@njit(cache=True, nogil=True)
def to_camera(verts: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(V,3) world points to camera coordinates R @ x + t."""
    cam = np.empty(verts.shape, dtype=np.float64)
    for i in range(verts.shape[0]):
        for k in range(3):
            cam[i, k] = R[k, 0] * verts[i, 0] + R[k, 1] * verts[i, 1] + R[k, 2] * verts[i, 2] + t[k]
    return cam


@njit(cache=True, nogil=True, inline="always")
def _edge(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@njit(cache=True, nogil=True)
def _raster_triangle(px, py, pz, pb, hs, ws, zbuf, fid, bary, face):
    """Z-buffer one screen triangle (3 points px/py, camera depths pz, (3,3) original barycentrics pb)."""
    area = _edge(px[0], py[0], px[1], py[1], px[2], py[2])
    if not (area != 0.0 and math.isfinite(area)):
        return  # degenerate (zero area) or overflowing: draws nothing
    orient = 1.0 if area > 0.0 else -1.0
    # per edge i (opposite vertex i): canonical endpoints, sign and the tie-break flag
    ex0 = np.empty(3)
    ey0 = np.empty(3)
    ex1 = np.empty(3)
    ey1 = np.empty(3)
    sg = np.empty(3)
    tie = np.zeros(3, dtype=np.bool_)
    for i in range(3):
        a = (i + 1) % 3
        b = (i + 2) % 3
        if not (px[a] < px[b] or (px[a] == px[b] and py[a] <= py[b])):
            a, b = b, a
            s = -orient
        else:
            s = orient
        ex0[i], ey0[i], ex1[i], ey1[i], sg[i] = px[a], py[a], px[b], py[b], s
        gx = -s * (ey1[i] - ey0[i])  # inward normal of the edge (gradient of the oriented edge function)
        gy = s * (ex1[i] - ex0[i])
        tie[i] = gx > 0.0 or (gx == 0.0 and gy > 0.0)
    lo_x = max(min(px[0], px[1], px[2]), -1.0)
    hi_x = min(max(px[0], px[1], px[2]), ws + 1.0)
    lo_y = max(min(py[0], py[1], py[2]), -1.0)
    hi_y = min(max(py[0], py[1], py[2]), hs + 1.0)
    c0 = max(int(math.ceil(lo_x - 0.5)), 0)
    c1 = min(int(math.floor(hi_x - 0.5)), ws - 1)
    r0 = max(int(math.ceil(lo_y - 0.5)), 0)
    r1 = min(int(math.floor(hi_y - 0.5)), hs - 1)
    inv_area = 1.0 / (area * orient)
    iz0, iz1, iz2 = 1.0 / pz[0], 1.0 / pz[1], 1.0 / pz[2]
    for r in range(r0, r1 + 1):
        sy = r + 0.5
        for c in range(c0, c1 + 1):
            sx = c + 0.5
            w0 = sg[0] * _edge(ex0[0], ey0[0], ex1[0], ey1[0], sx, sy)
            if w0 < 0.0 or (w0 == 0.0 and not tie[0]):
                continue
            w1 = sg[1] * _edge(ex0[1], ey0[1], ex1[1], ey1[1], sx, sy)
            if w1 < 0.0 or (w1 == 0.0 and not tie[1]):
                continue
            w2 = sg[2] * _edge(ex0[2], ey0[2], ex1[2], ey1[2], sx, sy)
            if w2 < 0.0 or (w2 == 0.0 and not tie[2]):
                continue
            q0 = w0 * inv_area * iz0  # screen barycentric / z: linear in screen space
            q1 = w1 * inv_area * iz1
            q2 = w2 * inv_area * iz2
            qs = q0 + q1 + q2
            if not qs > 0.0:
                continue
            z = 1.0 / qs
            k = r * ws + c
            if z < zbuf[k]:
                zbuf[k] = z
                fid[k] = face
                for j in range(3):
                    bary[k, j] = (q0 * pb[0, j] + q1 * pb[1, j] + q2 * pb[2, j]) * z


@njit(cache=True, nogil=True)
def raster_view(cam, cells, fx, fy, cx, cy, near, hs, ws, zbuf, fid, bary):
    """Fill zbuf/fid/bary (hs*ws samples) for camera-space vertices `cam` (V,3); clips at z = near."""
    zbuf[:] = np.inf
    fid[:] = -1
    px = np.empty(3)
    py = np.empty(3)
    pz = np.empty(3)
    pb = np.zeros((3, 3))
    # clipped polygon: at most 4 vertices with camera xyz and barycentric weights
    qx = np.empty(4)
    qy = np.empty(4)
    qz = np.empty(4)
    qb = np.zeros((4, 3))
    for f in range(cells.shape[0]):
        idx = cells[f]
        n = 0
        for e in range(3):
            ia, ib = idx[e], idx[(e + 1) % 3]
            ina = cam[ia, 2] >= near
            if ina:
                qx[n], qy[n], qz[n] = cam[ia, 0], cam[ia, 1], cam[ia, 2]
                qb[n, :] = 0.0
                qb[n, e] = 1.0
                n += 1
            if ina != (cam[ib, 2] >= near):
                # intersect in canonical order (lower vertex index first) so neighbours agree bitwise
                if ia < ib:
                    lo, hi, elo, ehi = ia, ib, e, (e + 1) % 3
                else:
                    lo, hi, elo, ehi = ib, ia, (e + 1) % 3, e
                t = (near - cam[lo, 2]) / (cam[hi, 2] - cam[lo, 2])
                qx[n] = cam[lo, 0] + t * (cam[hi, 0] - cam[lo, 0])
                qy[n] = cam[lo, 1] + t * (cam[hi, 1] - cam[lo, 1])
                qz[n] = near
                qb[n, :] = 0.0
                qb[n, elo] += 1.0 - t
                qb[n, ehi] += t
                n += 1
        if n < 3:
            continue
        for tri in range(n - 2):  # fan (0, 1, 2), (0, 2, 3)
            for j in range(3):
                m = 0 if j == 0 else tri + j
                px[j] = fx * qx[m] / qz[m] + cx
                py[j] = fy * qy[m] / qz[m] + cy
                pz[j] = qz[m]
                pb[j, :] = qb[m, :]
            _raster_triangle(px, py, pz, pb, hs, ws, zbuf, fid, bary, f)


@njit(cache=True, nogil=True)
def sample_bilinear(tex, u, v, out):
    """Bilinear texture lookup with wrap-around; texel (i, j) centre at uv ((j+0.5)/Wt, (i+0.5)/Ht)."""
    h, w = tex.shape[0], tex.shape[1]
    x = u * w - 0.5
    y = v * h - 0.5
    x0 = math.floor(x)
    y0 = math.floor(y)
    ax = x - x0
    ay = y - y0
    j0 = int(x0) % w
    i0 = int(y0) % h
    j1 = (j0 + 1) % w
    i1 = (i0 + 1) % h
    for k in range(3):
        top = (1.0 - ax) * tex[i0, j0, k] + ax * tex[i0, j1, k]
        bot = (1.0 - ax) * tex[i1, j0, k] + ax * tex[i1, j1, k]
        out[k] = (1.0 - ay) * top + ay * bot


@njit(cache=True, nogil=True)
def shade_view(fid, bary, verts, cells, uv, tex, flat, face_col, normals, use_light, light_dir, ambient, diffuse, shadow, bg, s, out):
    """Shade visible samples and box-filter s x s blocks into out (H,W,3); `shadow` = (size, basis, map, u0, v0, texel), size 0: none.

    Faces with `flat[f]` take the flat colour face_col[f] instead of the texture (obstacles)."""
    ssize, basis, smap, u0, v0, texel = shadow
    h, w = out.shape[0], out.shape[1]
    ws = w * s
    col = np.empty(3)
    acc = np.empty(3)
    inv = 1.0 / (s * s)
    for r in range(h):
        for c in range(w):
            acc[:] = 0.0
            for dr in range(s):
                for dc in range(s):
                    k = (r * s + dr) * ws + (c * s + dc)
                    f = fid[k]
                    if f < 0:
                        for j in range(3):
                            acc[j] += bg[j]
                        continue
                    a, b, cc = cells[f, 0], cells[f, 1], cells[f, 2]
                    b0, b1, b2 = bary[k, 0], bary[k, 1], bary[k, 2]
                    if flat[f]:
                        for j in range(3):
                            col[j] = face_col[f, j]
                    else:
                        u = b0 * uv[a, 0] + b1 * uv[b, 0] + b2 * uv[cc, 0]
                        v = b0 * uv[a, 1] + b1 * uv[b, 1] + b2 * uv[cc, 1]
                        sample_bilinear(tex, u, v, col)
                    shade = 1.0
                    if use_light:
                        nx = b0 * normals[a, 0] + b1 * normals[b, 0] + b2 * normals[cc, 0]
                        ny = b0 * normals[a, 1] + b1 * normals[b, 1] + b2 * normals[cc, 1]
                        nz = b0 * normals[a, 2] + b1 * normals[b, 2] + b2 * normals[cc, 2]
                        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
                        cosang = 0.0
                        if nn > 0.0:
                            cosang = abs(nx * light_dir[0] + ny * light_dir[1] + nz * light_dir[2]) / nn
                        shade = ambient + diffuse * cosang
                        if ssize > 0:
                            wx = b0 * verts[a, 0] + b1 * verts[b, 0] + b2 * verts[cc, 0]
                            wy = b0 * verts[a, 1] + b1 * verts[b, 1] + b2 * verts[cc, 1]
                            wz = b0 * verts[a, 2] + b1 * verts[b, 2] + b2 * verts[cc, 2]
                            if sk.in_shadow(wx, wy, wz, basis, smap, ssize, u0, v0, texel):
                                shade = ambient
                    for j in range(3):
                        acc[j] += col[j] * shade
            for j in range(3):
                out[r, c, j] = min(max(acc[j] * inv, 0.0), 1.0)


@njit(cache=True, nogil=True)
def frame_shadow(verts, cells, use_light, shadow_size, shadow_bias, shadow_slope_bias, shadow_basis):
    """(u0, v0, texel, depth map) of one frame's shadow map; an empty map when there is no light or no shadow."""
    smap = np.empty(shadow_size * shadow_size if use_light else 0)
    u0, v0, texel = 0.0, 0.0, 1.0
    if use_light and shadow_size > 0:
        u0, v0, texel = sk.shadow_frame(verts, shadow_basis, shadow_size)
        sk.shadow_map(verts, cells, shadow_basis, shadow_size, shadow_bias, shadow_slope_bias, u0, v0, texel, smap)
    return u0, v0, texel, smap


@njit(cache=True, nogil=True)
def render_views_kernel(
    verts, cells, uv, tex, flat, face_col, Ks, Rs, ts, h, w, s, near, use_light, light_dir, ambient, diffuse, shadow_size,
    shadow_basis, u0, v0, texel, smap, bg, out,
):  # fmt: skip
    """Render every view n into out[n] (N,H,W,3); cameras given as stacked K, R, t; the frame's shadow map from
    `frame_shadow`, made once per frame however many calls share the views."""
    hs, ws = h * s, w * s
    zbuf = np.empty(hs * ws)
    fid = np.empty(hs * ws, dtype=np.int32)
    bary = np.empty((hs * ws, 3))
    normals = vertex_normals(verts, cells) if use_light else np.zeros((1, 3))
    shadow = (shadow_size if use_light else 0, shadow_basis, smap, u0, v0, texel)
    for n in range(Ks.shape[0]):
        cam = to_camera(verts, Rs[n], ts[n])
        K = Ks[n]
        raster_view(cam, cells, K[0, 0] * s, K[1, 1] * s, K[0, 2] * s, K[1, 2] * s, near, hs, ws, zbuf, fid, bary)
        shade_view(fid, bary, verts, cells, uv, tex, flat, face_col, normals, use_light, light_dir, ambient, diffuse, shadow, bg, s, out[n])


@njit(cache=True, nogil=True)
def depth_kernel(verts, cells, K, R, t, h, w, near):
    """(H*W,) camera-z depth at pixel centres (inf where nothing is drawn)."""
    cam = to_camera(verts, R, t)
    zbuf = np.empty(h * w)
    fid = np.empty(h * w, dtype=np.int32)
    bary = np.empty((h * w, 3))
    raster_view(cam, cells, K[0, 0], K[1, 1], K[0, 2], K[1, 2], near, h, w, zbuf, fid, bary)
    return zbuf
