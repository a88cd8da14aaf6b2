"""A velocity output (BSMS-GNN's and HCMT's codes) in the shared model and trainer, against brute force.

The decoder then predicts the normalised x_{t+1} - x_t; the model steps to x_t + v on free nodes, the one-step
target is v* = (x_{t+1} + (1 - gamma) n) - (x_t + n), and a rollout integrates the same way.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.types import NORMAL, Trajectory
from clods_bench.plugins.simulators.learned.bsms import build_bsms
from clods_bench.plugins.simulators.learned.trainer import Trainer, TrainingData
from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig
from tests.plugins.simulators.structure_fixtures import PINNED


@pytest.fixture(scope="module")
def waving() -> Trajectory:
    """A 6x4 flag whose free nodes swing sideways, more the farther from the pole."""
    mesh = make_flag_mesh(6, 4, length=1.0, height=0.5)
    reach = mesh.mesh_pos[:, 0:1] / mesh.mesh_pos[:, 0].max()
    t = np.arange(12)[:, None, None]
    frames = mesh.rest_pos[None] + np.array([0.0, 0.1, 0.0])[None, None] * reach[None] * np.sin(0.4 * t)
    return Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, frames.astype(np.float32), 0.02)


def simulator(**overrides: object):
    base = dict(latent_size=16, hidden_layers=1, levels=1, warmup_steps=3, checkpoint_every=10**6, num_threads=1, output="velocity")
    return build_bsms(BsmsConfig(**{**base, **overrides}), SimpleNamespace(scene=PINNED))


def test_target_is_the_noisy_velocity(waving: Trajectory):
    sim = simulator(noise_gamma=0.3, noise_std=0.01)
    trainer = Trainer(sim.build_model(0), sim.config, TrainingData([waving], sim.cache, 1), seed=0)
    batch, noise = trainer.sample()
    f, n = batch.frames.double().numpy(), noise.double().numpy()
    expected = (f[2] + 0.7 * n) - (f[1] + n)
    np.testing.assert_allclose(trainer._target_output(batch, noise).double().numpy(), expected, rtol=1e-6, atol=1e-7)
    assert np.abs(n).max() > 0  # the noise is there to be checked


def test_step_moves_free_nodes_by_the_predicted_velocity(waving: Trajectory):
    sim = simulator()
    model = sim.build_model(0).double().eval()
    key, topo = sim.cache.get(waving.cells, waving.mesh_pos, waving.node_type)
    x, prev = torch.as_tensor(waving.world_pos[5], dtype=torch.float64), torch.as_tensor(waving.world_pos[4], dtype=torch.float64)
    kin = torch.as_tensor(waving.world_pos[6], dtype=torch.float64)
    with torch.no_grad():
        model.output_normalizer(0.05 * torch.randn(50, 3, generator=torch.Generator().manual_seed(0)) + 0.01, accumulate=True)
        out = model(topo, key, x, prev)
        velocity = (out * model.output_normalizer.std.double() + model.output_normalizer.mean.double()).numpy()
        nxt = model.step(topo, key, x, prev, kin).numpy()
    assert np.abs(velocity).max() > 1e-3  # a velocity of the normaliser's scale, not ~0
    free = topo.normal.numpy()
    np.testing.assert_allclose(nxt[free], x.numpy()[free] + velocity[free], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(nxt[~free], kin.numpy()[~free])


def test_training_lowers_the_loss_and_rolls_out(waving: Trajectory, tmp_path):
    """60 steps on the waving flag lower the loss below half its first value; the rollout keeps the handles where
    they are prescribed and stays finite."""
    sim = simulator(train_steps=60, learning_rate=3e-3, batch_size=2, noise_std=0.0)
    stats = sim.fit([waving], FitContext(work_dir=tmp_path, seed=0, progress=False))
    curve = json.loads((tmp_path / "bsms_train_log.json").read_text())["loss_curve"]
    assert stats["final_loss"] < 0.5 * curve[0]
    free = waving.node_type == NORMAL
    kinematic = waving.world_pos.copy()
    kinematic[:, free] = np.nan
    frames = sim.rollout(RolloutInput(waving.cells, waving.mesh_pos, waving.node_type, waving.world_pos[:2], kinematic, waving.dt))
    assert frames.shape == waving.world_pos.shape and np.isfinite(frames).all()
    np.testing.assert_array_equal(frames[:, ~free], waving.world_pos[:, ~free])
