"""The CDG task end to end on the tiny dataset, checked against an independent numpy computation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.interfaces import RolloutInput
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.outputs.mesh_pictures import load_mesh_sample
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import NORMAL, Trajectory
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.baselines import ConstantVelocity
from tests.conftest import tiny_config


def _independent_constvel(world_pos: np.ndarray, node_type: np.ndarray) -> np.ndarray:
    """Constant-velocity rollout written out longhand."""
    pred = world_pos.astype(np.float64).copy()
    free = node_type == NORMAL
    for t in range(2, len(pred)):
        pred[t, free] = pred[t - 1, free] + (pred[t - 1, free] - pred[t - 2, free])
    return pred


def _independent_constvel_rmse(world_pos: np.ndarray, node_type: np.ndarray) -> np.ndarray:
    """Per-frame RMSE of the longhand constant-velocity rollout."""
    err = _independent_constvel(world_pos, node_type) - world_pos
    return np.array([np.sqrt((e**2).sum() / e.size) for e in err])


def _independent_max_strain(traj: Trajectory) -> float:
    """Largest |l/l0 - 1| over the triangle edges of the constant-velocity rollout; a flag's rest lengths are its mesh_pos lengths."""
    pred = _independent_constvel(traj.world_pos, traj.node_type)
    worst = 0.0
    for a, b, c in traj.cells:
        for i, j in ((a, b), (b, c), (c, a)):
            rest = np.linalg.norm(traj.mesh_pos[i].astype(np.float64) - traj.mesh_pos[j])
            worst = max(worst, float(np.max(np.abs(np.linalg.norm(pred[:, i] - pred[:, j], axis=1) / rest - 1.0))))
    return worst


def test_constvel_cdg_matches_independent_numbers(tiny_root: Path, tmp_path: Path) -> None:
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", sim="constvel")
    rdir = run_task(cfg, default_registry())
    rec = json.loads((rdir / RECORD_FILE).read_text())
    store = DatasetStore.open(cfg.data.dataset_dir())
    viewed = [store.load_trajectory(1)]  # num_train=2: second half = trajectory 1
    unviewed = [store.load_trajectory(2)]
    # the picture sample: the unviewed trajectory's rollout, against the longhand constant-velocity one
    cells, meshes, truth, marks, _ = load_mesh_sample(rdir / "seed_0" / "rollout_meshes.npz")
    assert cells.tolist() == unviewed[0].cells.tolist() and marks == [8] and list(meshes) == ["constvel"]
    np.testing.assert_allclose(truth, unviewed[0].world_pos[: len(truth)], rtol=1e-6)
    np.testing.assert_allclose(meshes["constvel"], _independent_constvel(unviewed[0].world_pos, unviewed[0].node_type)[: len(truth)], atol=1e-5)
    assert len(truth) == 12  # the tiny preset's rollout length (d_end of extrapolation is frame 11 below)
    assert not (rdir / "seed_0" / "extraction_meshes.npz").exists()  # mesh-supervised: nothing extracted
    for group, trajs in (("viewed", viewed), ("unviewed", unviewed)):
        curves = np.stack([_independent_constvel_rmse(t.world_pos, t.node_type) for t in trajs])
        assert rec["metrics"][f"{group}/interp/d_avg"]["mean"] == pytest.approx(curves[:, 2:9].mean(), rel=1e-5)
        assert rec["metrics"][f"{group}/interp/d_end"]["mean"] == pytest.approx(curves[:, 8].mean(), rel=1e-5)
        assert rec["metrics"][f"{group}/extrap/d_avg"]["mean"] == pytest.approx(curves[:, 9:12].mean(), rel=1e-5)
        assert rec["metrics"][f"{group}/extrap/d_end"]["mean"] == pytest.approx(curves[:, 11].mean(), rel=1e-5)
    strain = max(_independent_max_strain(t) for t in viewed + unviewed)
    assert rec["metrics"]["max_strain"]["mean"] == pytest.approx(strain, rel=1e-5) and strain > 0.01  # constvel stretches the flag
    assert (rdir / "config.yaml").is_file()
    assert rec["versions"]["numpy"] and "data_seconds" in rec["run_timings"]


def test_constvel_is_exact_on_uniform_motion() -> None:
    cells = np.array([[0, 1, 2]], np.int32)
    mesh_pos = np.array([[0, 0], [1, 0], [0, 1]], np.float32)
    node_type = np.array([3, 0, 0], np.int32)
    t = np.arange(6, dtype=np.float32)[:, None, None]
    world = np.zeros((6, 3, 3), np.float32) + np.array([0.1, -0.2, 0.3], np.float32) * t
    world[:, 0] = 0.0  # the handle stays put
    traj = Trajectory(cells, mesh_pos, node_type, world, 0.02)
    pred = ConstantVelocity().rollout(RolloutInput.from_trajectory(traj))
    np.testing.assert_allclose(pred, world, atol=1e-5)


def test_rollout_input_hides_the_answer() -> None:
    cells = np.array([[0, 1, 2]], np.int32)
    traj = Trajectory(cells, np.zeros((3, 2), np.float32), np.array([3, 0, 0], np.int32), np.ones((5, 3, 3), np.float32), 0.02)
    inp = RolloutInput.from_trajectory(traj)
    assert np.isnan(inp.kinematic_pos[:, 1:]).all() and np.isfinite(inp.kinematic_pos[:, 0]).all()


def test_run_resumes_finished_seeds(tiny_root: Path, tmp_path: Path) -> None:
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", sim="frozen")
    rdir = run_task(cfg, default_registry())
    first = (rdir / "seed_0" / "result.json").read_text()
    cfg2 = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", "seeds=[0, 1]", sim="frozen")
    assert run_task(cfg2, default_registry()) == rdir
    assert (rdir / "seed_0" / "result.json").read_text() == first  # reused, not recomputed
    rec = json.loads((rdir / RECORD_FILE).read_text())
    assert rec["seeds"] == [0, 1]
    assert rec["metrics"]["viewed/interp/d_avg"]["std"] == pytest.approx(0.0, abs=1e-12)  # deterministic baseline


def test_missing_sim_and_unknown_plugin(tiny_root: Path, tmp_path: Path) -> None:
    with pytest.raises(ClodsError, match="needs a simulator"):
        run_task(tiny_config(tiny_root, f"runs_dir={tmp_path}"), default_registry())
    with pytest.raises(ClodsError, match="did you mean 'constvel'"):
        run_task(tiny_config(tiny_root, f"runs_dir={tmp_path}", sim="constvl"), default_registry())
