"""HCMT processor and edge attention: softmax and attention against dense brute force, gradcheck, equivariance."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.hcmt import EdgeAttention, HcmtProcessor, scatter_softmax
from clods_bench.plugins.simulators.learned.graph import EdgeSet
from clods_bench.plugins.simulators.learned.unet_configs import HcmtConfig
from tests.plugins.simulators.graph_fixtures import jittered_mesh, make_inputs, permute_inputs, union_inputs

LATENT = 16


def processor(levels: int = 2, edge_sets: tuple[str, ...] = ("mesh",), seed: int = 0) -> HcmtProcessor:
    torch.manual_seed(seed)
    return HcmtProcessor(LATENT, 1, list(edge_sets), HcmtConfig(latent_size=LATENT, levels=levels, heads=4))


def random_edges(n: int, e: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, n, (e,), generator=g), torch.randint(0, n, (e,), generator=g)


def test_scatter_softmax_matches_dense_softmax_per_receiver():
    n, heads = 7, 3
    _, receivers = random_edges(n, 40, seed=0)
    logits = 5.0 * torch.randn(40, heads, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    alpha = scatter_softmax(logits, receivers, n)
    for node in range(n):
        mask = receivers == node
        if mask.any():
            torch.testing.assert_close(alpha[mask], torch.softmax(logits[mask], dim=0))
    sums = torch.zeros(n, heads, dtype=torch.float64).index_add(0, receivers, alpha)
    has_edges = torch.bincount(receivers, minlength=n) > 0
    torch.testing.assert_close(sums[has_edges], torch.ones(int(has_edges.sum()), heads, dtype=torch.float64))


def test_scatter_softmax_is_stable_for_huge_logits():
    receivers = torch.tensor([0, 0, 1])
    alpha = scatter_softmax(torch.tensor([[1000.0], [999.0], [-1000.0]]), receivers, 2)
    torch.testing.assert_close(alpha, torch.tensor([[1 / (1 + math.exp(-1))], [1 / (1 + math.e)], [1.0]]))


def test_edge_attention_matches_dense_brute_force():
    torch.manual_seed(0)
    n, heads, d = 6, 2, 4
    att = EdgeAttention(heads * d, heads).double()
    s, r = random_edges(n, 20, seed=2)
    x = torch.randn(n, heads * d, dtype=torch.float64)
    e = torch.randn(20, heads * d, dtype=torch.float64)
    out = att(x, EdgeSet(e, s, r))
    wq, wk, wv, wg = (m.weight.detach() for m in (att.query, att.key, att.value, att.gate))
    wb, bb = att.bias.weight.detach(), att.bias.bias.detach()
    expected = torch.zeros(n, heads * d, dtype=torch.float64)
    for node in range(n):
        edges = [i for i in range(20) if int(r[i]) == node]
        for h in range(heads):
            sl = slice(h * d, (h + 1) * d)
            logit = [float((wq[sl] @ x[node]) @ (wk[sl] @ x[s[i]])) / math.sqrt(d) + float(wb[h] @ e[i] + bb[h]) for i in edges]
            if not edges:
                continue
            w = np.exp(np.array(logit) - max(logit))
            w /= w.sum()
            for wi, i in zip(w, edges):
                expected[node, sl] += wi * (wv[sl] @ x[s[i]]) * (wg[sl] @ e[i])
    torch.testing.assert_close(out.detach(), expected)


def test_edge_attention_gradcheck():
    torch.manual_seed(1)
    att = EdgeAttention(4, 2).double()
    s, r = torch.tensor([0, 1, 2, 2, 0]), torch.tensor([1, 0, 0, 1, 2])
    x = torch.randn(3, 4, dtype=torch.float64, requires_grad=True)
    e = torch.randn(5, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x, e: att(x, EdgeSet(e, s, r)), (x, e))


def test_shape_and_finite_gradients_for_every_parameter():
    s, r, pos = jittered_mesh(8, 6, seed=0)  # 48 -> 23 -> 10 nodes, every level has edges
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=0, key="a")
    proc = processor(levels=2)
    out = proc(nodes, inputs)
    assert out.shape == nodes.shape and torch.isfinite(out).all()
    out.square().mean().backward()
    # Attention is a softmax over each receiver's edges, unchanged by a constant shift of the logits, so the
    # constant term of the edge-bias layer has gradient exactly zero (0 or rounding noise): check that, not > 0.
    shift_invariant = {id(m.bias.bias) for m in proc.modules() if isinstance(m, EdgeAttention)}
    assert shift_invariant
    for name, p in proc.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        if id(p) in shift_invariant:
            assert p.grad.abs().max() < 1e-6, name
        else:
            assert p.grad.abs().sum() > 0, name


def test_permuting_nodes_permutes_the_output():
    s, r, pos = jittered_mesh(7, 5, seed=1)
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=1, key="a")
    proc = processor(levels=3)
    perm = torch.randperm(len(pos), generator=torch.Generator().manual_seed(0))
    out = proc(nodes, inputs)
    torch.testing.assert_close(proc(*permute_inputs(nodes, inputs, perm, key="p")), out[perm], rtol=1e-4, atol=1e-4)


def test_batched_union_equals_separate_meshes():
    a, b = jittered_mesh(6, 5, seed=2), jittered_mesh(5, 4, seed=3)
    ia = make_inputs(*a[:2], a[2], LATENT, seed=2, key="a")
    ib = make_inputs(*b[:2], 3.0 * b[2], LATENT, seed=3, key="b")
    proc = processor(levels=3)
    out = proc(*union_inputs(ia, ib, key="ab"))
    torch.testing.assert_close(out, torch.cat([proc(*ia), proc(*ib)]), rtol=1e-4, atol=1e-4)


def test_contact_attention_exists_only_with_obstacles():
    flag = processor(levels=2)
    assert not any("world" in name for name, _ in flag.named_parameters())
    with_obstacles = processor(levels=2, edge_sets=("mesh", "world"))
    extra = sum(p.numel() for p in with_obstacles.parameters()) - sum(p.numel() for p in flag.parameters())
    per_block = 4 * LATENT * LATENT + LATENT * 4 + 4 + 2 * LATENT + LATENT * LATENT  # Q,K,V,gate; bias; edge LN; wider O
    assert extra == 2 * per_block  # two contact blocks, nothing else
    s, r, pos = jittered_mesh(6, 4, seed=5)
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=5, key="a", world=(np.array([0, 23]), np.array([23, 0])))
    out = with_obstacles(nodes, inputs)
    w = inputs.edge_sets["world"]
    inputs.edge_sets["world"] = w._replace(features=w.features + 1.0)
    changed = (with_obstacles(nodes, inputs) - out).abs().sum(1) > 1e-6
    assert changed.any() and not changed.all()  # contact reaches only part of the mesh through the U-Net


@pytest.mark.parametrize("field,value", [("levels", -1), ("heads", 0), ("first_blocks", -1), ("blocks_per_level", 0)])
def test_bad_config_raises(field, value):
    with pytest.raises(ClodsError, match=field):
        HcmtProcessor(LATENT, 1, ["mesh"], HcmtConfig(latent_size=LATENT, **{field: value}))


def test_heads_must_divide_latent():
    with pytest.raises(ClodsError, match="heads"):
        HcmtProcessor(LATENT, 1, ["mesh"], HcmtConfig(latent_size=LATENT, heads=3))
