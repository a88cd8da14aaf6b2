"""Bi-stride multi-level graph hierarchy (BSMS-GNN, Cao et al. ICML 2023), built once per topology.

Facts from Eydcao/BSMS-GNN (`bsms_graph_wrapper.py`, `ops/basic.py`): per connected component
the seed is the node nearest the centroid of its (mesh-space) positions; a BFS from the seed
splits nodes by hop parity and the smaller parity set is kept (even on a tie, or if there is no
odd node); coarse edges are the nonzeros of (A + I)^2 restricted to kept nodes, diagonal removed.
Pooling is BSMS's weighted transition: node weights w (ones at the finest level) are spread over
out-edges as w/deg, each receiver takes the w-weighted mean of its in-neighbours, the kept nodes
are selected and the received weight becomes the next level's w.

Deviations, each for a stated reason: a node without neighbours pools its own value (BSMS would
give it zero); unpooling copies the coarse value to its kept node and gives every removed node
the pool-weighted mean of its kept neighbours (BSMS's transposed sum drops kept nodes' own value
and is not normalised); tied seeds are broken by lexicographic position, so the hierarchy does
not depend on node numbering. Construction is numpy/scipy; `HierarchyCache` converts once per
`topology_key`.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.csgraph import connected_components

from clods_bench.errors import ClodsError

REL_FEATURE_SIZE = 3 + 1 + 2 + 1  # relative world pos + norm, relative mesh pos + norm


@dataclass(frozen=True)
class Transition:
    """A weighted bipartite map between two levels: out[dst] = sum weight * x[src]."""

    src: torch.Tensor  # (T,) int64 indices into the source level
    dst: torch.Tensor  # (T,) int64 indices into the target level
    weight: torch.Tensor  # (T,) float32
    num_dst: int

    def apply(self, x: torch.Tensor) -> torch.Tensor:
        """Map node latents (V_src, C) to (num_dst, C)."""
        msg = x.index_select(0, self.src) * self.weight.to(x.dtype).unsqueeze(1)
        return x.new_zeros((self.num_dst, x.shape[1])).index_add(0, self.dst, msg)


@dataclass(frozen=True)
class Hierarchy:
    """Levels 0 (the given graph) .. L: nodes, edges, maps between neighbouring levels.

    `kept[l]` (V_{l+1},) indexes level l; `fine_index[l]` (V_l,) indexes level 0, for gathering
    positions; `unit[l]` (V_l,) is the mean rest edge length of the node's connected component
    at level 0, the length unit of coarse edge features (scale-free, identical when batched).
    """

    num_nodes: list[int]
    senders: list[torch.Tensor]
    receivers: list[torch.Tensor]
    kept: list[torch.Tensor]
    fine_index: list[torch.Tensor]
    unit: list[torch.Tensor]
    pool: list[Transition]
    unpool: list[Transition]

    @property
    def levels(self) -> int:
        """Number of coarse levels below the given graph."""
        return len(self.kept)


def _adjacency(senders: np.ndarray, receivers: np.ndarray, n: int) -> sp.csr_matrix:
    """Symmetric 0/1 adjacency without self loops."""
    a = sp.coo_matrix((np.ones(len(senders)), (senders, receivers)), shape=(n, n)).tocsr()
    a = ((a + a.T) > 0).astype(np.float64)
    a.setdiag(0)
    a.eliminate_zeros()
    return a.tocsr()


def _seeds(pos: np.ndarray, labels: np.ndarray, n_comp: int) -> np.ndarray:
    """Per component, the node nearest the centroid; ties broken by smallest position, then index."""
    counts = np.bincount(labels, minlength=n_comp).astype(np.float64)
    centre = np.stack([np.bincount(labels, pos[:, d], n_comp) for d in range(pos.shape[1])], 1) / counts[:, None]
    dist = np.linalg.norm(pos - centre[labels], axis=1)
    best = np.full(n_comp, np.inf)
    np.minimum.at(best, labels, dist)
    tol = 1e-9 * (1.0 + float(np.abs(pos).max(initial=0.0)))
    cand = np.nonzero(dist <= best[labels] + tol)[0]
    keys = [cand] + [pos[cand, d] for d in range(pos.shape[1] - 1, -1, -1)] + [labels[cand]]
    order = cand[np.lexsort(keys)]
    first = np.ones(len(order), dtype=bool)
    first[1:] = labels[order][1:] != labels[order][:-1]
    return order[first]


def bfs_depth(adj: sp.csr_matrix, seeds: np.ndarray) -> np.ndarray:
    """Hop distance of every node from the nearest seed (-1 if unreachable)."""
    n = adj.shape[0]
    depth = np.full(n, -1, dtype=np.int64)
    depth[seeds] = 0
    frontier = np.zeros(n)
    frontier[seeds] = 1.0
    d = 0
    while frontier.any():
        d += 1
        reach = (adj @ frontier > 0) & (depth < 0)
        depth[reach] = d
        frontier = reach.astype(np.float64)
    return depth


def bistride_kept(adj: sp.csr_matrix, pos: np.ndarray) -> np.ndarray:
    """Sorted indices of the nodes BSMS keeps: per component the smaller BFS hop-parity set."""
    n_comp, labels = connected_components(adj, directed=False)
    depth = bfs_depth(adj, _seeds(pos, labels, n_comp))
    odd = depth % 2 == 1
    n_odd = np.bincount(labels, odd, n_comp)
    n_even = np.bincount(labels, ~odd, n_comp)
    keep_odd = (n_odd > 0) & (n_odd < n_even)
    return np.nonzero(odd == keep_odd[labels])[0]


def two_hop_edges(adj: sp.csr_matrix, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coarse edges (senders, receivers) in kept indexing: nonzeros of (A + I)^2 among kept, no diagonal."""
    b = adj + sp.identity(adj.shape[0], format="csr")
    c = (b @ b)[kept][:, kept].tocoo()
    off = c.row != c.col
    order = np.lexsort((c.row[off], c.col[off]))
    return c.row[off][order].astype(np.int64), c.col[off][order].astype(np.int64)


