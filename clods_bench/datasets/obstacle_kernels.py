"""Numba kernels of the triangle-mesh obstacle: closest point on a triangle mesh, brute force with box culling.

`closest_point_triangle` is Ericson's Voronoi-region test ("Real-Time Collision Detection", 5.1.5): it
returns the closest point's barycentric coordinates and which feature holds it (the face, one of the
three edges, or one of the three corners), so the caller can sign the distance with the pseudo-normal
of that feature (Baerentzen & Aanaes 2005); zero-area triangles get their nearest corner or edge point.
`closest_points` visits every face for every point but skips faces whose bounding box is farther than the
best distance so far, starting from the previous point's face (cloth nodes come in spatially coherent
order). Both the obstacles and the cross-topology scoring (`benchmark.cross_topology.attach`) use it.
"""

from __future__ import annotations

import numba
import numpy as np

FACE, VERTEX_A, VERTEX_B, VERTEX_C, EDGE_AB, EDGE_BC, EDGE_CA = 0, 1, 2, 3, 4, 5, 6
"""Feature codes of the closest point on a triangle (a, b, c)."""


@numba.njit(cache=True)
def _dot3(a0, a1, a2, b0, b1, b2):
    return a0 * b0 + a1 * b1 + a2 * b2


@numba.njit(cache=True)
def closest_point_triangle(p, a, b, c):
    """Barycentric (u, v, w) of the point of triangle abc closest to p (each (3,)), and its feature code."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    d1 = _dot3(ab0, ab1, ab2, p[0] - a[0], p[1] - a[1], p[2] - a[2])
    d2 = _dot3(ac0, ac1, ac2, p[0] - a[0], p[1] - a[1], p[2] - a[2])
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0, VERTEX_A
    d3 = _dot3(ab0, ab1, ab2, p[0] - b[0], p[1] - b[1], p[2] - b[2])
    d4 = _dot3(ac0, ac1, ac2, p[0] - b[0], p[1] - b[1], p[2] - b[2])
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0, VERTEX_B
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        s = d1 / (d1 - d3) if d1 - d3 != 0.0 else 0.0
        return 1.0 - s, s, 0.0, EDGE_AB
    d5 = _dot3(ab0, ab1, ab2, p[0] - c[0], p[1] - c[1], p[2] - c[2])
    d6 = _dot3(ac0, ac1, ac2, p[0] - c[0], p[1] - c[1], p[2] - c[2])
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0, VERTEX_C
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        s = d2 / (d2 - d6) if d2 - d6 != 0.0 else 0.0
        return 1.0 - s, 0.0, s, EDGE_CA
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        den = (d4 - d3) + (d5 - d6)
        s = (d4 - d3) / den if den != 0.0 else 0.0
        return 0.0, 1.0 - s, s, EDGE_BC
    if va + vb + vc <= 0.0:  # a zero-area triangle the tests above did not catch: its first corner
        return 1.0, 0.0, 0.0, VERTEX_A
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    return 1.0 - v - w, v, w, FACE


@numba.njit(cache=True)
def _box_dist2(p, lo, hi):
    s = 0.0
    for d in range(3):
        if p[d] < lo[d]:
            s += (lo[d] - p[d]) ** 2
        elif p[d] > hi[d]:
            s += (p[d] - hi[d]) ** 2
    return s


@numba.njit(cache=True)
def closest_points(x, verts, faces, lo, hi, out_point, out_face, out_bary, out_feature):
    """For each point x[i]: closest point on the mesh, its face, barycentrics and feature code (outputs filled)."""
    nf = faces.shape[0]
    prev = 0
    for i in range(x.shape[0]):
        p = x[i]
        best = np.inf
        best_f = -1
        # first the previous point's face, to start with a tight bound
        for k in range(-1, nf):
            f = prev if k < 0 else k
            if k >= 0 and f == prev:
                continue
            if _box_dist2(p, lo[f], hi[f]) >= best:
                continue
            a = verts[faces[f, 0]]
            b = verts[faces[f, 1]]
            c = verts[faces[f, 2]]
            u, v, w, feat = closest_point_triangle(p, a, b, c)
            q0 = u * a[0] + v * b[0] + w * c[0]
            q1 = u * a[1] + v * b[1] + w * c[1]
            q2 = u * a[2] + v * b[2] + w * c[2]
            d2 = (p[0] - q0) ** 2 + (p[1] - q1) ** 2 + (p[2] - q2) ** 2
            if d2 < best:
                best = d2
                best_f = f
                out_point[i, 0], out_point[i, 1], out_point[i, 2] = q0, q1, q2
                out_bary[i, 0], out_bary[i, 1], out_bary[i, 2] = u, v, w
                out_feature[i] = feat
        out_face[i] = best_f
        prev = best_f
