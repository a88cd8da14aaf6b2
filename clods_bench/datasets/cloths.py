"""Scene cloths: what a scene plugin brings of its own: the triangle mesh, its rest coordinates, handles and their motion.

A `Cloth` is a frozen dataclass with a `kind` (a name for the type of cloth, written into each
trajectory's meta) and `build(resolution) -> ClothMesh`; it may move its handles through
`handle_positions(t, start)`. Its fields are hashed into the dataset identity (arrays by their
bytes), so an edited cloth never reuses old data, and it is pickled to generation workers, so it
holds data, not lambdas. The built-in flag and cylinder are clothes like any other; `MeshCloth`
takes any triangle mesh built in code or read from an OBJ/PLY file (`mesh_cloth_from_file`).

`validate_cloth_mesh` is what every scene's mesh must pass before it is simulated: one ClodsError
naming the scene and the problem for a wrong `mesh_pos` shape, zero-area or repeated-node triangles,
duplicate faces, edges of more than two faces, nodes joining two fans of faces, triangles not
consistently oriented, nodes in no face,
handle flags that contradict the scene's `has_handles`, a `mesh_pos` that does not measure the rest
shape, and a handle motion that does not start where the handles are.
"""

from __future__ import annotations

import abc

import dataclasses
import hashlib
import os
from dataclasses import dataclass
from typing import Any, ClassVar, Sequence

import numpy as np

from clods_bench.datasets.mesh_io import flatten_rest, read_triangle_mesh
from clods_bench.datasets.meshes import make_cylinder_mesh, make_flag_mesh, make_flagsimple_mesh
from clods_bench.datasets.types import HANDLE, NORMAL, ClothMesh, edge_use_counts, edges_from_cells
from clods_bench.errors import ClodsError

Resolution = tuple[int, int] | str
_CYLINDER_FLAGSIMPLE = (48, 33)  # 1584 nodes, close to FLAGSIMPLE's 1579
MESH_POS_TOLERANCE = 0.25
"""Largest median relative difference between mesh_pos and rest_pos edge lengths a cloth may have."""


class Cloth(abc.ABC):
    """Base of a scene's cloth; subclasses are frozen dataclasses holding data (picklable, hashable into the identity)."""

    kind: ClassVar[str] = "cloth"
    default_resolution: Resolution | None = None

    @abc.abstractmethod
    def build(self, resolution: Resolution | None) -> ClothMesh:
        """The cloth mesh at `resolution` (None: the cloth's default); HANDLE nodes in `node_type` are the handles."""

    def handle_positions(self, t: float, start: np.ndarray) -> np.ndarray | None:
        """Positions (H,3) of the handles at `t` seconds after the simulation starts, from their start (H,3).

        None (the default) keeps the handles fixed. `t` counts from the start of the warm-up, so frame 0 of a
        trajectory is at t = warmup_time. The result at t = 0 must equal `start`.
        """
        return None

    def identity(self) -> dict[str, Any]:
        """What decides the data this cloth makes: `kind` and every field that is not None (arrays by their hash)."""
        if not dataclasses.is_dataclass(self):
            raise ClodsError(f"{type(self).__name__} is not a dataclass", where="scene cloth", hint="declare it with @dataclass(frozen=True)")
        out: dict[str, Any] = {"kind": self.kind}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is not None:
                out[f.name] = canonical(value)
        return out


