"""LIP-style particle simulator: radius graph against brute force, invariances, no use of mesh edges, gradients,
training, free fall, checkpoints and bad input."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from clods_bench.benchmark.core.interfaces import FitContext
from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.types import HANDLE, NORMAL, Trajectory
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.graph import build_features, build_topology, concat_topologies
from clods_bench.plugins.simulators.learned.lip import build_lip
from clods_bench.plugins.simulators.learned.lip_config import LipConfig
from clods_bench.plugins.simulators.learned.radius_graph import radius_edges, rest_spacing
from clods_bench.plugins.simulators.learned.trainer import Trainer, TrainingData

PINNED = SimpleNamespace(name="test-pinned", has_obstacles=False, has_handles=True)
SMALL = dict(latent_size=16, hidden_layers=1, message_passing_steps=2, radius_factor=1.8, max_neighbours=None,
             warmup_steps=5, checkpoint_every=10**6, num_threads=1)  # fmt: skip


def lip(**overrides: object):
    return build_lip(LipConfig(**{**SMALL, **overrides}), SimpleNamespace(scene=PINNED))


@pytest.fixture(scope="module")
def windless() -> Trajectory:
    """A 5x3 flag swinging down under gravity in still air."""
    mesh = make_flag_mesh(5, 3, length=1.0, height=0.5)
    frames = ClothSolver(mesh, SolverParams(air_density=0.0, damping_mass=0.5), 0.02).simulate(mesh.rest_pos, np.zeros_like(mesh.rest_pos), 14)
    return Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, frames, 0.02)


# --- radius graph ------------------------------------------------------------------------------


def _brute_force(pos: np.ndarray, sample: np.ndarray, radius: np.ndarray, cap: int | None) -> set[tuple[int, int]]:
    """Every (sender, receiver) pair by an O(N^2) loop, each receiver keeping its `cap` nearest."""
    out = set()
    for i in range(len(pos)):
        near = [(float(np.linalg.norm(pos[j] - pos[i])), j) for j in range(len(pos))
                if j != i and sample[j] == sample[i] and np.linalg.norm(pos[j] - pos[i]) < radius[i]]  # fmt: skip
        near.sort()
        out |= {(j, i) for _, j in (near if cap is None else near[:cap])}
    return out


@pytest.mark.parametrize("cap", [None, 3])
def test_radius_graph_against_brute_force(cap: int | None) -> None:
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 1, (40, 3))  # two samples of 25 and 15 nodes occupying the same space
    sample = np.repeat([0, 1], [25, 15])
    radius = np.where(sample == 0, 0.35, 0.5)
    s, r = radius_edges(torch.as_tensor(pos, dtype=torch.float64), torch.as_tensor(sample), torch.as_tensor(radius), cap)
    got = list(zip(s.tolist(), r.tolist()))
    want = _brute_force(pos, sample, radius, cap)
    assert len(got) == len(set(got)) and set(got) == want
    assert len(want) > 40  # the case is not trivially empty
    if cap is not None:
        assert max(np.bincount(r.numpy())) == cap


def test_rest_spacing_is_the_grid_step() -> None:
    mesh = make_flag_mesh(6, 4, length=1.0, height=0.9)  # dx = 0.2, dy = 0.3
    assert rest_spacing(mesh.mesh_pos) == pytest.approx(0.2, rel=1e-6)


def test_edge_features_are_relative_position_over_radius_and_no_mesh_edge() -> None:
    mesh = make_flag_mesh(5, 3, length=1.0, height=0.5)  # spacing 0.25
    rng = np.random.default_rng(1)
    pos = (mesh.rest_pos + rng.normal(0, 0.02, mesh.rest_pos.shape)).astype(np.float32)
    sim = lip()
    topo = build_topology(mesh.cells, mesh.mesh_pos, mesh.node_type)
    nodes, sets = build_features(topo, torch.as_tensor(pos), torch.as_tensor(pos), sim.spec)
    assert set(sets) == {"radius"} and sim.spec.edge_widths == {"radius": 4}
    es, radius = sets["radius"], 1.8 * 0.25
    assert set(zip(es.senders.tolist(), es.receivers.tolist())) == _brute_force(pos, np.zeros(15), np.full(15, radius), None)
    for e, (s, r) in enumerate(zip(es.senders.tolist(), es.receivers.tolist())):
        d = (pos[s] - pos[r]) / radius
        np.testing.assert_allclose(es.features[e].numpy(), np.append(d, np.linalg.norm(d)), rtol=1e-5, atol=1e-6)
    assert nodes.shape == (15, 3 + 9)


# --- model ---------------------------------------------------------------------------------------


def _warmed(windless: Trajectory, seed: int = 0, **overrides: object) -> Trainer:
    """A trainer whose normalisers hold the trajectory's statistics and are then frozen."""
    sim = lip(**overrides)
    trainer = Trainer(sim.build_model(seed), sim.config, TrainingData([windless], sim.cache, 1), seed)
    with torch.no_grad():
        for _ in range(8):
            trainer.accumulate_only(*trainer.sample())
    for m in trainer.model.modules():
        if hasattr(m, "max_accumulations"):
            m.max_accumulations = 0
    return trainer


