"""Online normaliser (MGN `normalization.py`): statistics against numpy, the accumulation cap, no updates at rollout."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.types import Trajectory
from clods_bench.plugins.simulators.learned.config import MgnConfig
from clods_bench.plugins.simulators.learned.mgn import build_mgn
from clods_bench.plugins.simulators.learned.normalizer import Normalizer


def test_statistics_match_numpy_and_stop_after_max_accumulations() -> None:
    rng = np.random.default_rng(0)
    batches = [rng.normal(3.0, 0.5, (7, 2)) for _ in range(4)]
    norm = Normalizer(2, max_accumulations=3)
    for b in batches:
        norm(torch.as_tensor(b, dtype=torch.float32), accumulate=True)
    seen = np.concatenate(batches[:3])  # the fourth call came after the cap: not accumulated
    np.testing.assert_allclose(norm.mean.numpy(), seen.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(norm.std.numpy(), seen.std(axis=0), rtol=1e-5)  # population std, as MGN
    x = torch.as_tensor(batches[3], dtype=torch.float32)
    np.testing.assert_allclose(norm(x).numpy(), (batches[3] - seen.mean(0)) / seen.std(0), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(norm.inverse(norm(x)).numpy(), batches[3], rtol=1e-5, atol=1e-5)


def test_constant_feature_gets_epsilon_std_not_nan() -> None:
    norm = Normalizer(1, std_epsilon=1e-8)
    norm(torch.full((5, 1), 0.1), accumulate=True)
    assert float(norm.std) == np.float32(1e-8) and torch.isfinite(norm(torch.full((2, 1), 0.1))).all()


def test_rollout_leaves_every_normaliser_unchanged(tmp_path) -> None:
    """Statistics are fixed once training ends: a rollout (eval mode) must not feed them its own states."""
    mesh = make_flag_mesh(5, 3, length=1.0, height=0.5)
    frames = ClothSolver(mesh, SolverParams(air_density=0.0, damping_mass=0.5), 0.02).simulate(mesh.rest_pos, np.zeros_like(mesh.rest_pos), 12)
    traj = Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, frames, 0.02)
    cfg = MgnConfig(latent_size=8, hidden_layers=1, message_passing_steps=1, warmup_steps=3, train_steps=6, checkpoint_every=10**6, num_threads=1)
    sim = build_mgn(cfg, SimpleNamespace(scene=SimpleNamespace(name="t", has_obstacles=False, has_handles=True)))
    sim.fit([traj], FitContext(work_dir=tmp_path, seed=0, progress=False))
    before = {k: v.clone() for k, v in sim.model.state_dict().items() if "normalizer" in k}
    assert int(before["node_normalizer.num_accumulations"]) == 6  # 3 warm-up + 3 training calls
    sim.rollout(RolloutInput.from_trajectory(traj))
    after = {k: v for k, v in sim.model.state_dict().items() if "normalizer" in k}
    for k, v in before.items():
        torch.testing.assert_close(after[k], v, rtol=0, atol=0)
