"""Scoring a simulator whose mesh is not the ground-truth mesh (a reconstructed cloth, a remeshed one).

Per-node RMSE needs one node list for the prediction and the truth. When a simulator runs on its own mesh (for
example one reconstructed from the first frame's depth maps by `clods.sheet_mesh`), two scores remain:

- attached points: `attach` binds chosen material points (the ground-truth nodes at frame 0) to the predicted
  mesh at frame 0, each to the closest point of its closest triangle (face index + barycentric coordinates);
  `follow` carries them through the predicted frames with those fixed barycentric coordinates (the foot point
  on the surface: the offset along the normal at attach time is dropped), and `attached_rmse` compares them
  with where the ground truth has those points. A material point keeps its barycentric coordinates as the cloth
  deforms, so this measures tracking error, not only shape error; it needs the frame-0 meshes to be close.
- Chamfer: `chamfer` / `chamfer_per_frame` compare two point sets (vertices, or points sampled on the surfaces)
  with no correspondence at all: the shape error only.

Closest points are computed exactly (Ericson's Voronoi-region test per triangle) by a numba kernel, brute force
over the faces, pruned by each face's bounding sphere against the best distance found so far: exact, and fast at
the sizes here (thousands of points x thousands of faces).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from clods_bench.errors import ClodsError


@dataclass(frozen=True)
class Attachment:
    """Points bound to a triangle mesh: `face` (N,) int64 triangle index, `bary` (N,3) float64 barycentric coordinates
    (>= 0, summing to 1) of the closest point in that triangle, `distance` (N,) float64 from each point to it."""

    face: np.ndarray
    bary: np.ndarray
    distance: np.ndarray

    @property
    def num_points(self) -> int:
        return int(self.face.shape[0])


def _points(arr: np.ndarray, where: str) -> np.ndarray:
    a = np.asarray(arr)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ClodsError(f"shape {tuple(a.shape)}, expected (N, 3)", where=where)
    if not np.issubdtype(a.dtype, np.number):
        raise ClodsError(f"dtype {a.dtype}, expected numbers", where=where)
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise ClodsError(f"{int(np.sum(~np.isfinite(a)))} non-finite values (NaN/Inf)", where=where)
    return a


def _faces(faces: np.ndarray, num_verts: int, where: str = "faces") -> np.ndarray:
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ClodsError(f"shape {tuple(f.shape)} and dtype {f.dtype}, expected (F, 3) integers", where=where)
    if f.shape[0] == 0:
        raise ClodsError("no triangles", where=where)
    if f.min() < 0 or f.max() >= num_verts:
        raise ClodsError(f"indices in [{f.min()}, {f.max()}] but there are {num_verts} vertices", where=where)
    return f.astype(np.int64)


def _frames(arr: np.ndarray, where: str, num: int | None = None) -> np.ndarray:
    a = np.asarray(arr)
    if a.ndim != 3 or a.shape[2] != 3 or (num is not None and a.shape[1] != num):
        want = f"(T, {num}, 3)" if num is not None else "(T, N, 3)"
        raise ClodsError(f"shape {tuple(a.shape)}, expected {want}", where=where)
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise ClodsError(f"{int(np.sum(~np.isfinite(a)))} non-finite values (NaN/Inf)", where=where)
    return a


@numba.njit(cache=True)
def closest_on_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[float, float, float]:
    """Barycentric coordinates (u, v, w) of the point of triangle abc closest to p (Ericson, RTCD 5.1.5)."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ap0, ap1, ap2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0  # vertex a
    bp0, bp1, bp2 = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0  # vertex b
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3) if d1 - d3 != 0.0 else 0.0
        return 1.0 - t, t, 0.0  # edge ab
    cp0, cp1, cp2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0  # vertex c
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6) if d2 - d6 != 0.0 else 0.0
        return 1.0 - t, 0.0, t  # edge ac
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        den = (d4 - d3) + (d5 - d6)
        t = (d4 - d3) / den if den != 0.0 else 0.0
        return 0.0, 1.0 - t, t  # edge bc
    den = va + vb + vc
    if den <= 0.0:  # degenerate (zero-area) triangle not caught above: nearest vertex
        return 1.0, 0.0, 0.0
    v = vb / den
    w = vc / den
    return 1.0 - v - w, v, w  # interior


