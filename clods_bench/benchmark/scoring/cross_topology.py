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

Closest points are computed exactly (Ericson's Voronoi-region test per triangle) by the triangle-mesh obstacle's
numba kernel (`datasets.obstacle_kernels.closest_points`), brute force over the faces pruned by their bounding
boxes: exact, and fast at the sizes here (thousands of points x thousands of faces).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clods_bench.datasets.obstacle_kernels import closest_points
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


def attach(points: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> Attachment:
    """Bind each of `points` (N,3) to the closest point on the triangle mesh (`verts` (V,3), `faces` (F,3))."""
    p = _points(points, "points")
    v = _points(verts, "verts")
    f = _faces(faces, v.shape[0])
    tri = v[f]  # (F,3,3)
    n = p.shape[0]
    foot = np.empty((n, 3), dtype=np.float64)
    face = np.empty(n, dtype=np.int64)
    bary = np.empty((n, 3), dtype=np.float64)
    feature = np.empty(n, dtype=np.int64)
    closest_points(np.ascontiguousarray(p), v, np.ascontiguousarray(f), tri.min(axis=1), tri.max(axis=1), foot, face, bary, feature)
    bary = np.clip(bary, 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    return Attachment(face, bary, np.linalg.norm(p - foot, axis=1))


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