def _predict(model, cells: np.ndarray, mesh_pos: np.ndarray, node_type: np.ndarray, pos: np.ndarray, prev: np.ndarray) -> np.ndarray:
    topo = build_topology(cells, mesh_pos, node_type)
    with torch.no_grad():
        out = model(topo, "k", torch.as_tensor(pos, dtype=torch.float32), torch.as_tensor(prev, dtype=torch.float32))
    return model.acceleration(out).numpy()


def test_translation_invariance_permutation_equivariance_and_no_mesh_edges(windless: Trajectory) -> None:
    model = _warmed(windless).model.eval()
    pos, prev = windless.world_pos[6], windless.world_pos[5]
    cells, mp, nt = windless.cells, windless.mesh_pos, windless.node_type
    base = _predict(model, cells, mp, nt, pos, prev)
    assert np.abs(base).max() > 1e-5
    shift = np.array([0.7, -1.3, 2.1], np.float32)
    np.testing.assert_allclose(_predict(model, cells, mp, nt, pos + shift, prev + shift), base, rtol=0, atol=1e-4 * np.abs(base).max())  # float32 rounding of 2 m offsets
    perm = np.random.default_rng(2).permutation(len(nt))
    inv = np.argsort(perm)
    permuted = _predict(model, inv[cells], mp[perm], nt[perm], pos[perm], prev[perm])
    np.testing.assert_allclose(permuted, base[perm], rtol=0, atol=1e-5 * np.abs(base).max())
    other_cells = np.array([[0, 6, 12], [2, 3, 4]], np.int32)  # a different (even partial) triangulation: same answer
    np.testing.assert_array_equal(_predict(model, other_cells, mp, nt, pos, prev), base)


def test_only_nodes_within_the_radius_influence_a_node(windless: Trajectory) -> None:
    model = _warmed(windless, message_passing_steps=1).model.eval()  # one hop: the receptive field is the radius
    pos, prev = windless.world_pos[6].copy(), windless.world_pos[5]
    cells, mp, nt = windless.cells, windless.mesh_pos, windless.node_type
    base = _predict(model, cells, mp, nt, pos, prev)
    radius = 1.8 * rest_spacing(mp)
    moved = 14  # a free corner node; push it further out, staying out of every node's radius that it was out of
    far = np.linalg.norm(pos - pos[moved], axis=1) >= radius
    pos2 = pos.copy()
    pos2[moved] += np.array([0.0, 0.05, 0.0], np.float32)
    assert (np.linalg.norm(pos2 - pos2[moved], axis=1)[far] >= radius).all()
    after = _predict(model, cells, mp, nt, pos2, prev)
    np.testing.assert_array_equal(after[far], base[far])
    near = ~far
    near[moved] = False
    assert near.any() and np.abs(after[near] - base[near]).max() > 0


def test_gradients_reach_every_parameter(windless: Trajectory) -> None:
    trainer = _warmed(windless, batch_size=2)
    loss = trainer.one_step_loss(*trainer.sample())
    params = dict(trainer.model.named_parameters())
    grads = torch.autograd.grad(loss, list(params.values()))
    for (name, _), g in zip(params.items(), grads):
        assert torch.isfinite(g).all(), name
        assert g.abs().max() > 0, name


def test_one_training_step_lowers_the_loss(windless: Trajectory) -> None:
    trainer = _warmed(windless, batch_size=4, learning_rate=1e-3, noise_std=0.0)
    batch, noise = trainer.sample()
    before = trainer.one_step_loss(batch, noise)
    trainer.optimizer.zero_grad()
    before.backward()
    trainer.optimizer.step()
    with torch.no_grad():
        after = trainer.one_step_loss(batch, noise)
    assert float(after) < 0.9 * float(before.detach())


