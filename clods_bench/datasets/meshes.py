"""Cloth mesh builders: rectangular flags, the FLAGSIMPLE-sized flag and an open cylinder.

Every builder returns a validated `ClothMesh` whose triangles are counter-clockwise in
mesh space. File reading and per-frame export live in `mesh_io` and are re-exported here.
"""

from __future__ import annotations

import math

import numpy as np

from clods_bench.datasets.mesh_io import export_sequence, mesh_from_file
from clods_bench.datasets.types import HANDLE, NORMAL, ClothMesh
from clods_bench.errors import ClodsError

__all__ = [
    "FLAGSIMPLE_NODES",
    "FLAGSIMPLE_FACES",
    "make_flag_mesh",
    "make_flagsimple_mesh",
    "make_cylinder_mesh",
    "mesh_from_file",
    "export_sequence",
]

FLAGSIMPLE_NODES = 1579
FLAGSIMPLE_FACES = 3028
_FLAGSIMPLE_GRID = (44, 22)  # p + q = 66 -> 128 boundary nodes, as V=1579, F=3028 require


def _check_count(value: int, least: int, name: str, where: str) -> None:
    if int(value) != value or value < least:
        raise ClodsError(f"{name} must be an integer >= {least}, got {value}", where=where)


def _grid_quads(nx: int, ny: int) -> np.ndarray:
    """(Q,4) corner indices (n00, n10, n11, n01) of the grid quads, node index i + nx*j, row-major."""
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="xy")
    n00 = (i + nx * j).ravel()
    return np.stack([n00, n00 + 1, n00 + 1 + nx, n00 + nx], axis=1)


