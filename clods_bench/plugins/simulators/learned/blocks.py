"""Graph-network building blocks shared by the learned simulators (DeepMind `core_model.py`), in PyTorch.

MLPs have `hidden_layers` hidden ReLU layers of width `latent`, then a linear output layer
and a LayerNorm (none on the decoder). Each of `message_passing_steps` residual blocks
updates every edge set from [sender, receiver, edge] latents, then the nodes from
[node, sum of incoming edge latents per edge set]; aggregation is a sum (index_add).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from clods_bench.plugins.simulators.learned.graph import EdgeSet
from clods_bench.numerics.truncated_normal import truncated_normal_


def make_mlp(
    in_size: int, latent: int, hidden_layers: int, out_size: int, layer_norm: bool = True, torch_style: bool = False
) -> nn.Sequential:
    """MLP [in -> latent x hidden_layers -> out] with ReLU between layers, optional final LayerNorm.

    Default (MeshGraphNets, Sonnet): a LayerNorm with learned scale and offset, truncated-normal weights
    (std 1/sqrt(fan_in)) and zero biases. `torch_style` (BSMS-GNN and EvoMesh's `MLP`): a LayerNorm without
    learned parameters and torch's default Linear initialisation.
    """
    layers: list[nn.Module] = []
    size = in_size
    for _ in range(hidden_layers):
        layers += [nn.Linear(size, latent), nn.ReLU()]
        size = latent
    layers.append(nn.Linear(size, out_size))
    if layer_norm:
        layers.append(nn.LayerNorm(out_size, elementwise_affine=not torch_style))
    if not torch_style:
        for m in layers:  # Sonnet's default init: truncated normal, std 1/sqrt(fan_in), zero bias
            if isinstance(m, nn.Linear):
                std = 1.0 / math.sqrt(m.in_features)
                truncated_normal_(m.weight, std=std, a=-2 * std, b=2 * std)
                nn.init.zeros_(m.bias)
    return nn.Sequential(*layers)


def aggregate(edge_features: torch.Tensor, receivers: torch.Tensor, num_nodes: int) -> torch.Tensor:
    """Sum of edge features per receiving node (unsorted segment sum)."""
    out = edge_features.new_zeros((num_nodes, edge_features.shape[1]))
    return out.index_add(0, receivers, edge_features)


class EdgeFunction(nn.Module):
    """Edge MLP on concat[sender, receiver, edge] latents, computed without building the concat.

    The first linear layer W [x_s, x_r, e] = W_s x_s + W_r x_r + W_e e: the node terms are
    computed once per node and gathered per edge, which saves most of the first layer's work
    (same parameters and result as the plain concat, up to float rounding).
    """

    def __init__(self, latent: int, edge_in: int, hidden_layers: int) -> None:
        super().__init__()
        self.node_size = latent
        self.mlp = make_mlp(2 * latent + edge_in, latent, hidden_layers, latent)

    def forward(self, nodes: torch.Tensor, edges: EdgeSet) -> torch.Tensor:
        """New edge latents (E, latent)."""
        first: nn.Linear = self.mlp[0]  # type: ignore[assignment]
        w, n = first.weight, self.node_size
        proj = nodes @ torch.cat([w[:, :n], w[:, n : 2 * n]], dim=0).t()  # (V, 2H)
        h = first.out_features
        x = torch.addmm(first.bias, edges.features, w[:, 2 * n :].t())
        x = x + proj[:, :h].index_select(0, edges.senders) + proj[:, h:].index_select(0, edges.receivers)
        return self.mlp[1:](x)


class GraphNetBlock(nn.Module):
    """One residual message-passing step over several edge sets."""

    def __init__(self, latent: int, hidden_layers: int, edge_sets: list[str]) -> None:
        super().__init__()
        self.edge_fns = nn.ModuleDict({name: EdgeFunction(latent, latent, hidden_layers) for name in edge_sets})
        self.node_fn = make_mlp(latent * (1 + len(edge_sets)), latent, hidden_layers, latent)

    def forward(self, nodes: torch.Tensor, edge_sets: dict[str, EdgeSet]) -> tuple[torch.Tensor, dict[str, EdgeSet]]:
        """Update edges, then nodes from summed incoming edges; add residuals to both."""
        new_edges = {name: self.edge_fns[name](nodes, es) for name, es in edge_sets.items()}
        parts = [nodes] + [aggregate(new_edges[name], es.receivers, nodes.shape[0]) for name, es in edge_sets.items()]
        new_nodes = self.node_fn(torch.cat(parts, dim=-1)) + nodes
        return new_nodes, {name: es._replace(features=es.features + new_edges[name]) for name, es in edge_sets.items()}
