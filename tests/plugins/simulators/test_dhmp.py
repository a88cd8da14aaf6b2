"""DHMP processor: its level transitions against brute force, the relaxed selection's gradient, a per-input
hierarchy, its structure pinned, training."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from clods_bench.benchmark.core.interfaces import FitContext
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.dhmp import DhmpProcessor, build_dhmp
from clods_bench.plugins.simulators.learned.dhmp_ops import (
    expand,
    reduce,
    relaxed_keep,
    select_nodes,
    top_fraction,
    two_hop_edges_among,
)
from clods_bench.plugins.simulators.learned.gmp import WeightedGmp
from clods_bench.plugins.simulators.learned.hierarchy import _adjacency, two_hop_edges
from clods_bench.plugins.simulators.learned.trainer import Trainer, TrainingData
from clods_bench.plugins.simulators.learned.unet_configs import DhmpConfig
from tests.plugins.simulators.graph_fixtures import jittered_mesh, make_inputs, permute_inputs, union_inputs
from tests.plugins.simulators.structure_fixtures import CI_WIDTHS, assert_close, fixed_evaluation, mlp_parameters, shared_parameters

LATENT = 16
PINNED = SimpleNamespace(name="test-pinned", has_obstacles=False, has_handles=True)


def processor(levels: int = 3, fixed: int = 1, edge_sets: tuple[str, ...] = ("mesh",), seed: int = 0) -> DhmpProcessor:
    torch.manual_seed(seed)
    return DhmpProcessor(LATENT, 1, list(edge_sets), DhmpConfig(latent_size=LATENT, levels=levels, fixed_levels=fixed, position_scale="raw"))


# --- blocks against brute force -----------------------------------------------------------------


def test_two_hop_edges_match_brute_force_and_the_bistride_builder():
    s, r, pos = jittered_mesh(6, 4, seed=0)
    n = len(pos)
    kept = np.sort(np.random.default_rng(0).choice(n, 13, replace=False))
    got_s, got_r = two_hop_edges_among(torch.as_tensor(s), torch.as_tensor(r), n, torch.as_tensor(kept))
    got = set(zip(got_s.tolist(), got_r.tolist()))
    near = [{i} for i in range(n)]  # closed neighbourhoods
    for a, b in zip(s, r):
        near[a].add(b)
        near[b].add(a)
    want = {(i, j) for i, a in enumerate(kept) for j, c in enumerate(kept) if a != c and any(a in near[m] and c in near[m] for m in range(n))}
    assert got == want and len(got) == len(got_s)
    ref_s, ref_r = two_hop_edges(_adjacency(s, r, n), kept)
    assert got == set(zip(ref_s.tolist(), ref_r.tolist()))


def test_reduce_and_expand_on_a_toy_graph_against_loops():
    """A 4-node path plus self loops: REDUCE gathers into receivers, EXPAND sends back into senders, same weights."""
    s = torch.tensor([0, 1, 1, 2, 2, 3, 0, 1, 2, 3])
    r = torch.tensor([1, 0, 2, 1, 3, 2, 0, 1, 2, 3])
    w = torch.rand(10, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    x = torch.randn(4, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    down, up = torch.zeros(4, 3, dtype=torch.float64), torch.zeros(4, 3, dtype=torch.float64)
    for e in range(10):
        down[r[e]] += w[e] * x[s[e]]
        up[s[e]] += w[e] * x[r[e]]
    torch.testing.assert_close(reduce(x, s, r, w), down)
    torch.testing.assert_close(expand(x, s, r, w), up)
    # pooling keeps rows of REDUCE, unpooling writes them back over zeros before EXPAND
    kept = torch.tensor([1, 3])
    coarse = reduce(x, s, r, w)[kept]
    fine = torch.zeros(4, 3, dtype=torch.float64).index_copy(0, kept, coarse)
    want = torch.zeros(4, 3, dtype=torch.float64)
    for e in range(10):
        if int(r[e]) in (1, 3):
            want[s[e]] += w[e] * coarse[[1, 3].index(int(r[e]))]
    torch.testing.assert_close(expand(fine, s, r, w), want)


# --- the relaxed selection ----------------------------------------------------------------------


def test_straight_through_gate_is_one_with_the_soft_samples_gradient():
    g = torch.Generator().manual_seed(3)
    scores = torch.randn(6, 2, generator=g, dtype=torch.float64, requires_grad=True)
    noise = -torch.log(-torch.log(torch.rand(6, 2, generator=g, dtype=torch.float64)))
    tau = 0.7
    keep, soft, margin = relaxed_keep(scores, tau, noise)
    assert torch.equal(keep, (scores + noise).argmax(1) == 0)  # the Gumbel-max sample
    torch.testing.assert_close(margin, ((scores + noise)[:, 0] - (scores + noise)[:, 1]).detach(), check_stride=False)
    kept, gate = select_nodes(keep, soft, torch.zeros(6, dtype=torch.int64))
    torch.testing.assert_close(gate.detach(), torch.ones_like(gate))
    (grad,) = torch.autograd.grad(gate.sum(), scores)
    z = ((scores + noise) / tau).detach()
    q = torch.softmax(z, 1)[:, 0]
    want = torch.zeros(6, 2, dtype=torch.float64)
    want[kept, 0] = q[kept] * (1 - q[kept]) / tau  # d softmax_0 / d score_0, analytic
    want[kept, 1] = -q[kept] * (1 - q[kept]) / tau
    torch.testing.assert_close(grad, want)
    assert torch.autograd.gradcheck(lambda sc: relaxed_keep(sc, tau, noise)[1], (scores,))  # finite differences


def test_top_fraction_keeps_each_components_best_nodes_against_brute_force():
    g = torch.Generator().manual_seed(4)
    component = torch.randint(0, 4, (40,), generator=g)
    margin = torch.randn(40, generator=g)
    margin[5] = margin[6]  # a tie
    for ratio in (0.01, 0.3, 0.5, 1.0):
        keep = top_fraction(margin, component, ratio)
        for c in range(4):
            members = [i for i in range(40) if int(component[i]) == c]
            best = sorted(members, key=lambda i: (-float(margin[i]), i))[: max(1, round(ratio * len(members)))]
            assert sorted(torch.nonzero(keep & (component == c)).squeeze(1).tolist()) == sorted(best), (ratio, c)


def test_a_component_without_kept_nodes_keeps_its_most_probable_node():
    keep = torch.tensor([False, False, False, True, False])
    soft = torch.tensor([0.2, 0.4, 0.4, 0.9, 0.1], requires_grad=True)
    component = torch.tensor([0, 0, 0, 1, 2])
    kept, gate = select_nodes(keep, soft, component)
    assert kept.tolist() == [1, 3, 4]  # component 0: tie 0.4/0.4 -> lowest index; component 2: its only node
    gate.sum().backward()
    assert soft.grad.tolist() == [0, 1, 0, 1, 1]


# --- the processor ------------------------------------------------------------------------------


def test_shape_and_gradients_reach_every_parameter_including_the_selection_scores():
    s, r, pos = jittered_mesh(8, 6, seed=0)
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=0, key="a")
    proc = processor(levels=3, fixed=1)
    out = proc(nodes, inputs)
    assert out.shape == nodes.shape and torch.isfinite(out).all()
    out.square().mean().backward()
    # The edge weights are a softmax over each receiver's edges, unchanged by a constant shift of the logits, so
    # the bias of weight_fn's last layer has gradient exactly zero (0 or rounding noise): check that, not > 0.
    shift_invariant = {id(m.weight[-1].bias) for m in proc.modules() if isinstance(m, WeightedGmp)}
    assert shift_invariant
    for name, p in proc.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        if id(p) in shift_invariant:
            assert p.grad.abs().max() < 1e-6, name
        else:
            assert p.grad.abs().sum() > 0, name
    assert [n for n, _ in proc.named_parameters() if ".score." in n]  # learned levels 1 and 2 score their nodes
    assert all(layer.score is None for layer in [*proc.down[:1], *proc.bottom, *proc.up])


def test_the_hierarchy_is_selected_per_input():
    s, r, pos = jittered_mesh(10, 6, seed=1)
    proc = processor(levels=3, fixed=1).eval()
    kept = []
    for seed in range(4):
        nodes, inputs = make_inputs(s, r, pos, LATENT, seed=seed, key="a")
        a = proc(nodes, inputs)
        first = [k.clone() for k in proc.last_kept]
        torch.testing.assert_close(proc(nodes, inputs), a)  # evaluation: deterministic
        kept.append(first)
    assert all(torch.equal(k[1], kept[0][1]) for k in kept)  # the bi-stride level is the same for every input
    assert len({tuple(k[2].tolist()) for k in kept}) > 1  # the learned level is not
    proc.train()
    proc(nodes, inputs)
    one = proc.last_kept[2].clone()
    proc(nodes, inputs)
    assert not torch.equal(one, proc.last_kept[2]) and int(proc.calls) == 2  # training: a fresh Gumbel sample per call
    assert proc.temperature == pytest.approx(5.0 * 0.999**3)  # the third call's: decayed once per call, before use


def test_a_keep_ratio_fixes_the_level_sizes_but_not_the_nodes():
    s, r, pos = jittered_mesh(10, 6, seed=1)  # 60 nodes -> 29 (bi-stride) -> 14 -> 7 (ratio 0.5, half to even)
    torch.manual_seed(0)
    proc = DhmpProcessor(LATENT, 1, ["mesh"], DhmpConfig(latent_size=LATENT, levels=3, fixed_levels=1, keep_ratio=0.5, position_scale="raw")).eval()
    chosen = set()
    for seed in range(4):
        nodes, inputs = make_inputs(s, r, pos, LATENT, seed=seed, key="a")
        proc(nodes, inputs)
        sizes = [len(k) for k in proc.last_kept]
        assert sizes[2:] == [round(0.5 * sizes[1]), round(0.5 * round(0.5 * sizes[1]))]
        chosen.add(tuple(proc.last_kept[2].tolist()))
    assert len(chosen) > 1


def test_permuting_nodes_permutes_the_output():
    """With learned levels only: EvoMesh's bi-stride seeds break ties in summed hop distance by node index."""
    s, r, pos = jittered_mesh(7, 5, seed=1)
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=1, key="a")
    proc = processor(levels=3, fixed=0).eval()
    perm = torch.randperm(len(pos), generator=torch.Generator().manual_seed(0))
    out = proc(nodes, inputs)
    torch.testing.assert_close(proc(*permute_inputs(nodes, inputs, perm, key="p")), out[perm], rtol=1e-4, atol=1e-4)