def _split_quads(quads: np.ndarray, alternate: np.ndarray) -> np.ndarray:
    """Two CCW triangles per quad; diagonal n00-n11, or n10-n01 where `alternate` is set."""
    a, b, c, d = quads.T
    t1 = np.where(alternate[:, None], np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    t2 = np.where(alternate[:, None], np.stack([b, c, d], 1), np.stack([a, c, d], 1))
    return np.stack([t1, t2], axis=1).reshape(-1, 3)


def _flag_from_grid(mesh_pos: np.ndarray, cells: np.ndarray) -> ClothMesh:
    """Wrap rest 2D coordinates as a flag hanging in the x-z plane, pinned along mesh x == 0."""
    node_type = np.where(np.isclose(mesh_pos[:, 0], 0.0), HANDLE, NORMAL).astype(np.int32)
    rest = np.zeros((mesh_pos.shape[0], 3))
    rest[:, 0] = mesh_pos[:, 0]
    rest[:, 2] = mesh_pos[:, 1]
    mesh = ClothMesh(cells.astype(np.int32), mesh_pos.astype(np.float32), node_type, rest)
    mesh.validate("flag mesh")
    return mesh


def make_flag_mesh(nx: int, ny: int, length: float = 2.0, height: float = 1.0) -> ClothMesh:
    """A length x height flag of nx x ny nodes, pole edge (x=0) pinned, hanging in the x-z plane.

    Quads are split along alternating diagonals (checkerboard) so the mesh has no preferred
    shear direction. Node (i, j) has index i + nx*j, mesh position (i*dx, j*dy), world (x, 0, y).
    """
    _check_count(nx, 2, "nx", "make_flag_mesh")
    _check_count(ny, 2, "ny", "make_flag_mesh")
    if not (length > 0 and height > 0):
        raise ClodsError(f"length and height must be positive, got {length}, {height}", where="make_flag_mesh")
    xs, ys = np.meshgrid(np.linspace(0.0, length, nx), np.linspace(0.0, height, ny), indexing="xy")
    mesh_pos = np.stack([xs.ravel(), ys.ravel()], axis=1)
    quads = _grid_quads(nx, ny)
    qi = np.arange(quads.shape[0])
    alternate = ((qi % (nx - 1)) + (qi // (nx - 1))) % 2 == 1
    return _flag_from_grid(mesh_pos, _split_quads(quads, alternate))


def make_flagsimple_mesh(length: float = 2.0, height: float = 1.0) -> ClothMesh:
    """A flag with exactly the FLAGSIMPLE size: 1579 nodes and 3028 triangles.

    A 44 x 22 grid (968 nodes, 903 quads, 128 boundary nodes) where 611 quads, spread evenly
    in row-major order (Bresenham), get a centre node and 4 triangles; the others get 2.
    """
    p, q = _FLAGSIMPLE_GRID
    quads = _grid_quads(p, q)
    n_quads = quads.shape[0]
    n_centres = FLAGSIMPLE_NODES - p * q
    k = np.arange(n_quads)
    with_centre = (k + 1) * n_centres // n_quads - k * n_centres // n_quads == 1
    xs, ys = np.meshgrid(np.linspace(0.0, length, p), np.linspace(0.0, height, q), indexing="xy")
    grid_pos = np.stack([xs.ravel(), ys.ravel()], axis=1)
    centre_quads = quads[with_centre]
    centre_pos = grid_pos[centre_quads].mean(axis=1)
    c = p * q + np.arange(centre_quads.shape[0])
    a, b, cc, d = centre_quads.T
    fans = np.stack([np.stack([a, b, c], 1), np.stack([b, cc, c], 1), np.stack([cc, d, c], 1), np.stack([d, a, c], 1)], 1)
    plain = quads[~with_centre]
    pi = k[~with_centre]
    alternate = ((pi % (p - 1)) + (pi // (p - 1))) % 2 == 1
    cells = np.concatenate([_split_quads(plain, alternate), fans.reshape(-1, 3)], axis=0)
    mesh = _flag_from_grid(np.concatenate([grid_pos, centre_pos], axis=0), cells)
    if mesh.num_nodes != FLAGSIMPLE_NODES or mesh.num_faces != FLAGSIMPLE_FACES:  # pragma: no cover
        raise ClodsError(f"built {mesh.num_nodes} nodes / {mesh.num_faces} faces", where="make_flagsimple_mesh")
    return mesh


def make_cylinder_mesh(n_around: int, n_along: int, radius: float, height: float) -> ClothMesh:
    """An open tube of cloth (axis along world z, z in [0, height]) with the top ring pinned.

    Node (i, j) has index i + n_around*j at angle 2*pi*i/n_around and height j*dz. The tube is
    closed around, so no node is duplicated at the seam. `mesh_pos` is the unrolled rest
    position (arc length, height); `uv` is (i/n_around, j/(n_along-1)), u in [0, 1).

    UV seam: the column of faces between i = n_around-1 and i = 0 spans u from (n-1)/n back to
    0, so it interpolates the whole texture backwards (a one-column artefact), and its mesh_pos
    jumps by the circumference in the same way. Renderers that want a clean seam should use a
    texture that tiles in u and add 1 to the u of the i = 0 corners of faces whose u-span
    exceeds 0.5. The cloth solver takes its rest metric from `rest_pos`, so it is unaffected.
    """
    _check_count(n_around, 3, "n_around", "make_cylinder_mesh")
    _check_count(n_along, 2, "n_along", "make_cylinder_mesh")
    if not (radius > 0 and height > 0):
        raise ClodsError(f"radius and height must be positive, got {radius}, {height}", where="make_cylinder_mesh")
    i, j = np.meshgrid(np.arange(n_around), np.arange(n_along), indexing="xy")
    i, j = i.ravel(), j.ravel()
    theta = 2.0 * math.pi * i / n_around
    z = height * j / (n_along - 1)
    rest = np.stack([radius * np.cos(theta), radius * np.sin(theta), z], axis=1)
    mesh_pos = np.stack([radius * theta, z], axis=1).astype(np.float32)
    uv = np.stack([i / n_around, j / (n_along - 1)], axis=1).astype(np.float32)
    qi, qj = np.meshgrid(np.arange(n_around), np.arange(n_along - 1), indexing="xy")
    qi, qj = qi.ravel(), qj.ravel()
    n00 = qi + n_around * qj
    n10 = (qi + 1) % n_around + n_around * qj
    quads = np.stack([n00, n10, n10 + n_around, n00 + n_around], axis=1)
    cells = _split_quads(quads, (qi + qj) % 2 == 1)
    node_type = np.where(j == n_along - 1, HANDLE, NORMAL).astype(np.int32)
    mesh = ClothMesh(cells.astype(np.int32), mesh_pos, node_type, rest, uv=uv)
    mesh.validate("cylinder mesh")
    return mesh
