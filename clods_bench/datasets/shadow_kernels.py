"""Numba kernels of the ground-truth renderer's shadow map (a directional light's orthographic depth image).

Light space: rows (u, v, l) of an orthonormal basis, l the light's unit direction; a world point x has
map coordinates ((x.u - u0) / texel, (x.v - v0) / texel) and depth x.l (larger = farther from the light).
The map covers every vertex of the frame with one spare texel on each side; texel (row j, col i) has its
centre at (i + 0.5, j + 0.5). Each triangle is drawn with texel centres on its edges included (no light
leaks through shared edges), depth interpolated linearly (orthographic), plus its bias. A point is in
shadow when its depth exceeds the stored depth of the texel it falls in (nearest texel, no filtering).
Compiled lazily on first call and cached on disk, like `raster_kernels`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

EDGE_EPS = 1e-9  # relative tolerance of the inclusive edge test (closes float-rounding cracks between triangles)


@njit(cache=True, nogil=True)
def shadow_frame(verts, basis, size):
    """(u0, v0, texel): the map's origin and texel size covering every vertex with one spare texel per side."""
    lo_u, hi_u, lo_v, hi_v = np.inf, -np.inf, np.inf, -np.inf
    for i in range(verts.shape[0]):
        pu = basis[0, 0] * verts[i, 0] + basis[0, 1] * verts[i, 1] + basis[0, 2] * verts[i, 2]
        pv = basis[1, 0] * verts[i, 0] + basis[1, 1] * verts[i, 1] + basis[1, 2] * verts[i, 2]
        lo_u, hi_u = min(lo_u, pu), max(hi_u, pu)
        lo_v, hi_v = min(lo_v, pv), max(hi_v, pv)
    if verts.shape[0] == 0:
        return 0.0, 0.0, 1.0
    extent = max(hi_u - lo_u, hi_v - lo_v)
    texel = extent / (size - 2) if extent > 0.0 else 1.0
    return lo_u - texel, lo_v - texel, texel


@njit(cache=True, nogil=True)
def shadow_map(verts, cells, basis, size, bias, slope_bias, u0, v0, texel, depth):
    """Fill depth (size*size,) with the biased nearest depth along the light of the triangles `cells` (inf: empty)."""
    depth[:] = np.inf
    inv = 1.0 / texel
    gx = np.empty(3)
    gy = np.empty(3)
    gz = np.empty(3)
    for f in range(cells.shape[0]):
        for j in range(3):
            p = verts[cells[f, j]]
            gx[j] = ((basis[0, 0] * p[0] + basis[0, 1] * p[1] + basis[0, 2] * p[2]) - u0) * inv
            gy[j] = ((basis[1, 0] * p[0] + basis[1, 1] * p[1] + basis[1, 2] * p[2]) - v0) * inv
            gz[j] = basis[2, 0] * p[0] + basis[2, 1] * p[1] + basis[2, 2] * p[2]
        area = (gx[1] - gx[0]) * (gy[2] - gy[0]) - (gy[1] - gy[0]) * (gx[2] - gx[0])
        if not (area != 0.0 and math.isfinite(area)):
            continue  # edge-on to the light (or degenerate): casts no shadow of any area
        # depth slope per texel: z = z0 + a (x - x0) + b (y - y0)
        a = ((gz[1] - gz[0]) * (gy[2] - gy[0]) - (gz[2] - gz[0]) * (gy[1] - gy[0])) / area
        b = ((gz[2] - gz[0]) * (gx[1] - gx[0]) - (gz[1] - gz[0]) * (gx[2] - gx[0])) / area
        offset = bias + slope_bias * (abs(a) + abs(b))
        c0 = max(int(math.ceil(min(gx[0], gx[1], gx[2]) - 0.5)), 0)
        c1 = min(int(math.floor(max(gx[0], gx[1], gx[2]) - 0.5)), size - 1)
        r0 = max(int(math.ceil(min(gy[0], gy[1], gy[2]) - 0.5)), 0)
        r1 = min(int(math.floor(max(gy[0], gy[1], gy[2]) - 0.5)), size - 1)
        inv_area = 1.0 / area
        for r in range(r0, r1 + 1):
            sy = r + 0.5
            for c in range(c0, c1 + 1):
                sx = c + 0.5
                w0 = ((gx[2] - gx[1]) * (sy - gy[1]) - (gy[2] - gy[1]) * (sx - gx[1])) * inv_area
                w1 = ((gx[0] - gx[2]) * (sy - gy[2]) - (gy[0] - gy[2]) * (sx - gx[2])) * inv_area
                w2 = 1.0 - w0 - w1
                if w0 < -EDGE_EPS or w1 < -EDGE_EPS or w2 < -EDGE_EPS:
                    continue
                z = w0 * gz[0] + w1 * gz[1] + w2 * gz[2] + offset
                k = r * size + c
                if z < depth[k]:
                    depth[k] = z


@njit(cache=True, nogil=True)
def in_shadow(px, py, pz, basis, depth, size, u0, v0, texel):
    """Whether world point (px, py, pz) lies farther from the light than the shadow map's depth at its texel."""
    gu = ((basis[0, 0] * px + basis[0, 1] * py + basis[0, 2] * pz) - u0) / texel
    gv = ((basis[1, 0] * px + basis[1, 1] * py + basis[1, 2] * pz) - v0) / texel
    if not (gu >= 0.0 and gv >= 0.0 and gu < size and gv < size):
        return False
    d = basis[2, 0] * px + basis[2, 1] * py + basis[2, 2] * pz
    return d > depth[int(gv) * size + int(gu)]