def test_batched_union_equals_separate_meshes():
    a, b = jittered_mesh(6, 5, seed=2), jittered_mesh(5, 4, seed=3)
    ia = make_inputs(*a[:2], a[2], LATENT, seed=2, key="a")
    ib = make_inputs(*b[:2], 3.0 * b[2], LATENT, seed=3, key="b")
    proc = processor(levels=4, fixed=1).eval()
    out = proc(*union_inputs(ia, ib, key="ab"))
    torch.testing.assert_close(out, torch.cat([proc(*ia), proc(*ib)]), rtol=1e-4, atol=1e-4)


def test_contact_block_only_with_obstacles():
    assert processor().contact is None
    proc = processor(edge_sets=("mesh", "world"))
    s, r, pos = jittered_mesh(6, 4, seed=5)
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=5, key="a", world=(np.array([0, 23]), np.array([23, 0])))
    proc.eval()
    out = proc(nodes, inputs)
    w = inputs.edge_sets["world"]
    inputs.edge_sets["world"] = w._replace(features=w.features + 1.0)  # encoded features are not read: fibres are
    torch.testing.assert_close(proc(nodes, inputs), out, rtol=0, atol=0)
    inputs.edge_sets["world"] = w._replace(senders=w.senders[:0], receivers=w.receivers[:0], features=w.features[:0])
    assert (proc(nodes, inputs) - out).abs().max() > 1e-3


