"""Bi-stride levels (BSMS and EvoMesh rules) and BSMS's pooling weights against plain-Python brute force."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
import torch

from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.bistride import BistrideCache, build_bistride
from clods_bench.plugins.simulators.learned.graph import mesh_edges
from tests.plugins.simulators.graph_fixtures import jittered_mesh


def neighbours(s: np.ndarray, r: np.ndarray, n: int) -> list[set[int]]:
    nb: list[set[int]] = [set() for _ in range(n)]
    for a, b in zip(s.tolist(), r.tolist()):
        nb[a].add(b)
        nb[b].add(a)
    return nb


def hops(nb: list[set[int]], seed: int) -> dict[int, int]:
    depth, queue = {seed: 0}, deque([seed])
    while queue:
        u = queue.popleft()
        for m in sorted(nb[u]):
            if m not in depth:
                depth[m] = depth[u] + 1
                queue.append(m)
    return depth


def components(nb: list[set[int]]) -> list[list[int]]:
    seen: set[int] = set()
    out = []
    for start in range(len(nb)):
        if start not in seen:
            comp = sorted(hops(nb, start))
            seen |= set(comp)
            out.append(comp)
    return out


def brute_kept(nb: list[set[int]], pos: np.ndarray | None, rule: str) -> list[int]:
    """Per component: the seed (BSMS: first node nearest the centroid; EvoMesh: first of least summed hops), its
    BFS parity sets, the smaller kept (even on ties); EvoMesh tops it up with every k-th removed node by depth."""
    # (one component's ascending even/odd lists, as the authors' sets are filled)
    kept = []
    for comp in components(nb):
        if rule == "nearest_centroid":
            centre = np.mean(pos[comp], axis=0)  # exact ties are decided by rounding: the authors' vectorised norm
            seed = comp[int(np.argmin(np.linalg.norm(pos[comp] - centre[None, :], 2, axis=-1)))]
        else:
            seed = min(comp, key=lambda i: (sum(hops(nb, i).values()), i))
        depth = hops(nb, seed)
        even = [i for i in comp if depth[i] % 2 == 0]
        odd = [i for i in comp if depth[i] % 2 == 1]
        keep, removed = (even, odd) if len(even) <= len(odd) or not odd else (odd, even)
        delta = len(removed) - len(keep)
        if rule == "min_average" and delta > 0:
            index = {k: i for i, k in enumerate(comp)}  # the authors' list(set) order of the component's own numbers
            removed = [comp[i] for i in list(set(index[k] for k in removed))]
            order = np.argsort(np.array([depth[i] for i in removed], dtype=np.float64))
            keep = keep + [removed[k] for k in order[:: len(removed) // delta + 1]]
        kept += keep
    return sorted(kept)


def brute_two_hop(nb: list[set[int]], kept: list[int]) -> set[tuple[int, int]]:
    index = {k: i for i, k in enumerate(kept)}
    edges = set()
    for a in kept:
        reach = set(nb[a])
        for m in nb[a]:
            reach |= nb[m]
        edges |= {(index[a], index[b]) for b in reach if b in index and b != a}
    return edges


@pytest.mark.parametrize("rule", ["nearest_centroid", "min_average"])
@pytest.mark.parametrize("mesh", ["jittered", "grid", "two grids"])
def test_levels_match_brute_force(rule: str, mesh: str):
    if mesh == "jittered":
        s, r, pos = jittered_mesh(9, 6, seed=4)
    else:
        m = make_flag_mesh(8, 6)  # exact centroid ties: the first node in index order wins
        cells, pos = m.cells, m.mesh_pos
        if mesh == "two grids":
            b = make_flag_mesh(5, 4)
            cells, pos = np.concatenate([cells, b.cells + m.num_nodes]), np.concatenate([pos, b.mesh_pos + 5.0])
        s, r = mesh_edges(cells)
    h = build_bistride(s, r, len(pos), pos, 3, rule=rule)
    nb, p = neighbours(s, r, len(pos)), pos
    for level in range(3):
        kept = brute_kept(nb, p, rule)
        assert h.kept[level].tolist() == kept
        got = list(zip(h.senders[level + 1].tolist(), h.receivers[level + 1].tolist()))
        assert set(got) == brute_two_hop(nb, kept) and len(got) == len(set(got))
        assert got == sorted(got)  # sender-major order, as the authors' sparse product lists them
        nb, p = neighbours(h.senders[level + 1].numpy(), h.receivers[level + 1].numpy(), len(kept)), p[kept]


def test_bsms_pool_weights_and_unpool_transpose_against_loops():
    s, r, pos = jittered_mesh(7, 5, seed=2)
    h = build_bistride(s, r, len(pos), pos, 2)
    w = np.ones(len(pos))
    ls, lr = s, r
    for level in range(2):
        n, nc = h.num_nodes[level], h.num_nodes[level + 1]
        deg = np.zeros(n)
        for a in ls:
            deg[a] += 1
        received = np.full(n, 1e-12)
        for a, b in zip(ls, lr):
            received[b] += w[a] / deg[a]
        kept = h.kept[level].tolist()
        x = np.random.default_rng(level).standard_normal((n, 3))
        pooled = np.zeros((nc, 3))
        y = np.random.default_rng(9 + level).standard_normal((nc, 3))
        back = np.zeros((n, 3))
        for a, b in zip(ls, lr):  # BSMS: edge weight = sent share over what the receiver got, summed at kept receivers
            if b in kept:
                e = (w[a] / deg[a]) / received[b]
                pooled[kept.index(b)] += e * x[a]
                back[a] += e * y[kept.index(b)]  # unpooling: the same edges and weights, transposed
        np.testing.assert_allclose(h.pool[level].apply(torch.as_tensor(x)).numpy(), pooled, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(h.unpool[level].apply(torch.as_tensor(y)).numpy(), back, rtol=1e-12, atol=1e-14)
        w = received[kept]
        ls, lr = h.senders[level + 1].numpy(), h.receivers[level + 1].numpy()


def test_collapsed_levels_and_cache():
    m = make_flag_mesh(5, 3)
    s, r = mesh_edges(m.cells)
    h = build_bistride(s, r, m.num_nodes, m.mesh_pos, 4)
    assert h.num_nodes[-1] == 1 and len(h.senders[-1]) == 0  # pooled down to one node: a level without edges
    assert torch.equal(h.pool[-1].apply(torch.ones(1, 2, dtype=torch.float64)), torch.zeros(1, 2, dtype=torch.float64))
    cache = BistrideCache(2, max_entries=1)
    st, rt, mp = torch.as_tensor(s), torch.as_tensor(r), torch.as_tensor(m.mesh_pos)
    first = cache.get("a", st, rt, mp)
    assert cache.get("a", st, rt, mp) is first
    cache.get("b", st, rt, mp)
    assert cache.get("a", st, rt, mp) is not first


@pytest.mark.parametrize(
    "args,match",
    [
        ((np.array([0, 1]), np.array([1]), 2, np.zeros((2, 2)), 1), "equal 1-D"),
        ((np.array([0, 5]), np.array([1, 0]), 2, np.zeros((2, 2)), 1), "out of range"),
        ((np.array([0, 1]), np.array([1, 0]), 2, np.zeros((3, 2)), 1), "mesh_pos"),
        ((np.array([0, 1]), np.array([1, 0]), 2, np.zeros((2, 2)), -1), "levels"),
    ],
)
def test_bad_input_is_one_clear_error(args, match):
    with pytest.raises(ClodsError, match=match):
        build_bistride(*args)