def test_isolated_particles_fall_freely_and_handles_follow_their_path() -> None:
    """No node within the radius of another: with a zero-initialised last decoder layer the acceleration is the
    output normaliser's mean, which accumulated free-fall data makes g dt^2: the rollout is the ballistic path."""
    g, dt, steps = np.array([0.0, 0.0, -9.81]), 0.02, 20
    mesh_pos = np.array([[0, 0], [0.1, 0], [0, 0.1], [0.1, 0.1]], np.float32)  # rest spacing 0.1, radius 0.18
    cells, node_type = np.array([[0, 1, 2], [1, 3, 2]], np.int32), np.array([NORMAL, NORMAL, NORMAL, HANDLE], np.int32)
    x0 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float64)  # 1 m apart in the world
    v0 = np.array([[0.5, 0, 1.0], [0, -0.3, 0], [0.2, 0.2, 0.2], [0, 0, 0]])
    t = (np.arange(steps) * dt)[:, None, None]
    path = x0 + v0 * t + 0.5 * g * t**2
    traj = Trajectory(cells, mesh_pos, node_type, path.astype(np.float32), dt)  # training data: all fall (stats of all nodes)
    sim = lip(noise_std=0.0)
    model = sim.build_model(0)
    trainer = Trainer(model, sim.config, TrainingData([traj], sim.cache, 1), 0)
    with torch.no_grad():
        for _ in range(20):
            trainer.accumulate_only(*trainer.sample())
        torch.nn.init.zeros_(model.decoder[-1].weight)
        torch.nn.init.zeros_(model.decoder[-1].bias)
    model.eval()
    topo = sim.cache.get(cells, mesh_pos, node_type)[1]
    assert build_features(topo, torch.as_tensor(path[0], dtype=torch.float32), torch.as_tensor(path[0], dtype=torch.float32), sim.spec)[1]["radius"].senders.numel() == 0
    kin = torch.as_tensor(path, dtype=torch.float32)
    kin[:, 3] = torch.as_tensor(x0[3]) + torch.tensor([0.1, 0.0, 0.0]) * torch.sin(torch.arange(steps, dtype=torch.float32))[:, None]
    prev, cur = kin[0], kin[1]
    with torch.no_grad():
        for k in range(2, steps):
            prev, cur = cur, model.step(topo, "k", cur, prev, kin[k])
    np.testing.assert_allclose(cur.numpy()[:3], path[-1, :3], atol=2e-5)
    np.testing.assert_array_equal(cur.numpy()[3], kin[-1, 3].numpy())


# --- fit, checkpoints, bad input -----------------------------------------------------------------


def test_interrupted_training_resumes_to_the_same_weights(windless: Trajectory, tmp_path: Path, monkeypatch) -> None:
    cfg = dict(train_steps=16, checkpoint_every=8, batch_size=2)
    full = lip(**cfg)
    full_stats = full.fit([windless], FitContext(work_dir=tmp_path / "full", seed=3, progress=False))
    real_step = Trainer.train_step

    def crash_at_12(self: Trainer) -> float | None:
        if self.step == 12:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(Trainer, "train_step", crash_at_12)
    with pytest.raises(KeyboardInterrupt):
        lip(**cfg).fit([windless], FitContext(work_dir=tmp_path / "cut", seed=3, progress=False))
    monkeypatch.setattr(Trainer, "train_step", real_step)
    again = lip(**cfg)
    stats = again.fit([windless], FitContext(work_dir=tmp_path / "cut", seed=3, progress=False))
    assert stats["resumed_from_step"] == 8 and stats["train_steps"] == 16
    assert stats["final_loss"] == pytest.approx(full_stats["final_loss"], rel=1e-5)
    for a, b in zip(full.model.state_dict().values(), again.model.state_dict().values()):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_radius_factor_must_be_positive(bad: float) -> None:
    with pytest.raises(ClodsError) as err:
        lip(radius_factor=bad)
    assert err.value.where == "sim_config.lip.radius_factor"


def test_a_cloth_without_neighbours_within_the_radius_is_a_clear_error(windless: Trajectory, tmp_path: Path) -> None:
    sim = lip(radius_factor=0.9)  # below the grid step: no pair of nodes is that close
    with pytest.raises(ClodsError, match="no node has a neighbour within the radius") as err:
        sim.fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))
    assert err.value.where == "sim_config.lip.radius_factor"
    assert not (tmp_path / "lip.ckpt").exists()