def test_structure_at_ci_widths_is_pinned():
    """Parameter counts (by formula) and fixed-seed float64 outputs (committed): the ci preset's shape (one learned
    level at the mesh), the small preset's (2 bi-stride and 2 learned levels) and the ci shape with a keep ratio."""
    def block(scores: bool) -> int:  # WeightedGmp: edge MLP on (fibre 7 + 2 latents), weight MLP, node MLP, [score MLP]
        n = mlp_parameters(7 + 128, 64, 2, 64, False) + mlp_parameters(64, 64, 2, 1, False) + mlp_parameters(128, 64, 2, 64, False)
        return n + (mlp_parameters(128, 64, 2, 2, False) if scores else 0)

    count, value = fixed_evaluation(build_dhmp(DhmpConfig(**CI_WIDTHS, levels=1, fixed_levels=0, position_scale="raw"), SimpleNamespace(scene=PINNED)))
    assert count == shared_parameters(64, 2, encoded_edges=False) + block(True) + 2 * block(False) == 156296
    assert_close(value, -39.186881796086055)
    assert_close(fixed_evaluation(build_dhmp(DhmpConfig(**CI_WIDTHS, levels=1, fixed_levels=0, keep_ratio=0.5, position_scale="raw"), SimpleNamespace(scene=PINNED)))[1], 12.5817759494111)
    count, value = fixed_evaluation(build_dhmp(DhmpConfig(**CI_WIDTHS, levels=4, fixed_levels=2, position_scale="raw"), SimpleNamespace(scene=PINNED)))
    assert count == shared_parameters(64, 2, encoded_edges=False) + 2 * block(True) + 7 * block(False) == 420752
    assert_close(value, -28.750969251279837)


