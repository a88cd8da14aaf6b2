"""Obstacles as OBSTACLE nodes of a trajectory: appended after the cloth, split back out, coloured for the renderer."""

from __future__ import annotations

import numpy as np
import pytest

from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.obstacle_nodes import (
    OBSTACLE_COLOR,
    append_obstacles,
    cloth_node_mask,
    cloth_nodes,
    face_colors,
    render_uv,
    split_cloth,
)
from clods_bench.datasets.obstacles import Box, ObstaclePath, Sphere
from clods_bench.datasets.types import HANDLE, NORMAL, OBSTACLE, Trajectory
from clods_bench.errors import ClodsError


def cloth_traj(frames: int = 4) -> Trajectory:
    mesh = make_flag_mesh(4, 3)
    world = np.stack([mesh.rest_pos + [0.0, 0.1 * t, 0.0] for t in range(frames)]).astype(np.float32)
    return Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, world, 0.02, {"scene": "test"})


def test_obstacles_are_appended_after_the_cloth_with_their_surface_at_each_frame_time():
    traj = cloth_traj()
    path = ObstaclePath(times=(0.0, 1.0), offsets=((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)))
    ball, box = Sphere(center=(0.0, 2.0, 0.0), radius=0.3, path=path), Box(center=(3.0, 0.0, 0.0), half_extents=(0.1, 0.2, 0.3))
    times = [0.5 + 0.02 * k for k in range(traj.num_steps)]
    out = append_obstacles(traj, [ball, box], times)
    n = traj.num_nodes
    (vb, fb), (vx, fx) = ball.surface(times[0]), box.surface(times[0])
    assert out.num_nodes == n + len(vb) + len(vx) and out.cells.shape[0] == traj.cells.shape[0] + len(fb) + len(fx)
    np.testing.assert_array_equal(out.node_type[:n], traj.node_type)
    assert (out.node_type[n:] == OBSTACLE).all()
    np.testing.assert_array_equal(out.world_pos[:, :n], traj.world_pos)
    for k, t in enumerate(times):
        np.testing.assert_allclose(out.world_pos[k, n : n + len(vb)], ball.surface(t)[0], atol=1e-6)
        np.testing.assert_allclose(out.world_pos[k, n + len(vb) :], box.surface(t)[0], atol=1e-6)
    np.testing.assert_array_equal(out.cells[traj.cells.shape[0] :][: len(fb)], fb + n)
    assert out.meta["obstacle_nodes"] == len(vb) + len(vx) and out.meta["scene"] == "test"
    out.validate()
    # the ball moved along its path between the frames (0.02 s apart, path speed ~1 m/s mid-way): not a static copy
    assert np.abs(out.world_pos[-1, n] - out.world_pos[0, n]).max() > 1e-3
    assert append_obstacles(traj, [], times) is traj


def test_split_cloth_recovers_the_cloth_and_the_obstacle_surfaces():
    traj = cloth_traj()
    ball = Sphere(center=(0.0, 2.0, 0.0), radius=0.3)
    out = append_obstacles(traj, [ball], [0.0] * traj.num_steps)
    part = split_cloth(out.cells, out.mesh_pos, out.node_type)
    np.testing.assert_array_equal(part.cells, traj.cells)
    np.testing.assert_array_equal(part.mesh_pos, traj.mesh_pos)
    np.testing.assert_array_equal(part.node_type, traj.node_type)
    np.testing.assert_array_equal(part.nodes, np.arange(traj.num_nodes))
    np.testing.assert_array_equal(part.obstacle_faces, ball.surface(0.0)[1])
    np.testing.assert_array_equal(cloth_nodes(out.node_type), np.arange(traj.num_nodes))
    assert cloth_nodes(traj.node_type) is None and cloth_node_mask(out.node_type).sum() == traj.num_nodes
    assert set(np.unique(out.node_type[part.nodes])) <= {NORMAL, HANDLE}


def test_a_triangle_joining_cloth_and_obstacle_is_an_error():
    traj = cloth_traj()
    out = append_obstacles(traj, [Sphere(center=(0.0, 2.0, 0.0), radius=0.3)], [0.0] * traj.num_steps)
    cells = out.cells.copy()
    cells[0, 0] = out.num_nodes - 1
    with pytest.raises(ClodsError, match="join cloth and obstacle"):
        split_cloth(cells, out.mesh_pos, out.node_type)


def test_face_colours_and_uvs_for_the_ground_truth_renderer():
    traj = cloth_traj()
    out = append_obstacles(traj, [Sphere(center=(0.0, 2.0, 0.0), radius=0.3)], [0.0] * traj.num_steps)
    colors = face_colors(out.cells, out.node_type)
    f = traj.cells.shape[0]
    assert np.isnan(colors[:f]).all() and np.allclose(colors[f:], OBSTACLE_COLOR)
    assert face_colors(traj.cells, traj.node_type) is None
    uv = np.random.default_rng(0).random((traj.num_nodes, 2))
    full = render_uv(uv, out.num_nodes)
    np.testing.assert_allclose(full[: traj.num_nodes], uv, atol=1e-7)
    assert full.shape == (out.num_nodes, 2) and (full[traj.num_nodes :] == 0).all()
