"""Small meshes and cameras shared by the renderer tests."""

from __future__ import annotations

import numpy as np
import pytest

from clods_bench.datasets.cameras import Camera, camera_rig


def grid_mesh(nx: int = 3, ny: int = 2, size: tuple[float, float] = (1.0, 0.6), wave: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A gently waved (nx+1)x(ny+1) grid in the x-z plane: verts (V,3) float64, cells (F,3), mesh_pos (V,2)."""
    xs, zs = np.linspace(0, size[0], nx + 1), np.linspace(0, size[1], ny + 1)
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    mesh_pos = np.stack([X.ravel(), Z.ravel()], 1)
    verts = np.stack([X.ravel() - size[0] / 2, wave * np.sin(3.0 * X.ravel() + 1.0) * Z.ravel(), Z.ravel() - size[1] / 2], 1)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    cells = []
    for i in range(nx):
        for j in range(ny):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            cells += [[a, b, c], [a, c, d]]
    return verts, np.asarray(cells, dtype=np.int32), mesh_pos


def rig(n: int = 2, size: int = 16, radius: float = 2.5) -> list[Camera]:
    """n cameras of size x size pixels around the origin, looking at it."""
    return camera_rig(n, np.zeros(3), radius, size, size, fov_deg=40.0, phase_deg=90.0)


@pytest.fixture
def mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 4x3-node waved grid (12 nodes, 12 faces)."""
    return grid_mesh()
