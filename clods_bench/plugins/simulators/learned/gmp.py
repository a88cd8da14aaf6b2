"""Message passing on position fibres: BSMS-GNN's `GMP` and EvoMesh's `amp_base` / `amp` blocks, in PyTorch.

These blocks keep no edge latents. Every edge's input is rebuilt from node positions (its "fibre": sender minus
receiver position and norms) next to the sender's and receiver's latents; an edge MLP turns it into a message, a
sum (GMP) or a learned softmax-weighted sum (EvoMesh) per receiver aggregates, and a node MLP adds a residual.
Every MLP is `make_mlp(..., torch_style=True)`: a LayerNorm without learned parameters, as in both codes.

Facts from Eydcao/BSMS-GNN (`src/ops/basic.py`) and hbell99/EvoMesh (`src/core_model.py`): the edge MLP reads
[fibre, x_sender, x_receiver] with the fibre first; messages go to the receiver; the node MLP reads
[x, aggregate] and its output is added to x. EvoMesh's weight MLP maps a message to one logit, softmaxed over
each receiver's incoming edges, and its selection MLP maps [x, aggregate] to [keep, drop] scores.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from clods_bench.plugins.simulators.learned.blocks import aggregate, make_mlp


def fibre(pos: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor, groups: Sequence[tuple[int, int]]) -> torch.Tensor:
    """(E, D + len(groups)): pos[sender] - pos[receiver] (D columns), then the norm of each column range in `groups`."""
    d = pos.index_select(0, senders) - pos.index_select(0, receivers)
    norms = [torch.linalg.vector_norm(d[:, a:b], dim=1, keepdim=True) for a, b in groups]
    return torch.cat([d, *norms], dim=1)


def scatter_softmax(logits: torch.Tensor, index: torch.Tensor, num_nodes: int) -> torch.Tensor:
    """Softmax of logits (E,C) over the rows sharing `index` (E,), each group's maximum subtracted first."""
    idx = index.unsqueeze(1).expand_as(logits)
    peak = logits.new_full((num_nodes, logits.shape[1]), -torch.inf).scatter_reduce(0, idx, logits, "amax", include_self=True)
    e = torch.exp(logits - peak.gather(0, idx))
    return e / logits.new_zeros((num_nodes, logits.shape[1])).scatter_add(0, idx, e).gather(0, idx)


class FibreEdgeMlp(nn.Module):
    """Edge MLP on [fibre, x_sender, x_receiver], computed without building the concatenation.

    The first layer W [f, x_s, x_r] = W_f f + W_s x_s + W_r x_r: the node terms are computed once per node and
    gathered per edge (same parameters and result as the concatenation, up to rounding).
    """

    def __init__(self, fibre_size: int, latent: int, hidden_layers: int) -> None:
        super().__init__()
        self.fibre_size = fibre_size
        self.mlp = make_mlp(fibre_size + 2 * latent, latent, hidden_layers, latent, torch_style=True)

    def forward(self, x: torch.Tensor, fib: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor) -> torch.Tensor:
        """Messages (E, latent)."""
        first: nn.Linear = self.mlp[0]  # type: ignore[assignment]
        w, f, n = first.weight, self.fibre_size, x.shape[1]
        proj = x @ torch.cat([w[:, f : f + n], w[:, f + n :]], dim=0).t()  # (V, 2H)
        h = first.out_features
        y = torch.addmm(first.bias, fib, w[:, :f].t())
        y = y + proj[:, :h].index_select(0, senders) + proj[:, h:].index_select(0, receivers)
        return self.mlp[1:](y)


class Gmp(nn.Module):
    """BSMS-GNN's GMP: x + node_mlp([x, sum of edge_mlp([fibre, x_s, x_r]) per receiver])."""

    def __init__(self, latent: int, hidden_layers: int, fibre_size: int) -> None:
        super().__init__()
        self.edge = FibreEdgeMlp(fibre_size, latent, hidden_layers)
        self.node = make_mlp(2 * latent, latent, hidden_layers, latent, torch_style=True)

    def forward(self, x: torch.Tensor, fib: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor) -> torch.Tensor:
        """Updated node latents (V, latent)."""
        messages = self.edge(x, fib, senders, receivers)
        return self.node(torch.cat([x, aggregate(messages, receivers, x.shape[0])], dim=1)) + x


class ContactGmp(nn.Module):
    """A GMP over mesh edges and contact edges (BSMS-GNN 2023's `ContactGMP`): one edge MLP per set, the contact
    fibre is world-space only, the node MLP reads [x, mesh aggregate, contact aggregate]."""

    def __init__(self, latent: int, hidden_layers: int, fibre_size: int, contact_fibre_size: int) -> None:
        super().__init__()
        self.edge = FibreEdgeMlp(fibre_size, latent, hidden_layers)
        self.contact = FibreEdgeMlp(contact_fibre_size, latent, hidden_layers)
        self.node = make_mlp(3 * latent, latent, hidden_layers, latent, torch_style=True)

    def forward(
        self, x: torch.Tensor, fib: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor,
        contact_fib: torch.Tensor, contact_senders: torch.Tensor, contact_receivers: torch.Tensor,
    ) -> torch.Tensor:  # fmt: skip
        """Updated node latents (V, latent)."""
        n = x.shape[0]
        mesh = aggregate(self.edge(x, fib, senders, receivers), receivers, n)
        contact = aggregate(self.contact(x, contact_fib, contact_senders, contact_receivers), contact_receivers, n)
        return self.node(torch.cat([x, mesh, contact], dim=1)) + x


class WeightedGmp(nn.Module):
    """EvoMesh's anisotropic block (`amp_base`; with `scores`, `amp`): messages weighted by a softmax over each
    receiver's incoming edges of a learned logit; with `scores` it also scores [keep, drop] for every node."""

    def __init__(self, latent: int, hidden_layers: int, fibre_size: int, scores: bool = False) -> None:
        super().__init__()
        self.edge = FibreEdgeMlp(fibre_size, latent, hidden_layers)
        self.weight = make_mlp(latent, latent, hidden_layers, 1, layer_norm=False, torch_style=True)
        self.node = make_mlp(2 * latent, latent, hidden_layers, latent, torch_style=True)
        self.score = make_mlp(2 * latent, latent, hidden_layers, 2, layer_norm=False, torch_style=True) if scores else None

    def forward(
        self, x: torch.Tensor, fib: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """(updated latents (V, latent), edge weights (E,) summing to 1 per receiver, scores (V, 2) or None)."""
        n = x.shape[0]
        messages = self.edge(x, fib, senders, receivers)
        w = scatter_softmax(self.weight(messages), receivers, n)
        h = torch.cat([x, aggregate(messages * w, receivers, n)], dim=1)
        scores = self.score(h) if self.score is not None else None
        return self.node(h) + x, w.squeeze(1), scores
