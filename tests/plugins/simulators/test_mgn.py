"""MGN graph and trainer: features against brute force, the noise correction, the two losses, overfitting, checkpoints."""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.scenes import get_scene
from clods_bench.datasets.types import HANDLE, NORMAL, OBSTACLE, Trajectory
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import torch_threads
from clods_bench.plugins.simulators.learned.bsms import build_bsms
from clods_bench.plugins.simulators.learned.config import MgnConfig
from clods_bench.plugins.simulators.learned.graph import GraphSpec, build_features, build_topology
from clods_bench.plugins.simulators.learned.mgn import build_mgn
from clods_bench.plugins.simulators.learned.trainer import Trainer, TrainingData
from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig
from tests.plugins.simulators.structure_fixtures import CI_WIDTHS, assert_close, fixed_evaluation, mlp_parameters, shared_parameters

PINNED = SimpleNamespace(name="test-pinned", has_obstacles=False, has_handles=True)
SMALL = dict(latent_size=16, hidden_layers=1, message_passing_steps=2, warmup_steps=5, checkpoint_every=10**6, num_threads=1)


@pytest.fixture(scope="module")
def windless() -> Trajectory:
    """A 5x3 flag swinging down under gravity in still air: its accelerations are a function of its state."""
    mesh = make_flag_mesh(5, 3, length=1.0, height=0.5)
    solver = ClothSolver(mesh, SolverParams(air_density=0.0, damping_mass=0.5), 0.02)
    frames = solver.simulate(mesh.rest_pos, np.zeros_like(mesh.rest_pos), 14)
    return Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, frames, 0.02)


def mgn(**overrides: object):
    return build_mgn(MgnConfig(**{**SMALL, **overrides}), SimpleNamespace(scene=PINNED))


# --- graph -------------------------------------------------------------------------------------


def test_flag_graph_has_mesh_edges_only() -> None:
    scene = get_scene("flag")
    assert not scene.has_obstacles
    sim = build_mgn(MgnConfig(**SMALL), SimpleNamespace(scene=scene))
    model = sim.build_model(0)
    assert sim.spec.edge_widths == {"mesh": 7}
    assert set(model.edge_normalizers) == set(model.edge_encoders) == {"mesh"}
    for block in model.processor.blocks:
        assert set(block.edge_fns) == {"mesh"}
        assert block.node_fn[0].in_features == 2 * SMALL["latent_size"]  # node + one aggregated edge set
    mesh = make_flag_mesh(16, 8)
    topo = build_topology(mesh.cells, mesh.mesh_pos, mesh.node_type)
    x = torch.as_tensor(mesh.rest_pos, dtype=torch.float32)
    _, sets = build_features(topo, x, x, sim.spec)
    assert set(sets) == {"mesh"}
    undirected = {tuple(sorted(e)) for c in mesh.cells.tolist() for e in itertools.combinations(c, 2)}  # brute force
    pairs = set(zip(topo.senders.tolist(), topo.receivers.tolist()))
    assert pairs == undirected | {(b, a) for a, b in undirected} and len(pairs) == len(topo.senders)


def test_edge_and_node_features_against_brute_force() -> None:
    mesh = make_flag_mesh(4, 3)
    rng = np.random.default_rng(0)
    pos = (mesh.rest_pos + rng.normal(0, 0.1, mesh.rest_pos.shape)).astype(np.float32)
    prev = (pos - rng.normal(0, 0.01, pos.shape)).astype(np.float32)
    topo = build_topology(mesh.cells, mesh.mesh_pos, mesh.node_type)
    nodes, sets = build_features(topo, torch.as_tensor(pos), torch.as_tensor(prev), GraphSpec())
    np.testing.assert_allclose(nodes[:, :3].numpy(), pos - prev, atol=1e-7)
    np.testing.assert_array_equal(nodes[:, 3:].numpy().argmax(1), mesh.node_type)
    mesh_set = sets["mesh"]
    for e, (s, r) in enumerate(zip(mesh_set.senders.tolist(), mesh_set.receivers.tolist())):
        dw, dm = pos[s] - pos[r], mesh.mesh_pos[s] - mesh.mesh_pos[r]
        want = np.concatenate([dw, [np.linalg.norm(dw)], dm, [np.linalg.norm(dm)]])
        np.testing.assert_allclose(mesh_set.features[e].numpy(), want, rtol=1e-5, atol=1e-6)