def test_batched_samples_never_connect(windless: Trajectory) -> None:
    topo = build_topology(windless.cells, windless.mesh_pos, windless.node_type)
    both = concat_topologies([topo, concat_topologies([topo, topo])])
    assert both.sample.tolist() == [0] * 15 + [1] * 15 + [2] * 15
    x = torch.as_tensor(np.concatenate([windless.world_pos[3]] * 3))
    es = build_features(both, x, x, lip().spec)[1]["radius"]
    assert (both.sample[es.senders] == both.sample[es.receivers]).all() and es.senders.numel() > 0


def test_plan_row_is_the_finetune_pipeline_without_the_edge_loss() -> None:
    """The geometry-aware table: LIP = particle model, finetune variant, gamma 0; its CloDS row is Table 2's run."""
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.benchmark.reproduction.reproduce import build_configs, config_identity, default_plan_path, load_plan

    rows = {(run.table, run.label): cfg for run, cfg in build_configs(load_plan(default_plan_path()), "ci", default_registry())}
    row = rows[("geometry_aware", "LIP-style")]
    assert (row.sim, row.renderer) == ("lip", "smgs")
    assert row.task_config["clods"]["variant"] == "finetune" and float(row.task_config["clods"]["gamma"]) == 0.0
    assert row.sim_config["lip"]["radius_factor"] == 1.8  # the ci preset's size reaches the plugin
    assert config_identity(rows[("geometry_aware", "CloDS")]) == config_identity(rows[("table2_cdg", "CloDS")])
    assert not any(label.startswith("LIP") for table, label in rows if table == "table2_cdg")


# --- structure pinned at the ci preset's widths --------------------------------------------------------------

CI = dict(latent_size=64, message_passing_steps=4, radius_factor=1.8, max_neighbours=12)  # presets/ci.yaml


def test_parameter_counts_at_ci_widths() -> None:
    latent, hidden, steps = 64, 2, 4
    mlp = lambda i, o, ln=True: i * latent + latent + (hidden - 1) * (latent * latent + latent) + latent * o + o + (2 * o if ln else 0)  # noqa: E731
    frame = mlp(12, latent) + mlp(4, latent) + mlp(latent, 3, ln=False)  # node and radius-edge encoders, decoder
    block = mlp(3 * latent, latent) + mlp(2 * latent, latent)  # edge function on [sender, receiver, edge], node function
    model = build_lip(LipConfig(**CI), SimpleNamespace(scene=PINNED)).build_model(0)
    assert sum(p.numel() for p in model.parameters()) == frame + steps * block == 176_579


# A fixed-seed float64 output of the ci-width model (weights from seed 0, normalisers fed once): a refactor that
# changes the function moves these by far more than the ~1e-15 float64 differences between CPUs.
EXPECTED = {"norm": 4.035362526100458, "first": [-0.003209615196198841, 0.031454225182943905, -0.5539149398542837]}


def test_fixed_seed_float64_output_is_the_committed_one() -> None:
    import dataclasses

    model = build_lip(LipConfig(**CI), SimpleNamespace(scene=PINNED)).build_model(0).double()
    mesh = make_flag_mesh(9, 5, length=1.0, height=0.5)
    topo = build_topology(mesh.cells, mesh.mesh_pos, mesh.node_type)
    topo = dataclasses.replace(topo, node_type_onehot=topo.node_type_onehot.double(), rest_spacing=topo.rest_spacing.double())
    rng = np.random.default_rng(0)
    pos = torch.as_tensor(mesh.rest_pos + rng.normal(0.0, 0.02, mesh.rest_pos.shape))
    prev = pos - torch.as_tensor(rng.normal(0.0, 0.01, mesh.rest_pos.shape))
    with torch.no_grad():
        model(topo, "k", pos, prev, accumulate=True)
        out = model(topo, "k", pos, prev)
    got = {"norm": float(torch.linalg.vector_norm(out)), "first": out[mesh.rest_pos.shape[0] - 1].tolist()}
    assert got["norm"] == pytest.approx(EXPECTED["norm"], rel=1e-9)
    np.testing.assert_allclose(got["first"], EXPECTED["first"], rtol=0, atol=1e-9 * EXPECTED["norm"])
