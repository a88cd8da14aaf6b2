"""Bi-stride hierarchy: kept sets, 2-hop coarse edges and BSMS transition weights against brute-force references."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
import torch
from scipy.sparse.csgraph import connected_components

from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.hierarchy import (
    HierarchyCache,
    _adjacency,
    build_hierarchy,
    relative_features,
)
from clods_bench.plugins.simulators.learned.graph import mesh_edges
from tests.plugins.simulators.graph_fixtures import jittered_mesh


def neighbours(s: np.ndarray, r: np.ndarray, n: int) -> list[set[int]]:
    nb: list[set[int]] = [set() for _ in range(n)]
    for a, b in zip(s.tolist(), r.tolist()):
        if a != b:
            nb[a].add(b)
            nb[b].add(a)
    return nb


def reference_kept(nb: list[set[int]], pos: np.ndarray) -> list[int]:
    """BSMS selection with plain Python: per component, BFS from the node nearest its centroid, keep the smaller parity."""
    n, seen, kept = len(nb), [False] * len(nb), []
    for start in range(n):
        if seen[start]:
            continue
        comp, queue = [start], deque([start])
        seen[start] = True
        while queue:
            for m in nb[queue.popleft()]:
                if not seen[m]:
                    seen[m] = True
                    comp.append(m)
                    queue.append(m)
        centre = pos[comp].mean(axis=0)
        seed = min(comp, key=lambda i: float(np.linalg.norm(pos[i] - centre)))
        depth = {seed: 0}
        queue = deque([seed])
        while queue:
            u = queue.popleft()
            for m in nb[u]:
                if m not in depth:
                    depth[m] = depth[u] + 1
                    queue.append(m)
        even = [i for i in comp if depth[i] % 2 == 0]
        odd = [i for i in comp if depth[i] % 2 == 1]
        kept += even if (len(even) <= len(odd) or not odd) else odd
    return sorted(kept)


def reference_two_hop(nb: list[set[int]], kept: list[int]) -> set[tuple[int, int]]:
    """Coarse edges in kept indexing: pairs of distinct kept nodes at most two hops apart."""
    index = {k: i for i, k in enumerate(kept)}
    edges = set()
    for a in kept:
        reach = set(nb[a])
        for m in nb[a]:
            reach |= nb[m]
        edges |= {(index[a], index[b]) for b in reach if b in index and b != a}
    return edges


def test_levels_match_brute_force_selection_and_two_hop_edges():
    s, r, pos = jittered_mesh(9, 7, seed=0)
    h = build_hierarchy(s, r, len(pos), pos, levels=3)
    ls, lr, lpos = s, r, pos
    for level in range(3):
        nb = neighbours(ls, lr, len(lpos))
        kept = reference_kept(nb, lpos)
        assert h.kept[level].tolist() == kept
        coarse = set(zip(h.senders[level + 1].tolist(), h.receivers[level + 1].tolist()))
        assert coarse == reference_two_hop(nb, kept)
        assert len(coarse) == h.senders[level + 1].numel()  # no duplicates
        ls, lr, lpos = h.senders[level + 1].numpy(), h.receivers[level + 1].numpy(), lpos[kept]


def test_grid_properties_cover_halve_and_stay_connected():
    mesh = make_flag_mesh(12, 8)
    s, r = mesh_edges(mesh.cells)
    h = build_hierarchy(s, r, mesh.num_nodes, mesh.mesh_pos, levels=3)
    for level in range(3):
        n = h.num_nodes[level]
        nb = neighbours(h.senders[level].numpy(), h.receivers[level].numpy(), n)
        kept = set(h.kept[level].tolist())
        assert len(kept) <= 0.5 * n  # BSMS keeps the smaller parity class
        if level < 2:  # halving until (A + I)^2 makes the seed adjacent to all (then one node is kept)
            assert len(kept) >= 0.4 * n
        assert all(i in kept or nb[i] & kept for i in range(n))  # every node within one hop of a kept node
        adj = _adjacency(h.senders[level + 1].numpy(), h.receivers[level + 1].numpy(), h.num_nodes[level + 1])
        assert connected_components(adj, directed=False)[0] == 1
        assert torch.equal(h.fine_index[level + 1], h.fine_index[level][h.kept[level]])


def test_pool_weights_match_bsms_formula_and_transitions_preserve_constants():
    s, r, pos = jittered_mesh(8, 6, seed=1)
    h = build_hierarchy(s, r, len(pos), pos, levels=2)
    w = np.ones(len(pos))
    ls, lr = s, r
    for level in range(2):
        n, nc = h.num_nodes[level], h.num_nodes[level + 1]
        deg = np.bincount(ls, minlength=n)
        dense = np.zeros((n, n))  # BSMS cal_ew, one edge at a time
        for a, b in zip(ls.tolist(), lr.tolist()):
            dense[b, a] = w[a] / deg[a]
        received = dense.sum(axis=1)
        dense /= received[:, None]
        kept = h.kept[level].numpy()
        pool = np.zeros((nc, n))
        np.add.at(pool, (h.pool[level].dst.numpy(), h.pool[level].src.numpy()), h.pool[level].weight.numpy())
        np.testing.assert_allclose(pool, dense[kept], rtol=1e-6, atol=1e-7)
        x = torch.randn(n, 3)
        np.testing.assert_allclose(h.pool[level].apply(x).numpy(), dense[kept] @ x.numpy(), rtol=1e-5, atol=1e-5)
        ones = torch.ones(n, 2)
        torch.testing.assert_close(h.pool[level].apply(ones), torch.ones(nc, 2))
        torch.testing.assert_close(h.unpool[level].apply(torch.ones(nc, 2)), ones)
        y = torch.randn(nc, 4)
        torch.testing.assert_close(h.unpool[level].apply(y)[h.kept[level]], y)  # kept nodes copy their coarse value
        w = received[kept]
        ls, lr = h.senders[level + 1].numpy(), h.receivers[level + 1].numpy()


def test_disjoint_union_is_union_of_hierarchies():
    a = jittered_mesh(7, 5, seed=2)
    b = jittered_mesh(6, 6, seed=3)
    b = (b[0], b[1], 10.0 * b[2])  # another scale: units are per component
    na = len(a[2])
    s = np.concatenate([a[0], b[0] + na])
    r = np.concatenate([a[1], b[1] + na])
    pos = np.concatenate([a[2], b[2]])
    hu = build_hierarchy(s, r, len(pos), pos, levels=4)
    ha = build_hierarchy(*a[:2], na, a[2], levels=4)
    hb = build_hierarchy(*b[:2], len(b[2]), b[2], levels=4)
    for level in range(4):
        ka, kb = ha.kept[level], hb.kept[level]
        assert hu.kept[level].tolist() == ka.tolist() + (kb + ha.num_nodes[level]).tolist()
        assert hu.num_nodes[level + 1] == ha.num_nodes[level + 1] + hb.num_nodes[level + 1]
    torch.testing.assert_close(hu.unit[0][:na], ha.unit[0])
    torch.testing.assert_close(hu.unit[0][na:], hb.unit[0])


def test_unit_is_component_mean_edge_length_and_features_are_scale_free():
    mesh = make_flag_mesh(5, 3, length=4.0, height=2.0)  # dx = dy = 1, diagonals sqrt(2)
    s, r = mesh_edges(mesh.cells)
    lengths = np.linalg.norm(mesh.mesh_pos[s] - mesh.mesh_pos[r], axis=1)
    h = build_hierarchy(s, r, mesh.num_nodes, mesh.mesh_pos, levels=1)
    torch.testing.assert_close(h.unit[0], torch.full((mesh.num_nodes,), float(lengths.mean())))
    mp = torch.as_tensor(mesh.mesh_pos)
    pos = torch.cat([mp, torch.zeros(len(mp), 1)], 1)
    st, rt = torch.as_tensor(s), torch.as_tensor(r)
    f1 = relative_features(pos, mp, st, rt, h.unit[0])
    f2 = relative_features(3 * pos, 3 * mp, st, rt, 3 * h.unit[0])
    torch.testing.assert_close(f1, f2)
    torch.testing.assert_close(f1[:, 3], torch.as_tensor(lengths / lengths.mean(), dtype=torch.float32))


def test_symmetric_grid_ties_do_not_depend_on_numbering():
    mesh = make_flag_mesh(6, 6, length=1.0, height=1.0)  # centroid equidistant from 4 nodes
    s, r = mesh_edges(mesh.cells)
    h = build_hierarchy(s, r, mesh.num_nodes, mesh.mesh_pos, levels=2)
    perm = np.random.default_rng(0).permutation(mesh.num_nodes)
    inv = np.argsort(perm)
    hp = build_hierarchy(inv[s], inv[r], mesh.num_nodes, mesh.mesh_pos[perm], levels=2)
    for level in range(2):
        fine = h.fine_index[level + 1].numpy()
        assert sorted(perm[hp.fine_index[level + 1].numpy()].tolist()) == sorted(fine.tolist())


def test_single_nodes_and_collapsed_levels_keep_their_value():
    h = build_hierarchy(np.array([0, 1]), np.array([1, 0]), 3, np.array([[0.0, 0.0], [1.0, 0.0], [5.0, 5.0]]), levels=3)
    assert h.num_nodes == [3, 2, 2, 2]
    x = torch.tensor([[1.0], [2.0], [7.0]])
    pooled = h.pool[0].apply(x)
    torch.testing.assert_close(pooled[1], torch.tensor([7.0]))  # isolated node pools itself
    torch.testing.assert_close(h.pool[1].apply(pooled), pooled)
    torch.testing.assert_close(h.unpool[0].apply(pooled)[2], torch.tensor([7.0]))


def test_cache_hit_returns_same_object_and_evicts_oldest():
    s, r, pos = jittered_mesh(5, 4, seed=4)
    cache = HierarchyCache(levels=2, max_entries=2)
    args = (torch.as_tensor(s), torch.as_tensor(r), torch.as_tensor(pos))
    first = cache.get("a", *args)
    assert cache.get("a", *args) is first
    cache.get("b", *args)
    cache.get("c", *args)
    assert len(cache) == 2 and cache.get("a", *args) is not first


@pytest.mark.parametrize(
    "args",
    [
        (np.array([0, 1]), np.array([1]), 2, np.zeros((2, 2)), 1),
        (np.array([0, 5]), np.array([1, 0]), 2, np.zeros((2, 2)), 1),
        (np.array([0]), np.array([1]), 2, np.zeros((3, 2)), 1),
        (np.array([0]), np.array([1]), 2, np.zeros((2, 2)), -1),
    ],
)
def test_bad_input_raises_clods_error(args):
    with pytest.raises(ClodsError):
        build_hierarchy(*args)