def test_world_edges_only_with_obstacles_and_within_radius() -> None:
    cells = np.array([[0, 1, 2], [3, 4, 5]], np.int32)
    mesh_pos = np.zeros((6, 2), np.float32)
    node_type = np.array([NORMAL, NORMAL, HANDLE, OBSTACLE, OBSTACLE, OBSTACLE], np.int32)
    pos = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0.03, 0, 0], [1.2, 0, 0], [5, 0, 0]], np.float32)
    topo = build_topology(cells, mesh_pos, node_type)
    x = torch.as_tensor(pos)
    spec = GraphSpec.for_scene(SimpleNamespace(has_obstacles=True), world_radius=0.05)
    _, sets = build_features(topo, x, x, spec)
    want = {(a, b) for a in range(3) for b in range(3, 6) if np.linalg.norm(pos[a] - pos[b]) < 0.05}
    want |= {(b, a) for a, b in want}
    assert set(zip(sets["world"].senders.tolist(), sets["world"].receivers.tolist())) == want == {(0, 3), (3, 0)}
    assert "world" not in build_features(topo, x, x, GraphSpec.for_scene(SimpleNamespace(has_obstacles=False), 0.05))[1]


# --- trainer -----------------------------------------------------------------------------------


def _trainer(traj: Trajectory, seed: int = 0, **overrides: object) -> Trainer:
    sim = mgn(**overrides)
    window = sim.config.rollout_length if sim.config.loss == "rollout" else 1
    return Trainer(sim.build_model(seed), sim.config, TrainingData([traj], sim.cache, window), seed)


def test_noise_only_on_normal_nodes_and_target_correction(windless: Trajectory) -> None:
    trainer = _trainer(windless, noise_std=0.01, noise_gamma=0.1, batch_size=3)
    batch, noise = trainer.sample()
    normal = batch.topo.normal
    assert (noise[~normal] == 0).all() and noise[normal].std() == pytest.approx(0.01, rel=0.3)
    f = batch.frames.double()
    n = noise.double()
    a = f[2] - 2 * f[1] + f[0]
    got = trainer._target_acceleration(batch, noise).double()
    torch.testing.assert_close(got, a - 1.1 * n, rtol=0, atol=1e-6)  # a* = a - (1 + gamma) n (MGN cloth)


def _warm(trainer: Trainer, steps: int = 5) -> None:
    """Fill the normalisers, then freeze them so two loss evaluations see identical statistics."""
    with torch.no_grad():
        for _ in range(steps):
            trainer.accumulate_only(*trainer.sample())
    for m in trainer.model.modules():
        if hasattr(m, "max_accumulations"):
            m.max_accumulations = 0


def test_rollout_loss_with_one_step_equals_one_step_loss(windless: Trajectory) -> None:
    one = _trainer(windless, noise_std=0.003)
    roll = _trainer(windless, noise_std=0.003, loss="rollout", rollout_length=1)
    _warm(one)
    roll.model.load_state_dict(one.model.state_dict())
    _warm(roll, steps=0)
    batch, noise = one.sample()
    l1, l2 = one.one_step_loss(batch, noise), roll.rollout_loss(batch, noise)
    assert float(l1.detach()) == pytest.approx(float(l2.detach()), rel=1e-4)
    g1 = torch.autograd.grad(l1, list(one.model.parameters()), allow_unused=True)
    g2 = torch.autograd.grad(l2, list(roll.model.parameters()), allow_unused=True)
    for a, b in zip(g1, g2):
        if a is not None:
            torch.testing.assert_close(a, b, rtol=1e-3, atol=1e-6)


