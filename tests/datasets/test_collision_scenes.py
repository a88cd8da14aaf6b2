"""The collision scenes end to end: contact in the data, obstacles stored and drawn, world edges only where needed."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.descriptors import BuildContext
from clods_bench.benchmark.core.interfaces import RolloutInput
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.scoring.monitors import cloth_monitor
from clods_bench.datasets.cameras import camera_rig
from clods_bench.datasets.generate import render_steps, scene_fingerprint
from clods_bench.datasets.obstacle_nodes import OBSTACLE_COLOR, split_cloth
from clods_bench.datasets.obstacles import Sphere, TriangleMeshObstacle
from clods_bench.datasets.rasterizer import RasterSettings
from clods_bench.datasets.scenes import get_scene, simulate_scene
from clods_bench.datasets.types import OBSTACLE
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.graph import GraphSpec, build_features, build_topology
from clods_bench.plugins.simulators.physics import PhysicsConfig, PhysicsSimulator

DROP, BALL = get_scene("sphere-drop"), get_scene("flag-ball")


@pytest.fixture(scope="module")
def drop_traj():
    """The sheet dropped on the sphere: 8 x 4 nodes, 41 frames (0.8 s: falls 0.2 m in 0.2 s, then drapes)."""
    return simulate_scene(DROP, DROP.build_mesh((8, 4)), 41, seed=1)


def _clearance(traj, sphere: Sphere) -> np.ndarray:
    """(T,) smallest distance of a cloth node to the sphere's surface (negative: inside)."""
    cloth = traj.node_type != OBSTACLE
    return np.linalg.norm(traj.world_pos[:, cloth] - np.array(sphere.center), axis=2).min(axis=1) - sphere.radius


def test_dropped_sheet_lands_on_the_sphere_and_never_goes_inside(drop_traj):
    sphere = DROP.obstacles[0]
    gap = _clearance(drop_traj, sphere)
    thickness = DROP.params.contact_thickness
    assert gap[0] > 0.15  # starts 0.2 m above the top
    assert gap.min() > -0.5 * thickness  # no node inside beyond half the collision thickness
    assert gap[-1] < 2 * thickness  # and it did come to rest on it
    assert drop_traj.meta["contacts_per_step"] > 0
    # the sheet drapes: its corners end well below the sphere's top, held up in the middle (strain stays small)
    cloth = drop_traj.world_pos[-1, drop_traj.node_type != OBSTACLE]
    assert cloth[:, 2].min() < sphere.radius - 0.1
    monitor = cloth_monitor(DROP, drop_traj.cells, drop_traj.mesh_pos, drop_traj.node_type, 0.1, drop_traj.dt)
    assert monitor.max_strain(drop_traj.world_pos).max() < 0.05


def test_the_obstacle_is_stored_as_obstacle_nodes_of_its_surface(drop_traj):
    sphere = DROP.obstacles[0]
    verts, faces = sphere.surface(0.0)
    part = split_cloth(drop_traj.cells, drop_traj.mesh_pos, drop_traj.node_type)
    assert part.obstacle_nodes.size == len(verts) and np.array_equal(part.obstacle_faces, faces)
    np.testing.assert_allclose(drop_traj.world_pos[:, part.obstacle_nodes], np.broadcast_to(verts, (41, *verts.shape)), atol=1e-6)


def test_the_ball_sweeps_through_the_flag_and_pushes_it():
    traj = simulate_scene(BALL, BALL.build_mesh((8, 4)), 41, seed=0)
    ball = BALL.obstacles[0]
    part = split_cloth(traj.cells, traj.mesh_pos, traj.node_type)
    centre = traj.world_pos[:, part.obstacle_nodes].mean(axis=1)
    assert centre[-1, 1] - centre[0, 1] > 0.5  # the recorded ball moved towards the flag
    for t in (0, 20, 40):
        np.testing.assert_allclose(centre[t], np.array(ball.center) + ball.path.offset(1.0 + 0.02 * t), atol=2e-3)
    dist = np.linalg.norm(traj.world_pos[:, part.nodes] - centre[:, None], axis=2).min(axis=1) - ball.radius
    assert dist.min() > -0.5 * BALL.params.contact_thickness - 0.01  # the icosphere's facets lie up to 1 cm inside r
    assert traj.meta["contacts_per_step"] > 0


def test_ground_truth_frames_draw_the_obstacle(drop_traj):
    mesh = DROP.build_mesh((8, 4))
    cams = camera_rig(2, np.array([0.0, 0.0, 0.2]), 2.0, 32, 32, 45.0)
    texture = np.zeros((4, 4, 3), np.float32)  # a black cloth: anything grey-blue is the sphere
    frames = next(render_steps(drop_traj, mesh.texture_uv(), texture, cams, RasterSettings(supersample=1), times=[0]))
    target = np.rint(np.array(OBSTACLE_COLOR) * 255)
    hits = np.all(np.abs(frames.astype(float) - target) <= 1, axis=-1)
    assert hits.sum(axis=(1, 2)).min() > 20  # every view sees the sphere below the sheet


