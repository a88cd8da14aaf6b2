"""Fibre message-passing blocks (BSMS's GMP, its contact block, EvoMesh's weighted block) against per-edge loops."""

from __future__ import annotations

import torch

from clods_bench.plugins.simulators.learned.gmp import ContactGmp, Gmp, WeightedGmp, fibre, scatter_softmax

S = torch.tensor([0, 1, 1, 2, 2, 3, 0, 3])
R = torch.tensor([1, 0, 2, 1, 3, 2, 3, 0])


def test_fibre_is_differences_then_group_norms():
    pos = torch.randn(4, 5, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    f = fibre(pos, S, R, ((0, 2), (2, 5)))
    for e in range(len(S)):
        d = pos[S[e]] - pos[R[e]]
        torch.testing.assert_close(f[e], torch.cat([d, d[:2].norm().reshape(1), d[2:].norm().reshape(1)]))


def test_scatter_softmax_is_a_softmax_per_receiver():
    logits = torch.randn(8, 2, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 30.0  # large: needs the shift
    out = scatter_softmax(logits, R, 4)
    for node in range(4):
        into = (R == node).nonzero().squeeze(1)
        torch.testing.assert_close(out[into], torch.softmax(logits[into], dim=0))


def test_gmp_and_contact_gmp_against_loops():
    torch.manual_seed(2)
    gmp, contact = Gmp(4, 1, 3).double(), ContactGmp(4, 1, 3, 2).double()
    g = torch.Generator().manual_seed(3)
    x = torch.randn(4, 4, generator=g, dtype=torch.float64)
    f = torch.randn(8, 3, generator=g, dtype=torch.float64)
    cs, cr = torch.tensor([0, 3]), torch.tensor([3, 0])
    cf = torch.randn(2, 2, generator=g, dtype=torch.float64)
    out, out_c = gmp(x, f, S, R), contact(x, f, S, R, cf, cs, cr)
    with torch.no_grad():
        for node in range(4):
            msg = sum(gmp.edge.mlp(torch.cat([f[e], x[S[e]], x[R[e]]]))[None] for e in range(8) if R[e] == node)
            torch.testing.assert_close(out[node], x[node] + gmp.node(torch.cat([x[node], msg[0]])))
            mesh = sum(contact.edge.mlp(torch.cat([f[e], x[S[e]], x[R[e]]])) for e in range(8) if R[e] == node)
            touch = sum((contact.contact.mlp(torch.cat([cf[e], x[cs[e]], x[cr[e]]])) for e in range(2) if cr[e] == node), torch.zeros(4, dtype=torch.float64))
            torch.testing.assert_close(out_c[node], x[node] + contact.node(torch.cat([x[node], mesh, touch])))


def test_weighted_gmp_against_loops():
    torch.manual_seed(4)
    block = WeightedGmp(4, 1, 3, scores=True).double()
    g = torch.Generator().manual_seed(5)
    x = torch.randn(4, 4, generator=g, dtype=torch.float64)
    f = torch.randn(8, 3, generator=g, dtype=torch.float64)
    out, w, scores = block(x, f, S, R)
    with torch.no_grad():
        msg = [block.edge.mlp(torch.cat([f[e], x[S[e]], x[R[e]]])) for e in range(8)]
        logit = torch.stack([block.weight(m)[0] for m in msg])
        for node in range(4):
            into = [e for e in range(8) if R[e] == node]
            alpha = torch.softmax(logit[into], 0)
            torch.testing.assert_close(w[into], alpha)
            h = torch.cat([x[node], sum(a * msg[e] for a, e in zip(alpha, into))])
            torch.testing.assert_close(out[node], x[node] + block.node(h))
            torch.testing.assert_close(scores[node], block.score(h))
    assert not torch.isclose(w[0], w[1])  # 0->1 and 1->0 weigh differently: direction-aware
