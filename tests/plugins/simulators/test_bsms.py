"""BSMS processor: equivariance, batching, gradients, its U-Net wiring by brute force, and its structure pinned."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.bsms import BsmsProcessor, build_bsms
from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig
from tests.plugins.simulators.graph_fixtures import jittered_mesh, make_inputs, permute_inputs, union_inputs
from tests.plugins.simulators.structure_fixtures import CI_WIDTHS, PINNED, assert_close, fixed_evaluation, mlp_parameters, shared_parameters

LATENT = 16
AUTHORS_NETWORK = {"position_scale": "raw", "fibre_norms": "joint"}  # the authors' Eulerian GMP on the positions it is given


def processor(levels: int = 2, edge_sets: tuple[str, ...] = ("mesh",), seed: int = 0) -> BsmsProcessor:
    torch.manual_seed(seed)
    return BsmsProcessor(LATENT, 1, list(edge_sets), BsmsConfig(latent_size=LATENT, levels=levels, **AUTHORS_NETWORK))


def test_shape_and_finite_gradients_for_every_parameter():
    s, r, pos = jittered_mesh(8, 6, seed=0)  # 48 -> 23 -> 10 nodes, every level has edges
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=0, key="a")
    proc = processor(levels=2)
    out = proc(nodes, inputs)
    assert out.shape == nodes.shape and torch.isfinite(out).all()
    out.square().mean().backward()
    for name, p in proc.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, name


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


def test_dependency_pattern_matches_the_u_net_wiring():
    """With one level, node i depends on x through (A+I) U (C+I) P (A+I) + (A+I) (down, pool, bottom, unpool, up, skip);
    BSMS pools over in-edges only (P holds no node's own value) and unpools along the same edges (U = P's pattern, transposed)."""
    s, r, pos = jittered_mesh(14, 3, seed=4)
    n = len(pos)
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=4, key="a")
    nodes.requires_grad_(True)
    proc = processor(levels=1)
    out = proc(nodes, inputs)
    h = proc.levels.get("a", *inputs.edge_sets["mesh"][1:], inputs.mesh_pos)

    def dense(rows: int, cols: int, dst: torch.Tensor, src: torch.Tensor) -> np.ndarray:
        m = np.zeros((rows, cols), dtype=bool)
        m[dst.numpy(), src.numpy()] = True
        return m

    nc = h.num_nodes[1]
    fine = dense(n, n, h.receivers[0], h.senders[0]) | np.eye(n, dtype=bool)
    coarse = dense(nc, nc, h.receivers[1], h.senders[1]) | np.eye(nc, dtype=bool)
    pool = dense(nc, n, h.pool[0].dst, h.pool[0].src)
    unpool = dense(n, nc, h.unpool[0].dst, h.unpool[0].src)
    b = lambda x, y: (x.astype(int) @ y.astype(int)) > 0  # noqa: E731
    expected = b(b(b(b(fine, unpool), coarse), pool), fine) | fine
    probe = torch.randn(LATENT, generator=torch.Generator().manual_seed(0))  # a plain sum is blind to LayerNorm outputs
    for node in (0, 20, n - 1):
        (grad,) = torch.autograd.grad(out[node] @ probe, nodes, retain_graph=True)
        assert np.array_equal(grad.abs().sum(1).numpy() > 0, expected[node])
    assert expected[0].sum() > fine[0].sum() + 8  # the coarse level reaches well past the 1-ring


def test_contact_edges_only_at_the_mesh_level_and_read_from_positions():
    s, r, pos = jittered_mesh(6, 4, seed=5)
    world = (np.array([0, 23]), np.array([23, 0]))
    nodes, inputs = make_inputs(s, r, pos, LATENT, seed=5, key="a", world=world)
    proc = processor(levels=2, edge_sets=("mesh", "world"))
    contact = [n for n, _ in proc.named_parameters() if ".contact." in n]
    assert contact and all(n.startswith(("down.0.", "up.0.")) for n in contact)
    assert not any(".contact." in n for n, _ in processor(levels=2).named_parameters())
    out = proc(nodes, inputs)
    w = inputs.edge_sets["world"]
    inputs.edge_sets["world"] = w._replace(features=w.features + 1.0)  # encoded features are not read: fibres are
    torch.testing.assert_close(proc(nodes, inputs), out, rtol=0, atol=0)
    inputs.edge_sets["world"] = w._replace(senders=w.senders[:0], receivers=w.receivers[:0], features=w.features[:0])
    assert (proc(nodes, inputs) - out).abs().max() > 1e-3


@pytest.mark.parametrize("field,value", [("levels", -1), ("levels", 1.5)])
def test_bad_config_raises(field, value):
    with pytest.raises(ClodsError, match=field):
        BsmsProcessor(LATENT, 1, ["mesh"], BsmsConfig(latent_size=LATENT, **{field: value}))
    with pytest.raises(ClodsError):
        BsmsProcessor(LATENT, 1, ["world"])


def test_structure_at_ci_widths_is_pinned():
    """Parameter count (by formula: 2 levels + 1 GMPs, no edge encoder) and one fixed-seed float64 output (committed)."""
    count, value = fixed_evaluation(build_bsms(BsmsConfig(**CI_WIDTHS, levels=3, **AUTHORS_NETWORK), SimpleNamespace(scene=PINNED)))
    gmp = mlp_parameters(6 + 2 * 64, 64, 2, 64, False) + mlp_parameters(2 * 64, 64, 2, 64, False)  # fibre (5 + norm), no LN affine
    assert count == shared_parameters(64, 2, encoded_edges=False) + (2 * 3 + 1) * gmp == 252547
    assert_close(value, 38.7205266535034)
