"""A proxy geometry for frames without meshes: the bounding box of the foreground's visual hull, as a 12-triangle mesh.

Per-frame renderers (3DGS) only need a region to initialise their Gaussians in; on a dataset imported without
meshes the NVS task gives them this box instead of the ground-truth mesh. Foreground = pixels whose colour differs
from the white background; the hull = grid points inside every camera's foreground where that camera sees them
(and seen by at least one camera), carved in a cube around the point nearest to every camera's optical axis.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError

BOX_CELLS = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                      [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int32)  # fmt: skip
"""Outward-facing triangles of the box whose corner k has coordinates (lo or hi per bit k&1, k&2, k&4)."""


def foreground(images: np.ndarray, threshold: int = 16) -> np.ndarray:
    """(N,H,W) bool: pixels where some channel differs from white (255) by more than `threshold` (uint8 or [0,1] input)."""
    arr = np.asarray(images)
    if arr.dtype != np.uint8:
        arr = np.clip(np.rint(arr * 255.0), 0, 255).astype(np.uint8)
    return (255 - arr.astype(np.int16)).max(axis=-1) > threshold


def axes_meeting_point(cameras: Sequence[Camera]) -> np.ndarray:
    """The point nearest (least squares) to every camera's optical axis; the centres' mean if the axes are parallel."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for cam in cameras:
        d = np.asarray(cam.R, float)[2]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.center
    if np.linalg.cond(A) > 1e8:
        return np.mean([c.center + c.R[2] for c in cameras], axis=0)
    return np.linalg.solve(A, b)


def hull_box(images: np.ndarray, cameras: Sequence[Camera], resolution: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) corners of the foreground's visual-hull bounding box, padded by one grid cell; ClodsError if empty."""
    masks = foreground(images)
    centre = axes_meeting_point(cameras)
    half = max(np.linalg.norm(c.center - centre) * max(c.width / 2 / c.K[0, 0], c.height / 2 / c.K[1, 1]) for c in cameras)
    axis = np.linspace(-half, half, resolution)
    pts = centre + np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    keep = np.ones(len(pts), bool)
    seen = np.zeros(len(pts), bool)
    for cam, mask in zip(cameras, masks):
        uv, z = cam.project(pts)
        u, v = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
        inside = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        fg = np.zeros(len(pts), bool)
        fg[inside] = mask[v[inside], u[inside]]
        keep &= fg | ~inside
        seen |= inside
    keep &= seen
    if not keep.any():
        raise ClodsError("no foreground in the views' common field of view: cannot place a proxy geometry", where="visual hull",
                         hint="the cloth must be visible (not white) in the fitting cameras")  # fmt: skip
    step = axis[1] - axis[0]
    return pts[keep].min(axis=0) - step, pts[keep].max(axis=0) + step


def box_mesh(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(verts (8,3) float32, cells (12,3) int32, mesh_pos (8,2) float32) of the axis-aligned box [lo, hi]."""
    corners = np.array([[(hi if k & bit else lo)[i] for i, bit in enumerate((1, 2, 4))] for k in range(8)], np.float32)
    return corners, BOX_CELLS.copy(), corners[:, :2].copy()
