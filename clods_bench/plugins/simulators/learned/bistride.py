"""Bi-stride levels as BSMS-GNN's and EvoMesh's authors build them, with BSMS's pooling weights; built once per mesh.

Facts from Eydcao/BSMS-GNN (`src/graph_wrappers/bsms_graph_wrapper.py`, `src/ops/basic.py`): per connected
component a seed, a BFS from it, and the smaller hop-parity set kept (the even one on a tie or when there is no
odd node); the kept nodes in ascending order; the coarse edges are the nonzeros of (A + I)^2 between kept nodes,
diagonal removed, in row-major order. BSMS seeds each component at the node nearest the mean of its rest
positions (the first such node in index order). Its pooling (`WeightedEdgeConv.cal_ew`): node weights w (ones on
the mesh) are spread over a node's out-edges as w / out-degree, each receiver sums what it receives (+1e-12) and
an edge's weight is its share of that sum; pooled latents are the weighted sums over in-edges, read at the kept
nodes, and the received sums at the kept nodes are the next level's w. Unpooling writes the coarse latents at the
kept nodes over zeros and sends them back along the same edges with the same weights (the transpose).

EvoMesh (`src/helpers_bistride.py`, the `MinAve` rule its flag data uses) seeds each component at the node of least
summed hop distance to the rest of it (the first on a tie) and, when the kept parity set is smaller than the
removed one by delta > 0, also keeps every (n_removed // delta + 1)-th removed node in order of hop distance
(numpy's default argsort of their depths, the removed nodes listed as the authors' code lists them: in the
iteration order of a Python set of their indices filled in ascending order, which decides ties; the indices are
numbered within the component, so a mesh in a batch gets the levels it gets alone).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.csgraph import connected_components, shortest_path

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.hierarchy import Transition, _adjacency, bfs_depth

SeedRule = Literal["nearest_centroid", "min_average"]
WEIGHT_EPS = 1e-12  # BSMS `cal_ew`: added to every node's received weight


@dataclass(frozen=True)
class BistrideLevels:
    """Levels 0 (the given graph) .. L: edges per level, kept nodes, BSMS pool/unpool maps between neighbours."""

    num_nodes: list[int]
    senders: list[torch.Tensor]  # (E_l,) int64 for l = 0..L
    receivers: list[torch.Tensor]
    kept: list[torch.Tensor]  # (V_{l+1},) ascending indices into level l, for l = 0..L-1
    pool: list[Transition]  # level l -> l+1 (BSMS weights)
    unpool: list[Transition]  # level l+1 -> l (the transpose)


def nearest_centroid_seeds(labels: np.ndarray, n_comp: int, pos: np.ndarray) -> list[int]:
    """BSMS: per component, the first node (in index order) nearest the mean of the component's positions."""
    seeds = []
    for c in range(n_comp):
        members = np.nonzero(labels == c)[0]
        centre = np.mean(pos[members], axis=0)
        seeds.append(int(members[np.argmin(np.linalg.norm(pos[members] - centre[None, :], 2, axis=-1))]))
    return seeds


def min_average_seeds(adj: sp.csr_matrix, labels: np.ndarray, n_comp: int) -> list[int]:
    """EvoMesh: per component, the first node of least summed hop distance to the component's other nodes."""
    seeds = []
    for c in range(n_comp):
        members = np.nonzero(labels == c)[0]
        hops = shortest_path(adj[members][:, members], unweighted=True, directed=False)
        seeds.append(int(members[np.argmin(hops.sum(axis=1))]))
    return seeds