def canonical(value: Any) -> Any:
    """A JSON-able, content-complete form of a field value: arrays become their dtype, shape and SHA-256."""
    if isinstance(value, np.ndarray):
        data = np.ascontiguousarray(value)
        return {"array": str(data.dtype), "shape": list(data.shape), "sha256": hashlib.sha256(data.tobytes()).hexdigest()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {"class": f"{type(value).__module__}.{type(value).__qualname__}", **{
            f.name: canonical(getattr(value, f.name)) for f in dataclasses.fields(value)
        }}  # fmt: skip
    if isinstance(value, (list, tuple)):
        return [canonical(v) for v in value]
    if isinstance(value, dict):
        return {str(k): canonical(v) for k, v in value.items()}
    return value


@dataclass(frozen=True)
class FlagCloth(Cloth):
    """A rectangular flag hanging in the x-z plane, pinned along its pole edge (mesh x = 0)."""

    kind: ClassVar[str] = "flag"
    size: tuple[float, float] = (2.0, 1.0)
    """(length, height) in metres."""
    default_resolution: Resolution = "flagsimple"
    """(nx, ny) nodes, or "flagsimple" (1579 nodes, 3028 triangles: the FLAGSIMPLE size)."""

    def build(self, resolution: Resolution | None) -> ClothMesh:
        """The flag at (nx, ny) or "flagsimple"."""
        res = self.default_resolution if resolution is None else resolution
        if isinstance(res, str):
            if res != "flagsimple":
                raise ClodsError(f"unknown resolution '{res}'; use 'flagsimple' or (nx, ny)", where="cloth")
            return make_flagsimple_mesh(*self.size)
        return make_flag_mesh(int(res[0]), int(res[1]), *self.size)


@dataclass(frozen=True)
class CylinderCloth(Cloth):
    """An open tube of cloth (axis along z) hanging from its pinned top ring."""

    kind: ClassVar[str] = "cylinder"
    size: tuple[float, float] = (0.3, 1.0)
    """(radius, height) in metres."""
    default_resolution: Resolution = (32, 16)
    """(n_around, n_along) nodes, or "flagsimple" (48 x 33 = 1584 nodes, about the FLAGSIMPLE size)."""

    def build(self, resolution: Resolution | None) -> ClothMesh:
        """The tube at (n_around, n_along) or "flagsimple"."""
        res = self.default_resolution if resolution is None else resolution
        if isinstance(res, str):
            if res != "flagsimple":
                raise ClodsError(f"unknown resolution '{res}'; use 'flagsimple' or (n_around, n_along)", where="cloth")
            res = _CYLINDER_FLAGSIMPLE
        return make_cylinder_mesh(int(res[0]), int(res[1]), *self.size)


@dataclass(frozen=True)
class SheetCloth(Cloth):
    """A free rectangular sheet lying flat (in the x-y plane at height `height`, centred on the z axis), no handles."""

    kind: ClassVar[str] = "sheet"
    size: tuple[float, float] = (1.2, 0.6)
    """(length along x, width along y) in metres."""
    height: float = 0.45
    """Height (z) of the sheet's rest plane in metres."""
    default_resolution: Resolution = (16, 8)
    """(nx, ny) nodes."""

    def build(self, resolution: Resolution | None) -> ClothMesh:
        """The sheet at (nx, ny): the flag's triangulation laid flat, every node free."""
        res = self.default_resolution if resolution is None else resolution
        if isinstance(res, str):
            raise ClodsError(f"a sheet has no named resolution '{res}'; use (nx, ny)", where="cloth")
        flag = make_flag_mesh(int(res[0]), int(res[1]), *self.size)
        mp = np.asarray(flag.mesh_pos, np.float64)
        rest = np.stack([mp[:, 0] - 0.5 * self.size[0], mp[:, 1] - 0.5 * self.size[1], np.full(len(mp), self.height)], axis=1)
        return ClothMesh(flag.cells, flag.mesh_pos, np.full(len(mp), NORMAL, np.int32), rest)


@dataclass(frozen=True, eq=False)
class MeshCloth(Cloth):
    """Any triangle mesh as a cloth: rest shape, triangles, handle nodes; one resolution (data.resolution is ignored).

    `mesh_pos` (V,2) are the 2D material (rest-space) coordinates the learned simulators read edge
    rest lengths from; None flattens the rest shape: the texture coordinates `uv` scaled per axis to
    the 3D edge lengths when given (exact for a mesh cut flat and laid out without distortion),
    else the rest shape projected onto its best-fit plane (exact for a flat cloth). Either way the
    scene checks that mesh_pos measures the rest edges (`MESH_POS_TOLERANCE`).
    """

    kind: ClassVar[str] = "mesh"
    cells: np.ndarray
    """(F,3) triangles, node indices (counter-clockwise seen from the front)."""
    rest_pos: np.ndarray
    """(V,3) rest shape in metres (world frame: z up); the solver's rest metric."""
    handles: Sequence[int] | np.ndarray = ()
    """Indices of the handle nodes (pinned or moved by `handle_positions`)."""
    mesh_pos: np.ndarray | None = None
    """(V,2) material coordinates in metres; None: from `uv` or the best-fit plane (see the class docstring)."""
    uv: np.ndarray | None = None
    """(V,2) texture coordinates in [0,1]; None: mesh_pos normalised to its bounding box."""

    def build(self, resolution: Resolution | None) -> ClothMesh:
        """The mesh as given (the same at every resolution)."""
        rest = np.asarray(self.rest_pos, dtype=np.float64)
        cells = np.asarray(self.cells)
        if rest.ndim != 2 or rest.shape[1] != 3:
            raise ClodsError(f"rest_pos has shape {rest.shape}, expected (V, 3)", where="cloth.rest_pos")
        if cells.ndim != 2 or cells.shape[1] != 3 or not np.issubdtype(cells.dtype, np.integer):
            raise ClodsError(f"cells has shape {cells.shape} and dtype {cells.dtype}, expected (F, 3) integers", where="cloth.cells")
        handles = np.asarray(self.handles).reshape(-1)
        if handles.size and not np.issubdtype(handles.dtype, np.integer):
            raise ClodsError(f"handles must be node indices (integers), got dtype {handles.dtype}", where="cloth.handles")
        bad = handles[(handles < 0) | (handles >= rest.shape[0])]
        if bad.size:
            raise ClodsError(
                f"{bad.size} handle indices out of range [0, {rest.shape[0]}), first is {int(bad[0])}", where="cloth.handles"
            )
        node_type = np.full(rest.shape[0], NORMAL, dtype=np.int32)
        node_type[handles.astype(np.int64)] = HANDLE
        uv = None if self.uv is None else np.asarray(self.uv, dtype=np.float64)
        if self.mesh_pos is not None:
            mesh_pos = np.asarray(self.mesh_pos, dtype=np.float32)
        else:
            mesh_pos = flatten_rest(rest, cells, uv).astype(np.float32)
        return ClothMesh(cells.astype(np.int32), mesh_pos, node_type, rest, None if uv is None else uv.astype(np.float32))


def mesh_cloth_from_file(
    path: str | os.PathLike[str],
    handles: Sequence[int] | np.ndarray | None = None,
    top_tol: float | None = None,
    mesh_pos: np.ndarray | None = None,
) -> MeshCloth:
    """A `MeshCloth` read from an OBJ/PLY: vertices as the rest shape, the file's UVs kept as texture coordinates.

    Handles: the given indices, else the nodes within `top_tol` metres of the highest z, else none.
    `mesh_pos`: the given array, else flattened from the file's UVs or the best-fit plane (`MeshCloth`).
    """
    rest, cells, uv = read_triangle_mesh(path)
    if handles is None:
        handles = np.flatnonzero(rest[:, 2] >= rest[:, 2].max() - top_tol) if top_tol is not None else ()
    return MeshCloth(cells=cells, rest_pos=rest, handles=np.asarray(handles, dtype=np.int64), mesh_pos=mesh_pos, uv=uv)


def validate_cloth_mesh(mesh: ClothMesh, where: str, has_handles: bool) -> None:
    """Raise one ClodsError naming `where` and the problem if `mesh` is not a simulable cloth (see the module docstring)."""
    rest = np.asarray(mesh.rest_pos)
    num = rest.shape[0] if rest.ndim == 2 else -1
    if rest.ndim != 2 or rest.shape[1] != 3:
        raise ClodsError(f"rest_pos has shape {tuple(rest.shape)}, expected (V, 3)", where=where)
    if np.shape(mesh.mesh_pos) != (num, 2):
        raise ClodsError(f"mesh_pos has shape {tuple(np.shape(mesh.mesh_pos))}, expected (V, 2) = ({num}, 2)", where=where)
    if mesh.uv is not None and np.shape(mesh.uv) != (num, 2):
        raise ClodsError(f"uv has shape {tuple(np.shape(mesh.uv))}, expected (V, 2) = ({num}, 2)", where=where)
    mesh.validate(where)
    kinds = set(np.unique(mesh.node_type).tolist())
    if not kinds <= {NORMAL, HANDLE}:
        raise ClodsError(f"node_type holds {sorted(kinds)}; a cloth's nodes are NORMAL ({NORMAL}) or HANDLE ({HANDLE})", where=where)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    if cells.shape[0] == 0:
        raise ClodsError("the mesh has no triangles", where=where)
    _check_faces(cells, rest, where)
    _check_manifold(cells, num, where)
    unused = np.setdiff1d(np.arange(num), cells.ravel())
    if unused.size:
        raise ClodsError(f"{unused.size} nodes belong to no triangle (no mass), first is node {int(unused[0])}", where=where)
    n_handles = int(np.sum(mesh.node_type == HANDLE))
    if has_handles and n_handles == 0:
        raise ClodsError("the scene declares has_handles but the cloth has no handle node", where=where,
                         hint="mark handles, or set has_handles=False for a free cloth")  # fmt: skip
    if not has_handles and n_handles:
        raise ClodsError(f"the cloth has {n_handles} handle nodes but the scene declares has_handles=False", where=where)
    _check_mesh_pos(cells, rest, np.asarray(mesh.mesh_pos, dtype=np.float64), where)


def _check_faces(cells: np.ndarray, rest: np.ndarray, where: str) -> None:
    repeated = np.flatnonzero((cells[:, 0] == cells[:, 1]) | (cells[:, 1] == cells[:, 2]) | (cells[:, 0] == cells[:, 2]))
    if repeated.size:
        raise ClodsError(f"{repeated.size} triangles repeat a node, first is face {int(repeated[0])}", where=where)
    e1 = rest[cells[:, 1]] - rest[cells[:, 0]]
    e2 = rest[cells[:, 2]] - rest[cells[:, 0]]
    twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest = np.max(np.stack([np.sum(e1**2, 1), np.sum(e2**2, 1), np.sum((e2 - e1) ** 2, 1)]), axis=0)
    flat = np.flatnonzero(~(twice_area > 1e-10 * longest))  # area / longest^2 below 5e-11: zero to rounding
    if flat.size:
        raise ClodsError(f"{flat.size} triangles have zero rest area (degenerate), first is face {int(flat[0])}", where=where)
    key = np.sort(cells, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if np.any(counts > 1):
        dup = np.sort(first[counts > 1])
        raise ClodsError(f"{int(np.sum(counts[counts > 1] - 1))} duplicate faces, first duplicates face {int(dup[0])}", where=where)


def _check_manifold(cells: np.ndarray, num: int, where: str) -> None:
    edges, counts = edge_use_counts(cells)
    if np.any(counts > 2):
        bad = edges[counts > 2]
        raise ClodsError(
            f"{bad.shape[0]} edges are shared by more than two triangles (non-manifold), first is edge ({bad[0, 0]}, {bad[0, 1]})",
            where=where,
        )
    directed = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    if np.any(dcounts > 1):  # two faces sharing an edge must run along it in opposite directions
        raise ClodsError(
            f"triangles are not consistently oriented: {int(np.sum(dcounts > 1))} edges run the same way in both their "
            "triangles (normals, wind pressure and the initial bend need one side of the cloth)",
            where=where,
            hint="flip the corner order of the triangles on the wrong side",
        )
    boundary = edges[counts == 1]
    ends = np.bincount(boundary.ravel(), minlength=num)
    bowtie = np.flatnonzero(ends > 2)  # a manifold node lies on 0 or 2 boundary edges; more: fans meeting at a point
    if bowtie.size:
        raise ClodsError(
            f"{bowtie.size} nodes join separate fans of triangles (non-manifold), first is node {int(bowtie[0])}", where=where
        )


def _check_mesh_pos(cells: np.ndarray, rest: np.ndarray, mesh_pos: np.ndarray, where: str) -> None:
    edges = edges_from_cells(cells)
    l3 = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    l2 = np.linalg.norm(mesh_pos[edges[:, 0]] - mesh_pos[edges[:, 1]], axis=1)
    err = float(np.median(np.abs(l2 / l3 - 1.0)))  # the median ignores seam edges (a cylinder's wrap-around column)
    if not err <= MESH_POS_TOLERANCE:
        raise ClodsError(
            f"mesh_pos edge lengths differ from the rest shape's by {100 * err:.0f}% (median; at most "
            f"{100 * MESH_POS_TOLERANCE:.0f}%): mesh_pos must be the cloth's rest coordinates in metres",
            where=where,
            hint="give mesh_pos, or texture coordinates laid out without distortion",
        )


def validate_handle_motion(cloth: Cloth, start: np.ndarray, dt: float, where: str) -> bool:
    """Check the cloth's handle motion (shape, finite, starts at `start`); True if the handles move."""
    first = cloth.handle_positions(0.0, start)
    if first is None:
        return False
    for t in (0.0, dt):
        pos = np.asarray(cloth.handle_positions(t, start), dtype=np.float64)
        if pos.shape != start.shape:
            raise ClodsError(f"handle_positions({t}) has shape {pos.shape}, expected {start.shape} (one row per handle)", where=where)
        if not np.isfinite(pos).all():
            raise ClodsError(f"handle_positions({t}) holds NaN/Inf", where=where)
    jump = float(np.abs(np.asarray(first, dtype=np.float64) - start).max()) if start.size else 0.0
    if jump > 1e-9:
        raise ClodsError(f"handle_positions(0) is {jump:.3g} m away from the handles' start: they would jump", where=where)
    return True
