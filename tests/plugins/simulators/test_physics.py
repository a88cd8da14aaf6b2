"""The physics simulator against the ground-truth solver: exact on a windless scene, coarser steps worse."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from clods_bench.benchmark.core.descriptors import BuildContext
from clods_bench.benchmark.core.interfaces import RolloutInput
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.datasets.cloth_solver import ClothSolver
from clods_bench.datasets.scenes import draw_wind, get_scene, simulate_scene
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.physics import PhysicsConfig, PhysicsSimulator, expected_wind, solver_params

FLAG = get_scene("flag")
CALM = dataclasses.replace(FLAG, name="flag-calm", has_wind=False, params=dataclasses.replace(FLAG.params, turbulence_amplitude=0.0))


@pytest.fixture(scope="module")
def calm_traj():
    """A windless ground-truth trajectory (8 x 5 flag, 31 frames)."""
    return simulate_scene(CALM, CALM.build_mesh((8, 5)), 31, seed=3)


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def test_windless_same_dt_reproduces_ground_truth(calm_traj) -> None:
    """Same physics, same dt, no unknown wind: only float32 rounding of frames 0/1 separates the two."""
    pred = PhysicsSimulator(CALM, PhysicsConfig()).rollout(RolloutInput.from_trajectory(calm_traj))
    np.testing.assert_array_equal(pred[:2], calm_traj.world_pos[:2])
    assert np.abs(pred[2] - calm_traj.world_pos[2]).max() < 1e-5
    assert _rmse(pred, calm_traj.world_pos) < 3e-5


def test_coarser_dt_error_grows(calm_traj) -> None:
    inp = RolloutInput.from_trajectory(calm_traj)
    errs = [_rmse(PhysicsSimulator(CALM, PhysicsConfig(dt_factor=k)).rollout(inp), calm_traj.world_pos) for k in (1, 2, 4)]
    assert errs[0] < 1e-4 < errs[1] < errs[2]


def test_dt_factor_is_a_coarse_solver_plus_linear_interpolation(calm_traj) -> None:
    """dt_factor 2 equals the plain solver at 2 dt from (x1, (x1-x0)/dt) on odd frames, midpoints between."""
    inp = RolloutInput.from_trajectory(calm_traj)
    pred = PhysicsSimulator(CALM, PhysicsConfig(dt_factor=2)).rollout(inp)
    sim = PhysicsSimulator(CALM, PhysicsConfig())
    x0, x1 = (calm_traj.world_pos[i].astype(np.float64) for i in (0, 1))
    solver = ClothSolver(sim.rest_mesh(inp), sim.params, 2 * calm_traj.dt)
    coarse = solver.simulate(x1, (x1 - x0) / calm_traj.dt, 16, t0=calm_traj.dt)  # frames 1, 3, ..., 31
    np.testing.assert_allclose(pred[1::2], coarse[:15], atol=1e-6)
    np.testing.assert_allclose(pred[2::2], 0.5 * (coarse[:15] + coarse[1:16]), atol=1e-6)


def test_kinematic_nodes_follow_the_prescription(calm_traj) -> None:
    inp = RolloutInput.from_trajectory(calm_traj)
    moving = inp.kinematic_pos.copy()
    moving[:, inp.kinematic_mask] += np.linspace(0.0, 0.1, inp.num_frames)[:, None, None]
    moving[:2, inp.kinematic_mask] = inp.init_pos[:, inp.kinematic_mask]
    pred = PhysicsSimulator(CALM, PhysicsConfig()).rollout(dataclasses.replace(inp, kinematic_pos=moving))
    np.testing.assert_array_equal(pred[2:, inp.kinematic_mask], moving[2:, inp.kinematic_mask])
    assert np.isfinite(pred).all()


def test_expected_wind_matches_monte_carlo_of_the_scene_draw() -> None:
    rng = np.random.default_rng(0)
    draws = np.array([draw_wind(FLAG, rng)[0].wind_velocity for _ in range(20000)])
    np.testing.assert_allclose(expected_wind(FLAG), draws.mean(axis=0), atol=0.02)
    p = solver_params(FLAG, PhysicsConfig())
    assert p.turbulence_amplitude == 0.0 and p.youngs_modulus == FLAG.params.youngs_modulus
    assert solver_params(FLAG, PhysicsConfig(wind="still")).wind_velocity == (0.0, 0.0, 0.0)


def test_registered_with_typed_config(tmp_path) -> None:
    spec = default_registry().get("simulator", "physics")
    cfg = spec.make_config({"dt_factor": 2, "wind": "still"}, where="sim_config.physics")
    sim = spec.build(cfg, BuildContext(scene=get_scene("flag-stiff"), seed=0, work_dir=tmp_path))
    assert sim.fit([], None) == {} and sim.params.youngs_modulus == 50 * FLAG.params.youngs_modulus
    with pytest.raises(ClodsError, match="dt_factor"):
        spec.build(spec.make_config({"dt_factor": 0}, where="x"), BuildContext(scene=FLAG, seed=0, work_dir=tmp_path))
    with pytest.raises(ClodsError, match="unknown config key"):
        spec.make_config({"dt_fator": 2}, where="sim_config.physics")