def test_rollout_loss_unrolls_through_its_own_predictions(windless: Trajectory) -> None:
    """K=3 by hand: the model is fed its own positions, only the first target carries the noise correction."""
    trainer = _trainer(windless, noise_std=0.003, noise_gamma=0.1, loss="rollout", rollout_length=3)
    _warm(trainer)
    batch, noise = trainer.sample()
    model, topo, f, n = trainer.model, batch.topo, batch.frames.double(), noise.double()
    assert f.shape[0] == 5
    std = model.output_normalizer.std.double()
    prev, cur, terms = f[0], f[1] + n, []
    for k in (1, 2, 3):
        accel = model.acceleration(model(topo, batch.key, cur.float(), prev.float())).double()
        nxt = torch.where(topo.normal[:, None], 2 * cur - prev + accel, f[k + 1])
        target = f[k + 1] + 0.9 * n if k == 1 else f[k + 1]
        terms.append((((nxt - target) / std) ** 2).sum(1)[topo.normal].mean())
        prev, cur = cur, nxt
    want = sum(terms) / 3
    got = trainer.rollout_loss(batch, noise)
    assert float(got.detach()) == pytest.approx(float(want.detach()), rel=1e-5)
    # and it is not teacher forcing: the gradient reaches step 1's prediction through steps 2 and 3
    grads = torch.autograd.grad(got, list(model.decoder.parameters()))
    teacher = _teacher_forced(trainer, batch, noise)
    tgrads = torch.autograd.grad(teacher, list(model.decoder.parameters()))
    assert any(not torch.allclose(a, b, rtol=1e-3) for a, b in zip(grads, tgrads))


def _teacher_forced(trainer: Trainer, batch, noise) -> torch.Tensor:
    model, topo, f, n = trainer.model, batch.topo, batch.frames.double(), noise.double()
    std, terms = model.output_normalizer.std.double(), []
    for k in (1, 2, 3):
        prev, cur = f[k - 1] + (n if k == 2 else 0), f[k] + (n if k == 1 else 0)
        accel = model.acceleration(model(topo, batch.key, cur.float(), prev.float())).double()
        nxt = torch.where(topo.normal[:, None], 2 * cur - prev + accel, f[k + 1])
        target = f[k + 1] + 0.9 * n if k == 1 else f[k + 1]
        terms.append((((nxt - target) / std) ** 2).sum(1)[topo.normal].mean())
    return sum(terms) / 3


def _accel_error(sim, traj: Trajectory) -> float:
    """Relative error of the trained model's one-step accelerations on `traj` (free nodes, all frames)."""
    key, topo = sim.cache.get(traj.cells, traj.mesh_pos, traj.node_type)
    x = torch.as_tensor(traj.world_pos)
    errs, norms = [], []
    with torch.no_grad():
        for t in range(1, traj.num_steps - 1):
            a = sim.model.acceleration(sim.model(topo, key, x[t], x[t - 1]))
            true = x[t + 1] - 2 * x[t] + x[t - 1]
            errs.append((a - true)[topo.normal])
            norms.append(true[topo.normal])
    return float(torch.cat(errs).norm() / torch.cat(norms).norm())


def _rollout_error(sim, traj: Trajectory, k: int) -> float:
    """RMS position error of k-step rollouts of the trained model from every frame of `traj`, over constant velocity's."""
    key, topo = sim.cache.get(traj.cells, traj.mesh_pos, traj.node_type)
    x = torch.as_tensor(traj.world_pos)
    err, base = [], []
    with torch.no_grad():
        for t in range(1, traj.num_steps - k):
            prev, cur, cprev, ccur = x[t - 1], x[t], x[t - 1], x[t]
            for j in range(1, k + 1):
                prev, cur = cur, sim.model.step(topo, key, cur, prev, x[t + j])
                cprev, ccur = ccur, 2 * ccur - cprev
            err.append((cur - x[t + k])[topo.normal])
            base.append((ccur - x[t + k])[topo.normal])
    return float(torch.cat(err).norm() / torch.cat(base).norm())