def test_world_edges_exist_only_when_the_scene_has_obstacles(drop_traj):
    assert GraphSpec.for_scene(DROP, 0.05).world_edges and not GraphSpec.for_scene(get_scene("flag"), 0.05).world_edges
    spec = GraphSpec.for_scene(DROP, 0.05)
    topo = build_topology(drop_traj.cells, drop_traj.mesh_pos, drop_traj.node_type)
    import torch

    pos = torch.as_tensor(drop_traj.world_pos[-1], dtype=torch.float32)
    _, sets = build_features(topo, pos, pos, spec)
    w = sets["world"]
    obstacle = drop_traj.node_type == OBSTACLE
    assert w.senders.numel() > 0  # the sheet rests on the sphere: contact edges
    assert np.all(obstacle[w.senders.numpy()] != obstacle[w.receivers.numpy()])  # each joins cloth and obstacle
    assert torch.all(w.features[:, 3] < 0.05)
    flag = simulate_scene(get_scene("flag"), get_scene("flag").build_mesh((6, 4)), 3, seed=0)
    ftopo = build_topology(flag.cells, flag.mesh_pos, flag.node_type)
    fpos = torch.as_tensor(flag.world_pos[-1])
    _, fsets = build_features(ftopo, fpos, fpos, GraphSpec.for_scene(get_scene("flag"), 0.05))
    assert set(fsets) == {"mesh"}


@pytest.mark.parametrize("sim", ["mgn", "hcmt"])
def test_learned_simulators_build_contact_parts_only_for_obstacle_scenes(sim, tmp_path: Path):
    spec = default_registry().get("simulator", sim)
    cfg = spec.make_config({}, where=f"sim_config.{sim}")
    with_obstacles = spec.build(cfg, BuildContext(scene=DROP, seed=0, work_dir=tmp_path))
    without = spec.build(cfg, BuildContext(scene=get_scene("flag"), seed=0, work_dir=tmp_path))
    names = [n for n, _ in with_obstacles.build_model(0).named_parameters()]
    assert any("world" in n for n in names)
    assert not any("world" in n for n, _ in without.build_model(0).named_parameters())


def test_physics_baseline_collides_with_the_recorded_obstacle():
    """The windless sphere-drop with one solver step per frame (then (x1 - x0)/dt is exactly the solver's velocity).
    Data made with the sphere's own triangle mesh as the obstacle: the physics baseline, colliding with the recorded
    OBSTACLE nodes, reproduces it to float32 rounding. Data made with the exact sphere: identical until the sheet lands
    (frame ~10), then the facets (up to 4 mm inside the sphere) make it drift by at most a few cm over 0.8 s."""
    exact = dataclasses.replace(DROP, substeps=1)
    faceted = dataclasses.replace(exact, obstacles=(TriangleMeshObstacle(*exact.obstacles[0].surface(0.0)),))
    for scene, early, tol in ((faceted, 1e-5, 1e-4), (exact, 1e-5, 0.03)):
        truth = simulate_scene(scene, scene.build_mesh((8, 4)), 41, seed=1)
        pred = PhysicsSimulator(scene, PhysicsConfig()).rollout(RolloutInput.from_trajectory(truth))
        cloth = truth.node_type != OBSTACLE
        err = np.sqrt(np.mean((pred[:, cloth] - truth.world_pos[:, cloth]) ** 2, axis=(1, 2)))
        assert err[:8].max() < early and err.max() < tol, (scene.obstacles[0], err.max())
        np.testing.assert_array_equal(pred[:, ~cloth], truth.world_pos[:, ~cloth])
    drop_traj = truth
    still = PhysicsSimulator(dataclasses.replace(DROP, obstacles=(), has_obstacles=False), PhysicsConfig())
    free = still.rollout(RolloutInput.from_trajectory(split_cloth_traj(drop_traj)))
    assert free[-1, :, 2].max() < -1.0 < pred[-1, cloth, 2].min()  # without the obstacle it falls freely (to z ~ -2.7 m)


def split_cloth_traj(traj):
    part = split_cloth(traj.cells, traj.mesh_pos, traj.node_type)
    return dataclasses.replace(traj, cells=part.cells, mesh_pos=part.mesh_pos, node_type=part.node_type, world_pos=traj.world_pos[:, part.nodes])


def test_bad_collision_scenes_are_one_clear_error():
    with pytest.raises(ClodsError, match=r"scene bad.*has_obstacles is False but the scene has 1 obstacles"):
        dataclasses.replace(DROP, name="bad", has_obstacles=False)
    with pytest.raises(ClodsError, match=r"scene bad.*has_obstacles is True but the scene has 0"):
        dataclasses.replace(DROP, name="bad", obstacles=())
    with pytest.raises(ClodsError, match=r"scene bad\.obstacles\[0\].*expected a clods_bench.datasets.obstacles.Obstacle"):
        dataclasses.replace(DROP, name="bad", obstacles=("sphere",))
    inside = dataclasses.replace(DROP, name="bad", obstacles=(Sphere(center=(0.0, 0.0, 0.45), radius=0.2),))
    with pytest.raises(ClodsError, match=r"scene bad\.obstacles\[0\].*rest shape has \d+ nodes inside obstacle Sphere"):
        inside.build_mesh((8, 4))
    near = dataclasses.replace(DROP, name="bad", obstacles=(Sphere(center=(0.0, 0.0, 0.0), radius=0.42),), perturb_amplitude=0.2)
    mesh = DROP.build_mesh((8, 4))
    with pytest.raises(ClodsError, match=r"scene bad\.obstacles\[0\].*initial pose \(seed \d+\)"):
        for seed in range(20):  # some seed bends the sheet into the sphere
            simulate_scene(near, mesh, 3, seed=seed)


def test_obstacle_scenes_have_their_own_fingerprints_and_old_scenes_keep_theirs():
    moved = dataclasses.replace(DROP, obstacles=(Sphere(center=(0.0, 0.0, 0.01), radius=0.25),))
    assert scene_fingerprint(moved) != scene_fingerprint(DROP)
    stiffer = dataclasses.replace(DROP, params=dataclasses.replace(DROP.params, contact_stiffness=2e5))
    assert scene_fingerprint(stiffer) != scene_fingerprint(DROP)
    assert scene_fingerprint(get_scene("flag")) == "60b8812c6740f168"
