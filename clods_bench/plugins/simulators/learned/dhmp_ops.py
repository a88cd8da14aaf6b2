"""DHMP's selection and level transitions: Gumbel-softmax node selection, two-hop coarse edges, REDUCE/EXPAND.

Facts from the authors' public code (hbell99/EvoMesh `src/core_model.py`, the published version of DHMP; its
anisotropic block is `gmp.WeightedGmp`):
- selection is a Gumbel-softmax over a node's [keep, drop] scores with a straight-through hard sample: a node is
  kept when its noisy 'keep' score wins (or, with a keep ratio, an option of this implementation, when its noisy
  margin is among its component's top fraction), and the latents are multiplied by the hard-minus-detached-soft
  gate (1 in the forward pass, the soft sample's gradient in the backward pass) before the kept ones are taken;
- the coarse graph is the fine graph's edges and two-hop pairs (A u A^2) among the kept nodes;
- every level's anisotropic blocks see the level's edges plus one self loop per node (PyG's
  `add_remaining_self_loops`), except the bottom blocks;
- REDUCE (down) replaces each node by sum_s w_sr h_s with the level's learned weights before selection; EXPAND
  (up) writes the coarse latents over zeros at the kept nodes and sends them back along the same edges,
  transposed: h_s = sum_r w_sr h_r.
"""

from __future__ import annotations

import torch

from clods_bench.plugins.simulators.learned.blocks import aggregate

KEEP, DROP = 0, 1  # columns of the selection scores


def with_self_loops(senders: torch.Tensor, receivers: torch.Tensor, num_nodes: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The edges followed by one self loop per node (the graphs here have none of their own)."""
    loop = torch.arange(num_nodes, device=senders.device)
    return torch.cat([senders, loop]), torch.cat([receivers, loop])


def reduce(x: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """REDUCE: out[r] = sum over edges s->r of weight * x[s] (V,L)."""
    return aggregate(x.index_select(0, senders) * weight.unsqueeze(1), receivers, x.shape[0])


def expand(x: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """EXPAND, REDUCE transposed: out[s] = sum over edges s->r of weight * x[r] (V,L)."""
    return aggregate(x.index_select(0, receivers) * weight.unsqueeze(1), senders, x.shape[0])


@torch.no_grad()
def two_hop_edges_among(senders: torch.Tensor, receivers: torch.Tensor, num_nodes: int, kept: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Coarse edges in `kept` indexing: nonzeros of (A + I)^2 between kept nodes, diagonal removed, sorted by sender.

    Each pair (a, c) of kept nodes sharing a middle node m (a = m or a ~ m, likewise c) is one nonzero.
    """
    dev, k = senders.device, int(kept.shape[0])
    new = torch.full((num_nodes,), -1, dtype=torch.int64, device=dev)
    new[kept] = torch.arange(k, device=dev)
    loop = torch.arange(num_nodes, device=dev)
    end, mid = torch.cat([senders, receivers, loop]), torch.cat([receivers, senders, loop])  # A + A^T + I, as (end, middle)
    use = new[end] >= 0
    end, mid = new[end[use]], mid[use]
    order = torch.argsort(mid, stable=True)
    end, mid = end[order], mid[order]
    count = torch.bincount(mid, minlength=num_nodes)
    start = torch.cumsum(count, 0) - count
    reps = count[mid]  # every entry pairs with every entry of its middle node's group
    first = torch.repeat_interleave(torch.arange(len(end), device=dev), reps)
    offset = torch.arange(len(first), device=dev) - torch.repeat_interleave(torch.cumsum(reps, 0) - reps, reps)
    second = start[mid[first]] + offset
    a, c = end[first], end[second]
    off = a != c
    code = torch.unique(a[off] * k + c[off])
    return code // k, code % k


def gumbel_noise(shape: tuple[int, ...], generator: torch.Generator, device: torch.device, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Standard Gumbel samples -log(-log U), U drawn from `generator` in `dtype` (as `torch.rand_like` would) and
    kept off 0 and 1, where the code's would give an infinite score."""
    u = torch.rand(shape, generator=generator, dtype=dtype).clamp_(1e-10, 1.0 - 1e-7)
    return (-torch.log(-torch.log(u))).to(device)


def relaxed_keep(scores: torch.Tensor, tau: float, noise: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(hard keep mask (V,) bool, soft keep probability (V,), keep-minus-drop margin (V,)) of the Gumbel-softmax
    over [keep, drop] scores. With `noise` None (evaluation) the choice is the most probable one and the soft
    value the plain softmax."""
    logits = scores if noise is None else scores + noise
    soft = torch.softmax(logits / tau, dim=1)[:, KEEP]
    margin = logits[:, KEEP] - logits[:, DROP]
    return margin >= 0, soft, margin


def top_fraction(margin: torch.Tensor, component: torch.Tensor, ratio: float) -> torch.Tensor:
    """Keep mask (V,): in each connected component its max(1, round(ratio n)) nodes of highest `margin` (lowest index on ties)."""
    n = margin.shape[0]
    order = torch.argsort(margin.detach(), descending=True, stable=True)
    order = order[torch.argsort(component[order], stable=True)]  # by component, then margin descending
    size = torch.bincount(component)
    start = torch.cumsum(size, 0) - size
    rank = torch.empty(n, dtype=torch.int64, device=margin.device)
    rank[order] = torch.arange(n, device=margin.device) - start[component[order]]
    quota = torch.clamp(torch.round(ratio * size.to(margin.dtype)).to(torch.int64), min=1)
    return rank < quota[component]


def select_nodes(keep: torch.Tensor, soft: torch.Tensor, component: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(kept node indices (K,) ascending, straight-through gate (K,) equal to 1 with the soft value's gradient).

    A connected component with no kept node keeps its node of highest soft probability (the lowest index on a
    tie), so every level has at least one node per component and batched meshes stay independent.
    """
    n, dev = keep.shape[0], keep.device
    comps = int(component.max()) + 1 if n else 0
    has = torch.zeros(comps, dtype=torch.bool, device=dev).index_fill(0, component[keep], True)
    if not bool(has.all()):
        value = soft.detach()
        peak = value.new_full((comps,), -torch.inf).scatter_reduce(0, component, value, "amax")
        best = (value == peak[component]) & ~has[component]
        node = torch.arange(n, device=dev)
        first = torch.full((comps,), n, dtype=torch.int64, device=dev).scatter_reduce(0, component[best], node[best], "amin")
        keep = keep.clone()
        keep[first[first < n]] = True
    kept = torch.nonzero(keep).squeeze(1)
    s = soft.index_select(0, kept)
    return kept, 1.0 - s.detach() + s
