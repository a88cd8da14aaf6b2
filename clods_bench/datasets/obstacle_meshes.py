"""Triangle meshes of obstacles: the unit icosphere, faces turned outward, mesh validation, and the closest-point
query of a mesh obstacle (brute force in numba, `obstacle_kernels`), signed by the angle-weighted pseudo-normal of
the closest feature (Baerentzen & Aanaes 2005). The obstacle classes themselves are in `obstacles`."""

from __future__ import annotations

import functools
import math

import numpy as np

from clods_bench.datasets import obstacle_kernels as ok
from clods_bench.errors import ClodsError


def unit_vectors(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Rows of v normalised; rows of (near) zero length become `fallback`."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    tiny = norm[..., 0] <= 1e-300
    out = v / np.where(tiny[..., None], 1.0, norm)
    out[tiny] = fallback[tiny] if fallback.ndim == v.ndim else fallback
    return out


@functools.lru_cache(maxsize=8)
def _icosphere_cached(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    phi = (1.0 + math.sqrt(5.0)) / 2.0
    verts = [(-1, phi, 0), (1, phi, 0), (-1, -phi, 0), (1, -phi, 0), (0, -1, phi), (0, 1, phi),
             (0, -1, -phi), (0, 1, -phi), (phi, 0, -1), (phi, 0, 1), (-phi, 0, -1), (-phi, 0, 1)]  # fmt: skip
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
             (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
             (8, 6, 7), (9, 8, 1)]  # fmt: skip
    v = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in verts]
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def mid(i: int, j: int) -> int:
            key = (min(i, j), max(i, j))
            if key not in cache:
                m = v[i] + v[j]
                v.append(m / np.linalg.norm(m))
                cache[key] = len(v) - 1
            return cache[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    verts_arr = np.array(v)
    faces_arr = orient_outward(verts_arr, np.array(faces, dtype=np.int32), lambda c: np.zeros_like(c))
    verts_arr.setflags(write=False)
    faces_arr.setflags(write=False)
    return verts_arr, faces_arr


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit sphere: vertices (M,3) float64 and outward CCW faces (F,3) int32; 20 * 4^subdivisions faces."""
    if not (isinstance(subdivisions, (int, np.integer)) and 0 <= subdivisions <= 7):
        raise ClodsError(f"must be an integer in 0..7, got {subdivisions!r}", where="icosphere.subdivisions")
    verts, faces = _icosphere_cached(int(subdivisions))
    return verts.copy(), faces.copy()


def orient_outward(verts: np.ndarray, faces: np.ndarray, inner) -> np.ndarray:
    """Faces of a convex surface flipped where their normal points towards `inner(centroids)` (points inside)."""
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centroid = tri.mean(axis=1)
    flip = np.einsum("fi,fi->f", normal, centroid - inner(centroid)) < 0
    out = faces.copy()
    out[flip] = out[flip][:, [0, 2, 1]]
    return out.astype(np.int32)


def validate_mesh(verts: np.ndarray, faces: np.ndarray, where: str, vert_field: str) -> None:
    """A ClodsError naming `where` unless `faces` index `verts` (finite; a trailing frame axis allowed) with no
    degenerate triangle."""
    if not (isinstance(faces, np.ndarray) and faces.ndim == 2 and faces.shape[1] == 3 and faces.shape[0] >= 1):
        raise ClodsError(f"must be an (F, 3) integer array with F >= 1, got {getattr(faces, 'shape', type(faces))}", where=f"{where}.faces")
    if not np.issubdtype(faces.dtype, np.integer):
        raise ClodsError(f"must be integers, got {faces.dtype}", where=f"{where}.faces")
    m = verts.shape[-2]
    if faces.min() < 0 or faces.max() >= m:
        raise ClodsError(f"indices must be in [0, {m}), got [{faces.min()}, {faces.max()}]", where=f"{where}.faces")
    if not np.isfinite(verts).all():
        raise ClodsError("must be finite", where=f"{where}.{vert_field}")
    tri = verts[..., faces, :]
    area2 = np.linalg.norm(np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]), axis=-1)
    scale = max(float(np.ptp(verts.reshape(-1, 3), axis=0).max()), 1e-300)
    bad = np.flatnonzero((area2 <= 1e-12 * scale * scale).reshape(-1, faces.shape[0]).any(axis=0))
    if bad.size:
        raise ClodsError(f"{bad.size} degenerate (zero-area) triangles, first is face {bad[0]}", where=f"{where}.faces")


def edge_ids(faces: np.ndarray) -> np.ndarray:
    """(F,3) index of the undirected edges (v0,v1), (v1,v2), (v2,v0) of every face."""
    e = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1).reshape(-1, 2).astype(np.int64)
    e.sort(axis=1)
    _, inverse = np.unique(e[:, 0] * (int(faces.max()) + 1) + e[:, 1], return_inverse=True)
    return inverse.reshape(-1, 3)


def cached_edge_ids(obstacle: object) -> np.ndarray:
    """`edge_ids` of a frozen mesh obstacle's faces, computed once and kept on the instance."""
    cached = obstacle.__dict__.get("_edge_id")
    if cached is None:
        cached = edge_ids(np.asarray(obstacle.faces))  # type: ignore[attr-defined]
        object.__setattr__(obstacle, "_edge_id", cached)
    return cached


def mesh_query(x: np.ndarray, verts: np.ndarray, faces: np.ndarray, edge_id: np.ndarray):
    """Signed distance, outward normal, closest face and barycentrics of points x (N,3) on a triangle mesh."""
    tri = verts[faces]
    e1, e2, e3 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2]
    fn = unit_vectors(np.cross(e1, -e3), np.array([0.0, 0.0, 1.0]))
    # angle-weighted vertex pseudo-normals and edge pseudo-normals (sum of the adjacent faces' normals)
    ue = [unit_vectors(e, np.zeros(3)) for e in (e1, e2, e3)]
    angles = [np.arccos(np.clip(-np.einsum("fi,fi->f", ue[(k + 2) % 3], ue[k]), -1.0, 1.0)) for k in range(3)]
    vn = np.zeros_like(verts)
    for k in range(3):
        np.add.at(vn, faces[:, k], angles[k][:, None] * fn)
    en = np.zeros((int(edge_id.max()) + 1, 3))
    for k in range(3):
        np.add.at(en, edge_id[:, k], fn)
    n_pts = x.shape[0]
    point, face = np.zeros((n_pts, 3)), np.zeros(n_pts, np.int64)
    bary, feature = np.zeros((n_pts, 3)), np.zeros(n_pts, np.int64)
    ok.closest_points(np.ascontiguousarray(x), verts, faces, tri.min(axis=1), tri.max(axis=1), point, face, bary, feature)
    pseudo = fn[face]
    for k, code in enumerate((ok.VERTEX_A, ok.VERTEX_B, ok.VERTEX_C)):
        sel = feature == code
        pseudo[sel] = vn[faces[face[sel], k]]
    for k, code in enumerate((ok.EDGE_AB, ok.EDGE_BC, ok.EDGE_CA)):
        sel = feature == code
        pseudo[sel] = en[edge_id[face[sel], k]]
    rel = x - point
    dist = np.linalg.norm(rel, axis=1)
    sign = np.where(np.einsum("ni,ni->n", rel, pseudo) < 0, -1.0, 1.0)
    normal = np.where((dist > 1e-12)[:, None], sign[:, None] * rel / np.maximum(dist, 1e-300)[:, None], unit_vectors(pseudo, fn[face]))
    return sign * dist, normal, face, bary


def mesh_arrays(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous float64 vertices and int64 faces, as the numba kernels take them."""
    return np.ascontiguousarray(verts, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64)