def test_one_step_loss_overfits_one_trajectory(windless: Trajectory, tmp_path: Path) -> None:
    """The check that catches a broken trainer: on one noiseless, state-determined trajectory the fit becomes close."""
    sim = mgn(latent_size=32, train_steps=200, learning_rate=1e-3, noise_std=0.0, batch_size=4)
    stats = sim.fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))
    assert stats["train_steps"] == 200 and stats["train_samples"] == windless.num_steps - 2
    assert _accel_error(sim, windless) < 0.35  # zero acceleration (constant velocity) scores 1.0
    untrained = mgn(latent_size=32, train_steps=6, noise_std=0.0)
    untrained.fit([windless], FitContext(work_dir=tmp_path / "u", seed=0, progress=False))
    assert _accel_error(untrained, windless) > 0.8


@pytest.mark.slow  # ~15 s: unrolled training; the cheap checks of the rollout loss are the two tests above
def test_rollout_loss_trains_multi_step_rollouts(windless: Trajectory, tmp_path: Path) -> None:
    """Paper eq. 8 on a tiny case: K=3 rollouts of the trained model beat constant velocity's by a wide margin."""
    sim = mgn(latent_size=16, train_steps=150, learning_rate=1e-3, noise_std=0.0, loss="rollout", rollout_length=3, batch_size=2)
    stats = sim.fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))
    assert stats["train_samples"] == windless.num_steps - 4  # windows of K + 2 = 5 frames
    assert _rollout_error(sim, windless, 3) < 0.5
    untrained = mgn(latent_size=16, train_steps=6, noise_std=0.0, loss="rollout", rollout_length=3)
    untrained.fit([windless], FitContext(work_dir=tmp_path / "u", seed=0, progress=False))
    assert _rollout_error(untrained, windless, 3) > 0.8


# --- checkpoints and bad input ---------------------------------------------------------------------


def _params(sim) -> list[torch.Tensor]:
    return [p.detach().clone() for p in sim.model.state_dict().values()]


def test_interrupted_training_resumes_to_the_same_weights(windless: Trajectory, tmp_path: Path, monkeypatch) -> None:
    cfg = dict(train_steps=30, checkpoint_every=10, batch_size=2)
    full = mgn(**cfg)
    full_stats = full.fit([windless], FitContext(work_dir=tmp_path / "full", seed=3, progress=False))

    real_step = Trainer.train_step

    def crash_at_25(self: Trainer) -> float | None:
        if self.step == 25:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(Trainer, "train_step", crash_at_25)
    with pytest.raises(KeyboardInterrupt):
        mgn(**cfg).fit([windless], FitContext(work_dir=tmp_path / "cut", seed=3, progress=False))
    monkeypatch.setattr(Trainer, "train_step", real_step)
    again = mgn(**cfg)
    stats = again.fit([windless], FitContext(work_dir=tmp_path / "cut", seed=3, progress=False))
    assert stats["resumed_from_step"] == 20 and stats["train_steps"] == 30
    assert stats["final_loss"] == pytest.approx(full_stats["final_loss"], rel=1e-5)
    for a, b in zip(_params(full), _params(again)):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)


def test_foreign_checkpoints_are_clear_errors(windless: Trajectory, tmp_path: Path) -> None:
    mgn(train_steps=8).fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))
    with pytest.raises(ClodsError, match="another 'mgn' config"):
        mgn(train_steps=9).fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))
    other_mesh = make_flag_mesh(4, 3)
    moved = Trajectory(other_mesh.cells, other_mesh.mesh_pos, other_mesh.node_type, np.repeat(other_mesh.rest_pos[None], 5, 0).astype(np.float32), 0.02)
    with pytest.raises(ClodsError, match="other mesh topologies"):
        mgn(train_steps=8).fit([moved], FitContext(work_dir=tmp_path, seed=0, progress=False))
    shutil.copy(tmp_path / "mgn.ckpt", tmp_path / "bsms.ckpt")
    bsms = build_bsms(BsmsConfig(latent_size=16, hidden_layers=1, levels=1, train_steps=8, warmup_steps=2, num_threads=1), SimpleNamespace(scene=PINNED))
    with pytest.raises(ClodsError, match="written by simulator 'mgn', not 'bsms'"):
        bsms.fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))
    (tmp_path / "mgn.ckpt").write_bytes(b"not a checkpoint")
    with pytest.raises(ClodsError, match="unreadable checkpoint"):
        mgn(train_steps=8).fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))