@pytest.mark.parametrize("field,value", [("levels", -1), ("fixed_levels", 4), ("bottom_blocks", 0), ("tau_decay", 1.5), ("tau_min", 0.0), ("keep_ratio", 0.0)])
def test_bad_config_raises(field, value):
    with pytest.raises(ClodsError, match=field):
        DhmpProcessor(LATENT, 1, ["mesh"], DhmpConfig(**{"latent_size": LATENT, "levels": 3, field: value}))
    with pytest.raises(ClodsError):
        DhmpProcessor(LATENT, 1, ["world"])


# --- training through the shared trainer --------------------------------------------------------


@pytest.fixture(scope="module")
def waving() -> Trajectory:
    """A 6x4 flag whose free nodes swing sideways, more the farther from the pole (no solver: instant)."""
    mesh = make_flag_mesh(6, 4, length=1.0, height=0.5)
    reach = mesh.mesh_pos[:, 0:1] / mesh.mesh_pos[:, 0].max()
    t = np.arange(12)[:, None, None]
    side = np.array([0.0, 0.1, 0.0])[None, None]
    frames = mesh.rest_pos[None] + side * reach[None] * np.sin(0.4 * t)
    return Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, frames.astype(np.float32), 0.02)


def dhmp(**overrides: object):
    base = dict(latent_size=16, hidden_layers=1, levels=2, fixed_levels=1, warmup_steps=5, checkpoint_every=10**6, num_threads=1)
    return build_dhmp(DhmpConfig(**{**base, **overrides}), SimpleNamespace(scene=PINNED))


def test_one_training_step_lowers_the_loss(waving: Trajectory):
    sim = dhmp(learning_rate=1e-3, noise_std=0.0, batch_size=2)
    trainer = Trainer(sim.build_model(0), sim.config, TrainingData([waving], sim.cache, 1), seed=0)
    with torch.no_grad():
        for _ in range(5):
            trainer.accumulate_only(*trainer.sample())
    for m in trainer.model.modules():
        if hasattr(m, "max_accumulations"):
            m.max_accumulations = 0  # frozen statistics: the two losses differ by the step alone
    batch, noise = trainer.sample()
    proc = trainer.model.processor
    calls = proc.calls.clone()
    before = trainer.one_step_loss(batch, noise)
    trainer.optimizer.zero_grad()
    before.backward()
    trainer.optimizer.step()
    proc.calls.copy_(calls)  # the same Gumbel sample: the same hierarchy
    after = trainer.one_step_loss(batch, noise)
    assert float(after.detach()) < float(before.detach())


def test_interrupted_training_resumes_to_the_same_weights(waving: Trajectory, tmp_path: Path, monkeypatch):
    cfg = dict(train_steps=20, checkpoint_every=8, batch_size=2)
    full = dhmp(**cfg)
    full_stats = full.fit([waving], FitContext(work_dir=tmp_path / "full", seed=3, progress=False))
    real_step = Trainer.train_step

    def crash_at_13(self: Trainer) -> float | None:
        if self.step == 13:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(Trainer, "train_step", crash_at_13)
    with pytest.raises(KeyboardInterrupt):
        dhmp(**cfg).fit([waving], FitContext(work_dir=tmp_path / "cut", seed=3, progress=False))
    monkeypatch.setattr(Trainer, "train_step", real_step)
    again = dhmp(**cfg)
    stats = again.fit([waving], FitContext(work_dir=tmp_path / "cut", seed=3, progress=False))
    assert stats["resumed_from_step"] == 8 and stats["train_steps"] == 20
    assert stats["final_loss"] == pytest.approx(full_stats["final_loss"], rel=1e-5)
    assert int(again.model.processor.calls) == 15  # training calls after the 5 warm-up steps, restored from the checkpoint
    for (name, a), b in zip(full.model.state_dict().items(), again.model.state_dict().values()):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7, msg=name)


def test_registered_as_a_learned_simulator():
    from clods_bench.benchmark.core.registry import default_registry

    spec = default_registry().get("simulator", "dhmp")
    assert spec.learned and spec.make_config({"levels": 4}, where="sim_config.dhmp") == DhmpConfig(levels=4)
    with pytest.raises(ClodsError, match="must be <= levels"):  # checked when loaded (the 3 bi-stride levels by default)
        spec.make_config({"levels": 2}, where="sim_config.dhmp")
