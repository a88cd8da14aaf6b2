"""Cloth mesh file I/O through trimesh: read an OBJ/PLY as a `ClothMesh`, export trajectories per frame."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Literal

import numpy as np

from clods_bench.atomic import atomic_path
from clods_bench.datasets.types import HANDLE, NORMAL, ClothMesh, Trajectory, edges_from_cells
from clods_bench.errors import ClodsError

HandleFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
_MTL_NAME = "material.mtl"


def _load_trimesh(path: Path):  # -> trimesh.Trimesh
    """Load one triangle mesh without merging or reordering vertices."""
    import trimesh

    if not path.is_file():
        raise ClodsError("mesh file does not exist", where=str(path))
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False, maintain_order=True)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise ClodsError(f"cannot read mesh: {type(exc).__name__}: {exc}", where=str(path)) from exc
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
    if faces.ndim != 2 or faces.shape[0] == 0 or faces.shape[1] != 3:
        raise ClodsError("file holds no triangles", where=str(path))
    return mesh


def _pca_plane(points: np.ndarray) -> np.ndarray:
    """Project points onto their best-fit plane (two largest principal directions)."""
    centred = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return centred @ vt[:2].T


def _scale_to_edges(uv: np.ndarray, rest: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Scale uv per axis so mesh-space edge lengths best fit the 3D ones, then match the mean exactly.

    Least squares on squared lengths, sx^2 du^2 + sy^2 dv^2 ~ L^2, undoes the per-axis
    bounding-box normalisation usual for UVs. Edges far off the median length ratio (UV seams,
    e.g. a cylinder's wrap-around column) are left out of the fit; a degenerate fit falls back
    to one uniform scale.
    """
    edges = edges_from_cells(cells)
    d2 = (uv[edges[:, 0]] - uv[edges[:, 1]]) ** 2
    l3 = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    ratio = l3 / np.maximum(np.sqrt(d2.sum(axis=1)), 1e-300)
    keep = np.abs(np.log(ratio / np.median(ratio))) < np.log(4.0)  # drop seam edges before fitting
    scale = np.full(2, np.median(ratio))
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(d2[keep], l3[keep] ** 2, rcond=None)
        if not (np.all(coef > 0) and np.all(np.isfinite(coef))):
            break
        scale = np.sqrt(coef)
        fitted = np.sqrt(d2 @ scale**2) / np.maximum(l3, 1e-300)
        keep = (fitted > 0.5) & (fitted < 2.0)
    l2 = np.sqrt(d2[keep] @ scale**2)
    if not l2.mean() > 0:
        raise ClodsError("texture coordinates are degenerate (all edges have zero length)")
    return uv * scale * (l3[keep].mean() / l2.mean())