def test_no_handle_nodes_is_a_clear_error(windless: Trajectory, tmp_path: Path) -> None:
    free = Trajectory(windless.cells, windless.mesh_pos, np.zeros_like(windless.node_type), windless.world_pos, windless.dt)
    with pytest.raises(ClodsError, match="no kinematic \\(HANDLE\\) node"):
        mgn(train_steps=8).fit([free], FitContext(work_dir=tmp_path, seed=0, progress=False))
    loose = build_mgn(MgnConfig(**{**SMALL, "train_steps": 8}), SimpleNamespace(scene=SimpleNamespace(name="free", has_obstacles=False, has_handles=False)))
    assert loose.fit([free], FitContext(work_dir=tmp_path / "free", seed=0, progress=False))["train_steps"] == 8


def test_rollout_errors_and_divergence(windless: Trajectory, tmp_path: Path) -> None:
    sim = mgn(train_steps=8)
    inp = RolloutInput.from_trajectory(windless)
    with pytest.raises(ClodsError, match="rollout before fit"):
        sim.rollout(inp)
    sim.fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))
    out = sim.rollout(inp)
    assert out.shape == windless.world_pos.shape and np.isfinite(out).all()
    kin = windless.node_type != NORMAL
    np.testing.assert_array_equal(out[:, kin], windless.world_pos[:, kin])  # handles are prescribed
    np.testing.assert_array_equal(out[:2], windless.world_pos[:2])
    with pytest.raises(ClodsError, match="differs from the training dt"):
        sim.rollout(RolloutInput.from_trajectory(Trajectory(windless.cells, windless.mesh_pos, windless.node_type, windless.world_pos, 0.01)))
    with torch.no_grad():  # a decoder that outputs +inf: the rollout is NaN from frame 3 on, handles still prescribed
        sim.model.decoder[-1].bias.fill_(float("inf"))
    out = sim.rollout(inp)
    assert not np.isfinite(out[2, ~kin]).any() and np.isnan(out[3:, ~kin]).all()
    np.testing.assert_array_equal(out[:, kin], windless.world_pos[:, kin])


def test_snapshots_are_the_weights_after_their_step(windless: Trajectory, tmp_path: Path) -> None:
    cfg = dict(train_steps=12, checkpoint_every=4, batch_size=2)
    sim = mgn(**cfg)
    sim.fit([windless], FitContext(work_dir=tmp_path / "snap", seed=2, progress=False, snapshot_every=4))
    snaps = sim.snapshots(tmp_path / "snap")
    assert [s for s, _ in snaps] == [8, 12]  # step 4 is inside the 5-step warm-up: no weights to keep yet
    final = _params(sim)
    # an independent run of the shared trainer for 8 steps gives the weights of the step-8 snapshot
    ref = mgn(**cfg)
    with torch_threads(1):
        trainer = Trainer(ref.build_model(2), ref.config, TrainingData([windless], ref.cache, 1), 2)
        for _ in range(8):
            trainer.train_step()
    assert sim.use_snapshot(snaps[0][1]) == 8
    for a, b in zip(_params(sim), [p.detach() for p in trainer.model.state_dict().values()]):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert sim.use_snapshot(snaps[1][1]) == 12
    for a, b in zip(_params(sim), final):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert mgn(**cfg).snapshots(tmp_path / "none") == []


def test_foreign_snapshots_are_clear_errors(windless: Trajectory, tmp_path: Path) -> None:
    sim = mgn(train_steps=10)
    with pytest.raises(ClodsError, match="snapshot before fit"):
        sim.use_snapshot(tmp_path / "x.pt")
    sim.fit([windless], FitContext(work_dir=tmp_path / "a", seed=0, progress=False, snapshot_every=10))
    other = mgn(train_steps=11)
    other.fit([windless], FitContext(work_dir=tmp_path / "b", seed=0, progress=False, snapshot_every=11))
    with pytest.raises(ClodsError, match="config_digest"):
        other.use_snapshot(sim.snapshots(tmp_path / "a")[0][1])
    bad = tmp_path / "a" / "snapshots" / "step_0000010.pt"
    bad.write_bytes(b"torn")
    with pytest.raises(ClodsError, match="unreadable snapshot"):
        sim.use_snapshot(bad)


