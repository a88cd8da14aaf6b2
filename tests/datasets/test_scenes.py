"""Named scenes: the registry, meshes, reproducible trajectories and stability of the extreme ones."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clods_bench.datasets.scenes import BUILTIN_SCENES, get_scene, simulate_scene
from clods_bench.datasets.solver_bench import bench_solver
from clods_bench.datasets.types import HANDLE, edges_from_cells
from clods_bench.errors import ClodsError


def max_strain(mesh, frames: np.ndarray) -> float:
    e = edges_from_cells(mesh.cells)
    rest = np.linalg.norm(mesh.rest_pos[e[:, 0]] - mesh.rest_pos[e[:, 1]], axis=1)
    now = np.linalg.norm(frames[:, e[:, 0]].astype(np.float64) - frames[:, e[:, 1]], axis=2)
    return float(np.abs(now / rest - 1.0).max())


def test_builtin_scene_set():
    names = [s.name for s in BUILTIN_SCENES]
    assert names == ["flag", "flag-stiff", "flag-storm", "flag-large-dt", "flag-lit", "cylinder", "sphere-drop", "flag-ball"]
    flag, stiff, storm, large_dt, lit, cyl, drop, ball = BUILTIN_SCENES
    assert stiff.params.youngs_modulus >= 50 * flag.params.youngs_modulus
    assert stiff.params.bending_stiffness >= 50 * flag.params.bending_stiffness
    assert storm.wind_speed_range[0] > flag.wind_speed_range[1]
    assert large_dt.dt >= 0.04 and flag.dt == 0.02
    assert cyl.kind == "cylinder" and all(s.kind == "flag" for s in BUILTIN_SCENES[:5])
    assert lit.params == flag.params and lit.has_lighting and lit.light is not None and lit.light.has_shadows
    assert drop.has_obstacles and ball.has_obstacles and not drop.has_handles and not drop.has_wind and drop.kind == "sheet"
    assert ball.kind == "flag" and ball.params == flag.params and ball.obstacles[0].path is not None
    for s in BUILTIN_SCENES:
        assert s.has_handles == (s is not drop) and s.has_wind == (s is not drop)
        assert s.has_obstacles == (s in (drop, ball)) and s.has_lighting == (s is lit)
        assert "\n" not in s.description and s.description
        s.params.validate(s.name)


def test_unknown_scene_suggests_a_name():
    with pytest.raises(ClodsError, match="did you mean 'flag-storm'"):
        get_scene("flag-strom")


def test_build_mesh_resolutions():
    flag, cyl = get_scene("flag"), get_scene("cylinder")
    assert (flag.build_mesh("flagsimple").num_nodes, flag.build_mesh().num_faces) == (1579, 3028)
    assert flag.build_mesh((5, 3)).num_nodes == 15
    tube = cyl.build_mesh((10, 4))
    assert tube.num_nodes == 40 and np.sum(tube.node_type == HANDLE) == 10
    with pytest.raises(ClodsError, match="resolution"):
        flag.build_mesh("huge")


@pytest.mark.parametrize("name", ["flag", "cylinder"])
def test_simulate_scene_is_reproducible(name):
    scene = get_scene(name)
    mesh = scene.build_mesh((9, 5) if name == "flag" else (10, 5))
    a = simulate_scene(scene, mesh, 12, seed=3)
    b = simulate_scene(scene, mesh, 12, seed=3)
    c = simulate_scene(scene, mesh, 12, seed=4)
    assert a.world_pos.shape == (12, mesh.num_nodes, 3) and a.world_pos.dtype == np.float32
    assert a.dt == scene.dt
    np.testing.assert_array_equal(a.world_pos, b.world_pos)
    assert not np.allclose(a.world_pos, c.world_pos)
    meta = json.loads(json.dumps(a.meta))  # JSON-serialisable as is
    assert meta["scene"] == name and meta["seed"] == 3 and len(meta["wind_velocity"]) == 3
    lo, hi = scene.wind_speed_range
    assert lo <= np.linalg.norm(meta["wind_velocity"]) <= hi
    handles = mesh.node_type == HANDLE
    # handles start at the rest pose rotated about the vertical axis and never move
    np.testing.assert_allclose(np.linalg.norm(a.world_pos[0, handles, :2], axis=1), np.linalg.norm(mesh.rest_pos[handles, :2], axis=1), atol=1e-6)
    np.testing.assert_array_equal(a.world_pos[:, handles], np.broadcast_to(a.world_pos[0, handles], a.world_pos[:, handles].shape))


@pytest.mark.parametrize("name, bound", [("flag-stiff", 0.02), ("flag-storm", 0.6), ("flag-large-dt", 0.3), ("flag", 0.1)])
def test_scenes_stay_bounded_for_400_steps(name, bound):
    """400 steps on a 13 x 7 flag: finite, and the largest edge strain stays below `bound`."""
    scene = get_scene(name)
    mesh = scene.build_mesh((13, 7))
    traj = simulate_scene(scene, mesh, 401, seed=0)
    assert np.isfinite(traj.world_pos).all()
    assert max_strain(mesh, traj.world_pos) < bound
    moved = np.linalg.norm(traj.world_pos[-1] - traj.world_pos[0], axis=1).max()
    assert moved > 0.05  # the wind actually moves the cloth


def test_bench_solver_reports_timings():
    out = bench_solver(num_steps=3, resolution=(6, 4))
    assert out["num_steps"] == 3 and out["finite"]
    assert out["total_seconds"] > 0 and out["seconds_per_step"] == pytest.approx(out["total_seconds"] / 3)
    assert out["steps_per_second"] == pytest.approx(3 / out["total_seconds"])
