"""The data model shared by every part of clods-bench (FLAGSIMPLE schema).

Conventions, stated once:
- world coordinates are metres, gravity along -z by default (scene decides);
- `cells` (F,3) int32 triangles, counter-clockwise in mesh space;
- `mesh_pos` (V,2) float32 rest / UV coordinates in mesh space (metres);
- `node_type` (V,) int32 with MeshGraphNets codes NORMAL=0, OBSTACLE=1, HANDLE=3;
- `world_pos` (T,V,3) float32, frame 0 is the initial state, frames are `dt` seconds apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from clods_bench.errors import ClodsError

NORMAL = 0
OBSTACLE = 1
HANDLE = 3
NODE_TYPE_SIZE = 9  # one-hot width used by MeshGraphNets


@dataclass
class ClothMesh:
    """Mesh topology plus the rest shape of a cloth."""

    cells: np.ndarray  # (F,3) int32
    mesh_pos: np.ndarray  # (V,2) float32, rest coordinates in mesh space (also the UV source)
    node_type: np.ndarray  # (V,) int32
    rest_pos: np.ndarray  # (V,3) float64, rest shape in world space
    uv: np.ndarray | None = None  # (V,2) float32 texture coordinates in [0,1]; None -> from mesh_pos

    @property
    def num_nodes(self) -> int:
        return int(self.mesh_pos.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self.cells.shape[0])

    def texture_uv(self) -> np.ndarray:
        """UVs in [0,1]: the stored ones, or `mesh_pos` normalised to its bounding box."""
        if self.uv is not None:
            return self.uv.astype(np.float32)
        lo = self.mesh_pos.min(axis=0)
        span = np.maximum(self.mesh_pos.max(axis=0) - lo, 1e-12)
        return ((self.mesh_pos - lo) / span).astype(np.float32)

    def validate(self, where: str = "mesh") -> None:
        """Raise ClodsError naming the field when shapes, indices or values are wrong."""
        validate_topology(self.cells, self.mesh_pos, self.node_type, where)
        _check_shape(self.rest_pos, (self.num_nodes, 3), f"{where}.rest_pos")
        _check_finite(self.rest_pos, f"{where}.rest_pos")


@dataclass
class Trajectory:
    """One simulated (or recorded) cloth trajectory in the FLAGSIMPLE schema."""

    cells: np.ndarray  # (F,3) int32
    mesh_pos: np.ndarray  # (V,2) float32
    node_type: np.ndarray  # (V,) int32
    world_pos: np.ndarray  # (T,V,3) float32
    dt: float
    meta: dict[str, Any] = field(default_factory=dict)  # scene name, seed, wind, ...

    @property
    def num_steps(self) -> int:
        return int(self.world_pos.shape[0])

    @property
    def num_nodes(self) -> int:
        return int(self.world_pos.shape[1])

    @property
    def handle_mask(self) -> np.ndarray:
        """(V,) bool: nodes whose motion is prescribed (not NORMAL)."""
        return self.node_type != NORMAL

    def validate(self, where: str = "trajectory") -> None:
        """Raise ClodsError naming the field when shapes, dtypes or values are wrong."""
        validate_topology(self.cells, self.mesh_pos, self.node_type, where)
        wp = self.world_pos
        if wp.ndim != 3 or wp.shape[1:] != (self.mesh_pos.shape[0], 3):
            raise ClodsError(
                f"world_pos has shape {tuple(wp.shape)}, expected (T, {self.mesh_pos.shape[0]}, 3)",
                where=f"{where}.world_pos",
            )
        if wp.shape[0] < 2:
            raise ClodsError(f"world_pos has {wp.shape[0]} frames, need at least 2", where=f"{where}.world_pos")
        _check_finite(wp, f"{where}.world_pos")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ClodsError(f"dt must be a positive number, got {self.dt}", where=f"{where}.dt")

    def slice(self, start: int, stop: int) -> "Trajectory":
        """Frames [start, stop) as a new trajectory sharing topology."""
        return Trajectory(self.cells, self.mesh_pos, self.node_type, self.world_pos[start:stop], self.dt, dict(self.meta))


def validate_topology(cells: np.ndarray, mesh_pos: np.ndarray, node_type: np.ndarray, where: str) -> None:
    """Check cells/mesh_pos/node_type shapes, index range and finiteness."""
    if mesh_pos.ndim != 2 or mesh_pos.shape[1] != 2:
        raise ClodsError(f"mesh_pos has shape {tuple(mesh_pos.shape)}, expected (V, 2)", where=f"{where}.mesh_pos")
    num_nodes = mesh_pos.shape[0]
    if cells.ndim != 2 or cells.shape[1] != 3:
        raise ClodsError(f"cells has shape {tuple(cells.shape)}, expected (F, 3)", where=f"{where}.cells")
    if not np.issubdtype(cells.dtype, np.integer):
        raise ClodsError(f"cells has dtype {cells.dtype}, expected an integer type", where=f"{where}.cells")
    if cells.size and (cells.min() < 0 or cells.max() >= num_nodes):
        raise ClodsError(
            f"cells index nodes in [{cells.min()}, {cells.max()}] but there are {num_nodes} nodes",
            where=f"{where}.cells",
        )
    _check_shape(node_type, (num_nodes,), f"{where}.node_type")
    _check_finite(mesh_pos, f"{where}.mesh_pos")


def _check_shape(arr: np.ndarray, shape: tuple[int, ...], where: str) -> None:
    if tuple(arr.shape) != shape:
        raise ClodsError(f"shape {tuple(arr.shape)}, expected {shape}", where=where)


def _check_finite(arr: np.ndarray, where: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ClodsError(f"{int(bad.sum())} non-finite values (NaN/Inf), first at index {first}", where=where)


def edges_from_cells(cells: np.ndarray) -> np.ndarray:
    """Unique undirected edges (E,2) int64 with sender < receiver, from triangles."""
    e = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]], axis=0).astype(np.int64)
    e = np.sort(e, axis=1)
    return np.unique(e, axis=0)


def edge_use_counts(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique undirected edges (E,2) as `edges_from_cells`, how many triangles use each): 1 on the rim, 2 inside."""
    e = np.sort(np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]], axis=0).astype(np.int64), axis=1)
    return np.unique(e, axis=0, return_counts=True)


def boundary_nodes(cells: np.ndarray) -> np.ndarray:
    """Sorted nodes on an edge that only one triangle uses (the rim of an open sheet)."""
    edges, counts = edge_use_counts(cells)
    return np.unique(edges[counts == 1])