# --- device ----------------------------------------------------------------------------------------


def test_device_option_is_checked_and_does_not_change_the_model_identity(windless: Trajectory, tmp_path: Path) -> None:
    assert MgnConfig(device="cpu").digest() == MgnConfig().digest() == MgnConfig(device="cuda:1").digest()
    for bad in ("gpu", "cuda:x", "CPU", 0):
        with pytest.raises(ClodsError) as e:
            MgnConfig(device=bad).validate()
        assert e.value.where == "sim_config.mgn.device"
    if torch.cuda.is_available():
        return
    with pytest.raises(ClodsError, match="torch sees no CUDA GPU") as e:
        mgn(train_steps=8, device="cuda").fit([windless], FitContext(work_dir=tmp_path, seed=0, progress=False))
    assert e.value.where == "sim_config.mgn.device" and not (tmp_path / "mgn.ckpt").exists()


@pytest.mark.parametrize("name", ["mgn", "mgn-rollout", "bsms"])
def test_training_and_rollout_on_a_gpu_match_the_cpu(windless: Trajectory, tmp_path: Path, name: str) -> None:
    """The same seed on the CPU and on CUDA: the same initial weights, batches and noise, so losses, weights and a
    rollout agree to float32 rounding; a GPU-written checkpoint resumes on the CPU. 'mgn-rollout' trains with
    CloDS's 8-step rollout loss (eq. 8), the loss of stage 3."""
    if not torch.cuda.is_available():
        pytest.skip("the CPU/GPU agreement of a simulator needs a CUDA GPU (torch.cuda.is_available() is False); ran on an H200, README 'On a GPU'")
    cfg = dict(train_steps=20, checkpoint_every=10, batch_size=2)
    if name == "mgn-rollout":
        cfg.update(loss="rollout", rollout_length=8, rollout_start_step=0)

    def build(device: str):
        if name.startswith("mgn"):
            return mgn(**cfg, device=device)
        return build_bsms(BsmsConfig(latent_size=16, hidden_layers=1, levels=2, warmup_steps=2, num_threads=1, device=device, **cfg),
                          SimpleNamespace(scene=PINNED))  # fmt: skip

    cpu, gpu = build("cpu"), build("cuda")
    s_cpu = cpu.fit([windless], FitContext(work_dir=tmp_path / "cpu", seed=1, progress=False))
    s_gpu = gpu.fit([windless], FitContext(work_dir=tmp_path / "gpu", seed=1, progress=False))
    assert s_gpu["final_loss"] == pytest.approx(s_cpu["final_loss"], rel=1e-3)
    for a, b in zip(_params(cpu), _params(gpu)):
        torch.testing.assert_close(b.cpu(), a, rtol=1e-3, atol=1e-5)
    inp = RolloutInput.from_trajectory(windless)
    np.testing.assert_allclose(gpu.rollout(inp)[:12], cpu.rollout(inp)[:12], atol=1e-4)
    again = build("cpu")  # the GPU's checkpoint, finished: loads on the CPU and rolls out the same
    again.fit([windless], FitContext(work_dir=tmp_path / "gpu", seed=1, progress=False))
    np.testing.assert_allclose(again.rollout(inp)[:12], gpu.rollout(inp)[:12], atol=1e-5)


# --- structure pinned ----------------------------------------------------------------------------


def test_structure_at_ci_widths_is_pinned() -> None:
    """Parameter count (by formula) and one fixed-seed float64 output (committed) at the ci preset's MGN widths."""
    count, value = fixed_evaluation(build_mgn(MgnConfig(**CI_WIDTHS, message_passing_steps=4), SimpleNamespace(scene=PINNED)))
    block = mlp_parameters(3 * 64, 64, 2, 64, True) + mlp_parameters(2 * 64, 64, 2, 64, True)  # edge and node MLPs
    assert count == shared_parameters(64, 2, encoded_edges=True) + 4 * block == 176771
    assert_close(value, 9.42477075348118)