@numba.njit(cache=True)
def _attach_kernel(points, verts, faces, centres, radii, face_out, bary_out, dist_out):  # pragma: no cover - numba
    n = points.shape[0]
    nf = faces.shape[0]
    for i in range(n):
        p = points[i]
        best = np.inf
        bf = -1
        bu, bv, bw = 1.0, 0.0, 0.0
        for f in range(nf):
            dx = p[0] - centres[f, 0]
            dy = p[1] - centres[f, 1]
            dz = p[2] - centres[f, 2]
            lower = np.sqrt(dx * dx + dy * dy + dz * dz) - radii[f]  # no point of the face is nearer than this
            if lower > 0.0 and lower * lower >= best:
                continue
            a, b, c = verts[faces[f, 0]], verts[faces[f, 1]], verts[faces[f, 2]]
            u, v, w = closest_on_triangle(p, a, b, c)
            qx = u * a[0] + v * b[0] + w * c[0] - p[0]
            qy = u * a[1] + v * b[1] + w * c[1] - p[1]
            qz = u * a[2] + v * b[2] + w * c[2] - p[2]
            d2 = qx * qx + qy * qy + qz * qz
            if d2 < best:
                best, bf, bu, bv, bw = d2, f, u, v, w
        face_out[i] = bf
        bary_out[i, 0], bary_out[i, 1], bary_out[i, 2] = bu, bv, bw
        dist_out[i] = np.sqrt(best)


def attach(points: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> Attachment:
    """Bind each of `points` (N,3) to the closest point on the triangle mesh (`verts` (V,3), `faces` (F,3))."""
    p = _points(points, "points")
    v = _points(verts, "verts")
    f = _faces(faces, v.shape[0])
    tri = v[f]  # (F,3,3)
    centres = tri.mean(axis=1)
    radii = np.linalg.norm(tri - centres[:, None, :], axis=2).max(axis=1) * (1.0 + 1e-9) + 1e-12
    face = np.empty(p.shape[0], dtype=np.int64)
    bary = np.empty((p.shape[0], 3), dtype=np.float64)
    dist = np.empty(p.shape[0], dtype=np.float64)
    _attach_kernel(p, v, f, centres, radii, face, bary, dist)
    bary = np.clip(bary, 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    return Attachment(face, bary, dist)


def _check_attachment(att: Attachment, num_faces: int) -> None:
    if not isinstance(att, Attachment):
        raise ClodsError(f"expected an Attachment (from attach), got {type(att).__name__}", where="att")
    if att.face.size and (att.face.min() < 0 or att.face.max() >= num_faces):
        raise ClodsError(f"faces in [{att.face.min()}, {att.face.max()}] but the mesh has {num_faces} triangles", where="att.face",
                         hint="attach to the same faces you follow")  # fmt: skip


def follow(frames: np.ndarray, faces: np.ndarray, att: Attachment) -> np.ndarray:
    """(T,N,3) positions of the attached points carried by their barycentric coordinates through `frames` (T,V,3)."""
    fr = _frames(frames, "frames")
    f = _faces(faces, fr.shape[1])
    _check_attachment(att, f.shape[0])
    corners = fr[:, f[att.face]]  # (T,N,3,3): frame, point, corner, xyz
    return np.einsum("tnkx,nk->tnx", corners, att.bary)


def attached_rmse(pred_frames: np.ndarray, faces: np.ndarray, att: Attachment, gt_frames: np.ndarray) -> np.ndarray:
    """(T,) root mean square over the attached points of |followed on the prediction - ground truth| (metres)."""
    pos = follow(pred_frames, faces, att)
    gt = _frames(gt_frames, "gt_frames", att.num_points)
    if gt.shape[0] != pos.shape[0]:
        raise ClodsError(f"{gt.shape[0]} ground-truth frames but {pos.shape[0]} predicted ones", where="gt_frames")
    return np.sqrt(np.mean(np.sum((pos - gt) ** 2, axis=2), axis=1))


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Chamfer distance in metres: (mean over a of the distance to the nearest b + the same from b to a) / 2.

    Distances, not squared distances (so the value reads as a length, like an RMSE).
    """
    from scipy.spatial import cKDTree

    pa, pb = _points(a, "a"), _points(b, "b")
    if pa.shape[0] == 0 or pb.shape[0] == 0:
        raise ClodsError("Chamfer distance of an empty point set", where="a" if pa.shape[0] == 0 else "b")
    dab = cKDTree(pb).query(pa)[0]
    dba = cKDTree(pa).query(pb)[0]
    return float(0.5 * (dab.mean() + dba.mean()))


def chamfer_per_frame(a_frames: np.ndarray, b_frames: np.ndarray) -> np.ndarray:
    """(T,) `chamfer` of each frame of `a_frames` (T,Na,3) against the same frame of `b_frames` (T,Nb,3)."""
    a, b = _frames(a_frames, "a_frames"), _frames(b_frames, "b_frames")
    if a.shape[0] != b.shape[0]:
        raise ClodsError(f"{a.shape[0]} frames against {b.shape[0]}", where="b_frames")
    return np.array([chamfer(a[t], b[t]) for t in range(a.shape[0])])
