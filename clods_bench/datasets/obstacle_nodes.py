"""Obstacles stored in a trajectory as FLAGSIMPLE-style OBSTACLE nodes, and the cloth part taken back out.

A scene's rigid obstacles are written into each trajectory as extra nodes after the cloth's
(node_type OBSTACLE, positions per frame from the obstacle's surface mesh at that frame's time)
and extra triangles after the cloth's, as MeshGraphNets stores its obstacles: a learned simulator
then sees them as kinematic nodes (their positions are given for every frame, like the handles)
and can build world edges to them. Obstacle nodes have no material coordinates; their `mesh_pos`
is the cloth's lowest corner, so mesh-space edge features stay in the cloth's range.

Everything that scores the cloth (RMSE, edge strain, energy) scores the cloth nodes only
(`cloth_node_mask`, `split_cloth`); the ground-truth renderer draws obstacle triangles in a flat
colour (`face_colors`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from clods_bench.datasets.types import OBSTACLE, Trajectory
from clods_bench.errors import ClodsError

OBSTACLE_COLOR = (0.55, 0.57, 0.62)
"""The flat colour the ground-truth renderer paints obstacles with (a neutral grey-blue)."""


def obstacle_frames(obstacles: Sequence[object], times: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Surface vertices (T,M,3) float32 at each time and faces (F,3) int32 of all obstacles, numbered from 0."""
    verts: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    offset = 0
    for k, obstacle in enumerate(obstacles):
        per_time = []
        f0 = None
        for t in times:
            v, f = obstacle.surface(float(t))  # type: ignore[attr-defined]
            v, f = np.asarray(v, np.float64), np.asarray(f, np.int64)
            if f0 is None:
                f0 = f
            elif v.shape != per_time[0].shape or not np.array_equal(f, f0):
                raise ClodsError("surface() changed its topology over time", where=f"obstacles[{k}]")
            per_time.append(v)
        assert f0 is not None
        verts.append(np.stack(per_time))
        faces.append(f0 + offset)
        offset += per_time[0].shape[0]
    if not verts:
        return np.zeros((len(times), 0, 3), np.float32), np.zeros((0, 3), np.int32)
    return np.concatenate(verts, axis=1).astype(np.float32), np.concatenate(faces).astype(np.int32)


def append_obstacles(traj: Trajectory, obstacles: Sequence[object], times: Sequence[float]) -> Trajectory:
    """`traj` (cloth only) with the obstacles' surfaces at `times` (one per frame) appended as OBSTACLE nodes and faces."""
    if not obstacles:
        return traj
    if len(times) != traj.num_steps:
        raise ClodsError(f"{len(times)} times for {traj.num_steps} frames", where="append_obstacles")
    verts, faces = obstacle_frames(obstacles, times)
    n = traj.num_nodes
    m = verts.shape[1]
    corner = np.asarray(traj.mesh_pos, np.float32).min(axis=0)
    return Trajectory(
        np.concatenate([np.asarray(traj.cells, np.int32), faces + n]),
        np.concatenate([np.asarray(traj.mesh_pos, np.float32), np.tile(corner, (m, 1))]),
        np.concatenate([np.asarray(traj.node_type, np.int32), np.full(m, OBSTACLE, np.int32)]),
        np.concatenate([np.asarray(traj.world_pos, np.float32), verts], axis=1),
        traj.dt,
        {**traj.meta, "obstacle_nodes": int(m), "obstacle_faces": int(faces.shape[0])},
    )


def cloth_node_mask(node_type: np.ndarray) -> np.ndarray:
    """(V,) bool: the cloth's nodes (NORMAL and HANDLE), not the obstacles'."""
    return np.asarray(node_type) != OBSTACLE


def cloth_nodes(node_type: np.ndarray) -> np.ndarray | None:
    """Indices of the cloth's nodes, or None when every node is cloth (no obstacle: score all nodes)."""
    mask = cloth_node_mask(node_type)
    return None if mask.all() else np.flatnonzero(mask)


@dataclass(frozen=True)
class ClothPart:
    """The cloth of a trajectory or rollout input without its obstacles, and where each part sits in the full node list."""

    cells: np.ndarray
    """(Fc,3) int32 cloth triangles, renumbered over the cloth nodes."""
    mesh_pos: np.ndarray
    """(Vc,2) the cloth nodes' material coordinates."""
    node_type: np.ndarray
    """(Vc,) the cloth nodes' types."""
    nodes: np.ndarray
    """(Vc,) indices of the cloth nodes in the full node list."""
    obstacle_nodes: np.ndarray
    """(Vo,) indices of the obstacle nodes in the full node list."""
    obstacle_faces: np.ndarray
    """(Fo,3) int32 obstacle triangles, numbered over the obstacle nodes (0..Vo-1)."""


def split_cloth(cells: np.ndarray, mesh_pos: np.ndarray, node_type: np.ndarray) -> ClothPart:
    """Split a mesh into its cloth and its obstacles (a triangle is the obstacle's when all its corners are)."""
    cells = np.asarray(cells, np.int64)
    cloth = cloth_node_mask(node_type)
    nodes, obst = np.flatnonzero(cloth), np.flatnonzero(~cloth)
    is_obstacle_face = ~cloth[cells].any(axis=1)
    mixed = ~cloth[cells].all(axis=1) & ~is_obstacle_face
    if mixed.any():
        raise ClodsError(f"{int(mixed.sum())} triangles join cloth and obstacle nodes", where="split_cloth.cells")
    renumber = np.full(len(cloth), -1, np.int64)
    renumber[nodes] = np.arange(nodes.size)
    renumber[obst] = np.arange(obst.size)
    return ClothPart(
        renumber[cells[~is_obstacle_face]].astype(np.int32),
        np.asarray(mesh_pos)[nodes],
        np.asarray(node_type)[nodes],
        nodes,
        obst,
        renumber[cells[is_obstacle_face]].astype(np.int32),
    )


def face_colors(cells: np.ndarray, node_type: np.ndarray) -> np.ndarray | None:
    """(F,3) flat colours for the ground-truth renderer: OBSTACLE_COLOR on obstacle faces, NaN (textured) on the cloth's; None without obstacles."""
    obstacle = ~cloth_node_mask(node_type)
    if not obstacle.any():
        return None
    faces = obstacle[np.asarray(cells, np.int64)].all(axis=1)
    out = np.full((len(faces), 3), np.nan)
    out[faces] = OBSTACLE_COLOR
    return out


def render_uv(uv: np.ndarray, num_nodes: int) -> np.ndarray:
    """Texture coordinates for every node of a trajectory: the cloth's `uv` (Vc,2) then zeros for obstacle nodes."""
    uv = np.asarray(uv, np.float32)
    if uv.shape[0] > num_nodes:
        raise ClodsError(f"{uv.shape[0]} uv rows for {num_nodes} nodes", where="render_uv")
    return np.concatenate([uv, np.zeros((num_nodes - uv.shape[0], 2), np.float32)])