def read_triangle_mesh(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(rest (V,3) float64, cells (F,3) int32, uv (V,2) float64 or None) of an OBJ/PLY, vertices in file order."""
    p = Path(path)
    tm = _load_trimesh(p)
    rest = np.asarray(tm.vertices, dtype=np.float64)
    cells = np.asarray(tm.faces, dtype=np.int32)
    uv_raw = getattr(getattr(tm, "visual", None), "uv", None)
    uv = np.asarray(uv_raw, dtype=np.float64) if uv_raw is not None and np.shape(uv_raw) == (rest.shape[0], 2) else None
    return rest, cells, uv


def flatten_rest(rest: np.ndarray, cells: np.ndarray, uv: np.ndarray | None) -> np.ndarray:
    """(V,2) mesh-space coordinates of a rest shape: `uv` scaled to the 3D edge lengths, or the best-fit plane."""
    if uv is not None:
        return _scale_to_edges(np.asarray(uv, dtype=np.float64), rest, cells)
    return _pca_plane(rest)


def mesh_from_file(
    path: str | os.PathLike[str],
    handle_fn: HandleFn | None = None,
    top_tol: float | None = None,
) -> ClothMesh:
    """Read an OBJ/PLY cloth: 3D vertices become `rest_pos`; mesh space from UVs or a PCA plane.

    Mesh-space coordinates (`mesh_pos`) come from the file's texture coordinates when present
    (then also kept as `uv`), scaled to the 3D edge lengths (see `_scale_to_edges`); otherwise
    the vertices are projected onto their best-fit plane. Handle nodes: `handle_fn(rest_pos,
    mesh_pos)` returns a bool mask or indices of HANDLE nodes; else, if `top_tol` is given, the
    nodes within `top_tol` metres of the highest z are handles; else every node is NORMAL.
    """
    p = Path(path)
    rest, cells, uv = read_triangle_mesh(p)
    try:
        mesh_pos = flatten_rest(rest, cells, uv)
    except ClodsError as exc:
        raise ClodsError(exc.what, where=str(p)) from exc
    node_type = np.full(rest.shape[0], NORMAL, dtype=np.int32)
    if handle_fn is not None:
        node_type[np.asarray(handle_fn(rest, mesh_pos))] = HANDLE
    elif top_tol is not None:
        node_type[rest[:, 2] >= rest[:, 2].max() - top_tol] = HANDLE
    mesh = ClothMesh(cells, mesh_pos.astype(np.float32), node_type, rest, None if uv is None else uv.astype(np.float32))
    mesh.validate(str(p))
    return mesh


def _frame_trimesh(traj: Trajectory, frame: int, uv: np.ndarray | None):  # -> trimesh.Trimesh
    import trimesh
    from trimesh.visual import TextureVisuals

    visual = TextureVisuals(uv=uv) if uv is not None else None
    return trimesh.Trimesh(
        vertices=np.asarray(traj.world_pos[frame], dtype=np.float64), faces=traj.cells, visual=visual, process=False
    )


def export_sequence(
    traj: Trajectory,
    out_dir: str | os.PathLike[str],
    fmt: Literal["obj", "ply"] = "obj",
    uv: np.ndarray | None = None,
) -> list[Path]:
    """Write one mesh file per frame (`frame_0000.obj`, ...) atomically, for Blender/MeshLab.

    UVs are written in both formats (OBJ `vt`, PLY vertex `s`/`t`): `uv` if given, else
    `mesh_pos` normalised to its bounding box (what `ClothMesh.texture_uv` gives). OBJ files
    share one `material.mtl` in `out_dir`.
    """
    import trimesh

    if fmt not in ("obj", "ply"):
        raise ClodsError(f"unknown mesh format '{fmt}'; known: obj, ply", where="export_sequence")
    traj.validate("export_sequence")
    if uv is None:
        uv = ClothMesh(traj.cells, traj.mesh_pos, traj.node_type, np.zeros((traj.num_nodes, 3))).texture_uv()
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape != (traj.num_nodes, 2):
        raise ClodsError(f"uv has shape {uv.shape}, expected ({traj.num_nodes}, 2)", where="export_sequence.uv")
    out = Path(out_dir)
    paths: list[Path] = []
    mtl_written = False
    for t in range(traj.num_steps):
        tm = _frame_trimesh(traj, t, uv)
        target = out / f"frame_{t:04d}.{fmt}"
        if fmt == "obj":
            text, extra = trimesh.exchange.obj.export_obj(
                tm, include_texture=True, return_texture=True, write_texture=False, mtl_name=_MTL_NAME, header=None
            )
            data = text.encode()
            if not mtl_written and _MTL_NAME in extra:
                with atomic_path(out / _MTL_NAME) as tmp:
                    tmp.write_bytes(extra[_MTL_NAME])
                mtl_written = True
        else:
            data = trimesh.exchange.ply.export_ply(tm, encoding="binary", include_attributes=True)
        with atomic_path(target) as tmp:
            tmp.write_bytes(data)
        paths.append(target)
    return paths