def _transitions(adj: sp.csr_matrix, kept: np.ndarray, w: np.ndarray) -> tuple[tuple, tuple, np.ndarray]:
    """BSMS pool weights (fine->coarse), normalised unpool weights (coarse->fine), next node weights."""
    n = adj.shape[0]
    coo = adj.tocoo()
    s, r = coo.row.astype(np.int64), coo.col.astype(np.int64)
    deg = np.bincount(s, minlength=n).astype(np.float64)
    send = w[s] / deg[s]
    aggr = np.bincount(r, send, minlength=n)
    ew = send / aggr[r]
    new_index = np.full(n, -1, dtype=np.int64)
    new_index[kept] = np.arange(len(kept))
    into_kept = new_index[r] >= 0
    lonely = kept[deg[kept] == 0]  # no neighbours: pool/unpool its own value
    p_src = np.concatenate([s[into_kept], lonely])
    p_dst = np.concatenate([new_index[r[into_kept]], new_index[lonely]])
    p_w = np.concatenate([ew[into_kept], np.ones(len(lonely))])
    removed = into_kept & (new_index[s] < 0)
    total = np.bincount(s[removed], ew[removed], minlength=n)
    if np.any((new_index < 0) & (total <= 0)):  # pragma: no cover - impossible by BFS parity
        raise ClodsError("a removed node has no kept neighbour", where="bistride hierarchy")
    u_src = np.concatenate([np.arange(len(kept)), new_index[r[removed]]])
    u_dst = np.concatenate([kept, s[removed]])
    u_w = np.concatenate([np.ones(len(kept)), ew[removed] / total[s[removed]]])
    next_w = np.where(deg[kept] > 0, aggr[kept], w[kept])
    return (p_src, p_dst, p_w), (u_src, u_dst, u_w), next_w


def _component_unit(adj: sp.csr_matrix, pos: np.ndarray) -> np.ndarray:
    """Per node, the mean edge length (in `pos`) of its connected component (1 where it has no edges)."""
    n_comp, labels = connected_components(adj, directed=False)
    coo = adj.tocoo()
    length = np.linalg.norm(pos[coo.row] - pos[coo.col], axis=1)
    count = np.bincount(labels[coo.row], minlength=n_comp)
    total = np.bincount(labels[coo.row], length, minlength=n_comp)
    unit = np.where((count > 0) & (total > 0), total / np.maximum(count, 1), 1.0)
    return unit[labels]