def bistride_selection(adj: sp.csr_matrix, pos: np.ndarray | None, rule: SeedRule) -> np.ndarray:
    """Ascending indices of the kept nodes: per component the smaller BFS parity set (EvoMesh: topped up to half)."""
    n_comp, labels = connected_components(adj, directed=False)
    seeds = nearest_centroid_seeds(labels, n_comp, pos) if rule == "nearest_centroid" else min_average_seeds(adj, labels, n_comp)  # type: ignore[arg-type]
    depth = bfs_depth(adj, np.asarray(seeds, dtype=np.int64))  # components are disjoint: one BFS from all seeds
    kept = []
    for c in range(n_comp):
        members = np.nonzero(labels == c)[0]
        even, odd = members[depth[members] % 2 == 0], members[depth[members] % 2 == 1]
        keep, removed = (even, odd) if (len(even) <= len(odd) or len(odd) == 0) else (odd, even)
        delta = len(removed) - len(keep)
        if rule == "min_average" and delta > 0:
            local = list(set(np.searchsorted(members, removed).tolist()))  # the code's order: a set's, filled ascending,
            removed = members[np.asarray(local, dtype=np.int64)]  # of the component's own node numbers (a batch = each mesh alone)
            order = np.argsort(depth[removed].astype(np.float64))
            keep = np.concatenate([keep, removed[order[:: len(removed) // delta + 1]]])
        kept.append(keep)
    return np.sort(np.concatenate(kept)) if kept else np.zeros(0, dtype=np.int64)


def two_hop_edges(adj: sp.csr_matrix, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coarse edges (senders, receivers) in kept indexing: nonzeros of (A + I)^2 between kept nodes, no diagonal,
    sorted by sender then receiver."""
    b = adj + sp.identity(adj.shape[0], format="csr")
    c = (b @ b)[kept][:, kept].tocoo()
    off = c.row != c.col
    order = np.lexsort((c.col[off], c.row[off]))
    return c.row[off][order].astype(np.int64), c.col[off][order].astype(np.int64)


def bsms_edge_weights(senders: np.ndarray, receivers: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BSMS `cal_ew`: (edge weights (E,), received node weights (V,)) for node weights w (V,)."""
    n = len(w)
    deg = np.bincount(senders, minlength=n).astype(np.float64)
    with np.errstate(divide="ignore"):
        send = (w / deg)[senders]  # a node without out-edges sends nothing (BSMS divides by zero there, unused)
    received = np.bincount(receivers, send, minlength=n) + WEIGHT_EPS
    return send / received[receivers], received


def build_bistride(
    senders: np.ndarray, receivers: np.ndarray, num_nodes: int, mesh_pos: np.ndarray | None, levels: int,
    rule: SeedRule = "nearest_centroid", device: str | torch.device = "cpu",
) -> BistrideLevels:  # fmt: skip
    """The `levels` coarse levels of a symmetric graph (level 0); `mesh_pos` (V,D) is needed by the BSMS seed rule
    (its centroid distances are computed in `mesh_pos`'s own floating dtype, as the authors' code does with its data's)."""
    s, r = np.asarray(senders, dtype=np.int64), np.asarray(receivers, dtype=np.int64)
    where = "bi-stride levels"
    if s.shape != r.shape or s.ndim != 1:
        raise ClodsError(f"senders {s.shape} and receivers {r.shape} must be equal 1-D", where=where)
    if len(s) and (min(s.min(), r.min()) < 0 or max(s.max(), r.max()) >= num_nodes):
        raise ClodsError(f"edge indices out of range [0, {num_nodes})", where=where)
    pos = None if mesh_pos is None else np.asarray(mesh_pos)  # its own dtype: seeds on exact ties follow its rounding
    if pos is not None and not np.issubdtype(pos.dtype, np.floating):
        pos = pos.astype(np.float64)
    if rule == "nearest_centroid" and (pos is None or pos.ndim != 2 or pos.shape[0] != num_nodes):
        raise ClodsError(f"mesh_pos must be ({num_nodes}, D), got {None if pos is None else pos.shape}", where=where)
    if int(levels) != levels or levels < 0:
        raise ClodsError(f"levels must be an integer >= 0, got {levels}", where=where)

    def t(a: np.ndarray, dtype: torch.dtype = torch.int64) -> torch.Tensor:
        return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)

    out: dict[str, list] = {k: [] for k in ("num_nodes", "senders", "receivers", "kept", "pool", "unpool")}
    out["num_nodes"].append(int(num_nodes))
    out["senders"].append(t(s))
    out["receivers"].append(t(r))
    w = np.ones(num_nodes)
    for _ in range(int(levels)):
        n = len(w)
        adj = _adjacency(s, r, n)
        kept = bistride_selection(adj, pos, rule)
        ew, received = bsms_edge_weights(s, r, w)
        new = np.full(n, -1, dtype=np.int64)
        new[kept] = np.arange(len(kept))
        into = new[r] >= 0
        out["pool"].append(Transition(t(s[into]), t(new[r[into]]), t(ew[into], torch.float64), len(kept)))
        out["unpool"].append(Transition(t(new[r[into]]), t(s[into]), t(ew[into], torch.float64), n))
        s, r = two_hop_edges(adj, kept)
        w, pos = received[kept], None if pos is None else pos[kept]
        out["num_nodes"].append(len(kept))
        out["senders"].append(t(s))
        out["receivers"].append(t(r))
        out["kept"].append(t(kept))
    return BistrideLevels(**out)


class BistrideCache:
    """Bi-stride levels by topology key (built on first use, on the edges' device); least recently used dropped."""

    def __init__(self, levels: int, rule: SeedRule = "nearest_centroid", max_entries: int = 64) -> None:
        self.levels = levels
        self.rule: SeedRule = rule
        self.max_entries = max_entries
        self._store: OrderedDict[str, BistrideLevels] = OrderedDict()

    def get(self, key: str, senders: torch.Tensor, receivers: torch.Tensor, mesh_pos: torch.Tensor) -> BistrideLevels:
        """The levels of the graph identified by `key` (built from the arguments on a miss)."""
        key = f"{key}@{senders.device}"
        hit = self._store.get(key)
        if hit is None:
            hit = build_bistride(
                senders.detach().cpu().numpy(), receivers.detach().cpu().numpy(), int(mesh_pos.shape[0]),
                mesh_pos.detach().cpu().numpy(), self.levels, self.rule, device=senders.device,
            )  # fmt: skip
            self._store[key] = hit
            if len(self._store) > self.max_entries:
                self._store.popitem(last=False)
        self._store.move_to_end(key)
        return hit
