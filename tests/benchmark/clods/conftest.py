"""A small textured mesh scene for stage-2 tests: a fitted-looking GaMeS renderer and its cameras."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.datasets.types import HANDLE, NORMAL
from clods_bench.plugins.renderers.games import GamesConfig, GamesRenderer


def grid(nx: int = 5, ny: int = 3, size: tuple[float, float] = (1.0, 0.6)) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A gently waved grid in the x-z plane: verts (V,3), cells (F,3), mesh_pos (V,2), node_type (V,) with the top row pinned."""
    xs, zs = np.linspace(0, size[0], nx + 1), np.linspace(0, size[1], ny + 1)
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    mesh_pos = np.stack([X.ravel(), Z.ravel()], 1).astype(np.float32)
    verts = np.stack([X.ravel() - size[0] / 2, 0.08 * np.sin(3.0 * X.ravel() + 1.0) * Z.ravel(), Z.ravel() - size[1] / 2], 1)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    cells = []
    for i in range(nx):
        for j in range(ny):
            a, b, c, d = idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]
            cells += [[a, b, c], [a, c, d]]
    node_type = np.where(np.isclose(Z.ravel(), size[1]), HANDLE, NORMAL).astype(np.int32)
    return verts.astype(np.float32), np.asarray(cells, dtype=np.int32), mesh_pos, node_type


def cameras(n: int = 3, size: int = 32) -> list[Camera]:
    """n cameras around the origin, looking at it."""
    return camera_rig(n, np.zeros(3), 1.8, size, size, fov_deg=40.0, phase_deg=60.0)


def textured_renderer(verts: np.ndarray, cells: np.ndarray, mesh_pos: np.ndarray, cams: list[Camera]) -> GamesRenderer:
    """GaMeS on the mesh with random colours and high opacities (a textured cloth, so pixels constrain vertices)."""
    r = GamesRenderer(GamesConfig(gaussians_per_face=4, iterations=0, init_scale_factor=1.5), seed=0)
    r.fit(verts[None], cells, mesh_pos, np.ones((1, len(cams), cams[0].height, cams[0].width, 3), np.float32), cams)
    g = torch.Generator().manual_seed(3)
    r.params["color"].copy_(torch.rand(r.params["color"].shape, generator=g))
    r.params["opacity_logit"].fill_(3.0)
    return r


def smooth_deformation(verts: np.ndarray, node_type: np.ndarray, amplitude: float = 0.03) -> np.ndarray:
    """A smooth, small displacement of the free nodes (handles stay): a bend out of plane plus a sideways drift."""
    x, z = verts[:, 0], verts[:, 2]
    d = np.stack([0.3 * amplitude * np.cos(2.0 * z), amplitude * np.sin(2.5 * x + 0.5) * (0.3 - z), 0.3 * amplitude * np.sin(3.0 * x)], 1)
    d[node_type != NORMAL] = 0.0
    return (verts + d).astype(np.float32)


@pytest.fixture(scope="module")
def scene() -> dict:
    """Mesh, cameras and a textured renderer shared by a test module."""
    verts, cells, mesh_pos, node_type = grid()
    cams = cameras()
    return {"verts": verts, "cells": cells, "mesh_pos": mesh_pos, "node_type": node_type, "cams": cams,
            "renderer": textured_renderer(verts, cells, mesh_pos, cams)}  # fmt: skip