def build_hierarchy(
    senders: np.ndarray, receivers: np.ndarray, num_nodes: int, mesh_pos: np.ndarray, levels: int, device: str | torch.device = "cpu"
) -> Hierarchy:
    """The bi-stride hierarchy of a graph with `levels` coarse levels (the graph itself is level 0)."""
    senders, receivers = np.asarray(senders, dtype=np.int64), np.asarray(receivers, dtype=np.int64)
    pos = np.asarray(mesh_pos, dtype=np.float64)
    if senders.shape != receivers.shape or senders.ndim != 1:
        raise ClodsError(f"senders {senders.shape} and receivers {receivers.shape} must be equal 1-D", where="build_hierarchy")
    if len(senders) and (min(senders.min(), receivers.min()) < 0 or max(senders.max(), receivers.max()) >= num_nodes):
        raise ClodsError(f"edge indices out of range [0, {num_nodes})", where="build_hierarchy")
    if pos.ndim != 2 or pos.shape[0] != num_nodes:
        raise ClodsError(f"mesh_pos has shape {pos.shape}, expected ({num_nodes}, D)", where="build_hierarchy")
    if int(levels) != levels or levels < 0:
        raise ClodsError(f"levels must be an integer >= 0, got {levels}", where="build_hierarchy")

    def t(a: np.ndarray, dtype: torch.dtype = torch.int64) -> torch.Tensor:
        return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)

    adj = _adjacency(senders, receivers, num_nodes)
    unit0 = _component_unit(adj, pos)
    fine = np.arange(num_nodes)
    w = np.ones(num_nodes)
    out: dict[str, list] = {k: [] for k in ("num_nodes", "senders", "receivers", "kept", "fine_index", "unit", "pool", "unpool")}
    out["num_nodes"].append(num_nodes)
    out["senders"].append(t(senders))
    out["receivers"].append(t(receivers))
    out["fine_index"].append(t(fine))
    out["unit"].append(t(unit0, torch.float32))
    for _ in range(int(levels)):
        kept = bistride_kept(adj, pos[fine])
        (ps, pd, pw), (us, ud, uw), w = _transitions(adj, kept, w)
        cs, cr = two_hop_edges(adj, kept)
        n_fine, fine = adj.shape[0], fine[kept]
        adj = _adjacency(cs, cr, len(kept))
        out["num_nodes"].append(len(kept))
        out["senders"].append(t(cs))
        out["receivers"].append(t(cr))
        out["kept"].append(t(kept))
        out["fine_index"].append(t(fine))
        out["unit"].append(t(unit0[fine], torch.float32))
        out["pool"].append(Transition(t(ps), t(pd), t(pw, torch.float32), len(kept)))
        out["unpool"].append(Transition(t(us), t(ud), t(uw, torch.float32), n_fine))
    return Hierarchy(**out)


def relative_features(
    pos: torch.Tensor, mesh_pos: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor, unit: torch.Tensor
) -> torch.Tensor:
    """Edge features (E, REL_FEATURE_SIZE): sender minus receiver in world and mesh space with norms, over `unit`."""
    u = unit.to(pos.dtype).index_select(0, receivers).unsqueeze(1)
    dw = (pos.index_select(0, senders) - pos.index_select(0, receivers)) / u
    dm = (mesh_pos.index_select(0, senders) - mesh_pos.index_select(0, receivers)).to(pos.dtype) / u
    norm = torch.linalg.vector_norm
    return torch.cat([dw, norm(dw, dim=1, keepdim=True), dm, norm(dm, dim=1, keepdim=True)], dim=1)


class HierarchyCache:
    """Hierarchies by topology key, built on first use; least recently used dropped past `max_entries`."""

    def __init__(self, levels: int, max_entries: int = 64) -> None:
        self.levels = levels
        self.max_entries = max_entries
        self._store: OrderedDict[str, Hierarchy] = OrderedDict()

    def get(self, key: str, senders: torch.Tensor, receivers: torch.Tensor, mesh_pos: torch.Tensor) -> Hierarchy:
        """The hierarchy of the mesh graph identified by `key` (built from the arguments on a miss), on their device."""
        key = f"{key}@{senders.device}"
        hit = self._store.get(key)
        if hit is not None:
            self._store.move_to_end(key)
            return hit
        h = build_hierarchy(
            senders.detach().cpu().numpy(),
            receivers.detach().cpu().numpy(),
            int(mesh_pos.shape[0]),
            mesh_pos.detach().cpu().numpy(),
            self.levels,
            device=senders.device,
        )
        self._store[key] = h
        if len(self._store) > self.max_entries:
            self._store.popitem(last=False)
        return h

    def __len__(self) -> int:
        return len(self._store)
