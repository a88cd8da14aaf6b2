"""HCMT-style processor: a mesh-transformer U-Net over a bi-stride hierarchy (Yu et al., ICLR 2024).

Following yuyudeep/hcmt `core_model.py`: pre-norm transformer blocks whose attention runs
over graph edges (V = V + O(attn(LN(V), LN(E))); V = V + FFN(LN(V))), queries from receivers,
keys and values from senders, values gated by a projection of the edge latent; the first
blocks at the mesh level also attend over contact ('world') edges with their own attention,
and the two results are concatenated before O. Pooling selects the kept nodes, unpooling
writes the coarse latents back over the kept nodes of the same level's skip; coarse edges are
encoded from relative positions by one MLP shared by all levels.

Where this differs from that code, on purpose: each head has one scalar logit
q.k/sqrt(d) + b(e) normalised by a softmax over each receiver's incoming edges (max-subtracted),
instead of a per-channel exp of a clipped score with no normaliser; the up path ends at the
mesh level with its own blocks. Contact attention exists only when the scene has obstacles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.blocks import make_mlp
from clods_bench.plugins.simulators.learned.graph import EdgeSet
from clods_bench.plugins.simulators.learned.hierarchy import (
    REL_FEATURE_SIZE,
    Hierarchy,
    HierarchyCache,
    relative_features,
)
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator
from clods_bench.plugins.simulators.learned.unet_configs import HcmtConfig


def scatter_softmax(logits: torch.Tensor, index: torch.Tensor, num_nodes: int) -> torch.Tensor:
    """Softmax of logits (E,H) over the edges sharing each receiver `index` (E,); max-subtracted for stability."""
    expanded = index.unsqueeze(1).expand_as(logits)
    peak = logits.new_full((num_nodes, logits.shape[1]), -math.inf).scatter_reduce(0, expanded, logits, "amax")
    ex = torch.exp(logits - peak.detach().index_select(0, index))
    total = logits.new_zeros((num_nodes, logits.shape[1])).index_add(0, index, ex)
    return ex / total.index_select(0, index)


class EdgeAttention(nn.Module):
    """Multi-head attention of each receiver over its incoming edges, with edge bias and edge-gated values."""

    def __init__(self, latent: int, heads: int) -> None:
        super().__init__()
        if latent % heads:
            raise ClodsError(f"latent {latent} is not divisible by heads {heads}", where="sim_config.hcmt.heads")
        self.heads, self.head_size = heads, latent // heads
        self.query = nn.Linear(latent, latent, bias=False)
        self.key = nn.Linear(latent, latent, bias=False)
        self.value = nn.Linear(latent, latent, bias=False)
        self.gate = nn.Linear(latent, latent, bias=False)
        self.bias = nn.Linear(latent, heads)

    def forward(self, x: torch.Tensor, edges: EdgeSet) -> torch.Tensor:
        """Attention output (V, latent) for node latents x (V, latent) and edge latents (E, latent)."""
        n, shape = x.shape[0], (-1, self.heads, self.head_size)
        s, r = edges.senders, edges.receivers
        q = self.query(x).view(shape).index_select(0, r)
        k = self.key(x).view(shape).index_select(0, s)
        logits = (q * k).sum(-1) / math.sqrt(self.head_size) + self.bias(edges.features)  # (E,H)
        alpha = scatter_softmax(logits, r, n)
        msg = self.value(x).view(shape).index_select(0, s) * self.gate(edges.features).view(shape) * alpha.unsqueeze(2)
        return x.new_zeros((n, self.heads, self.head_size)).index_add(0, r, msg).reshape(n, -1)


class TransformerBlock(nn.Module):
    """Pre-norm graph-transformer block attending over one or more edge sets."""

    def __init__(self, latent: int, heads: int, hidden_layers: int, edge_sets: Sequence[str]) -> None:
        super().__init__()
        self.edge_names = list(edge_sets)
        self.node_norm = nn.LayerNorm(latent)
        self.edge_norms = nn.ModuleDict({n: nn.LayerNorm(latent) for n in self.edge_names})
        self.attention = nn.ModuleDict({n: EdgeAttention(latent, heads) for n in self.edge_names})
        self.out = nn.Linear(latent * len(self.edge_names), latent, bias=False)
        self.ffn_norm = nn.LayerNorm(latent)
        self.ffn = make_mlp(latent, latent, hidden_layers, latent, layer_norm=False)

    def forward(self, x: torch.Tensor, sets: dict[str, EdgeSet]) -> torch.Tensor:
        """x + O(attention) then + FFN, each on layer-normalised inputs."""
        y = self.node_norm(x)
        parts = []
        for name in self.edge_names:
            es = sets[name]
            parts.append(self.attention[name](y, es._replace(features=self.edge_norms[name](es.features))))
        x = x + self.out(torch.cat(parts, dim=1))
        return x + self.ffn(self.ffn_norm(x))


class HcmtProcessor(nn.Module):
    """Node latents (V,L) -> (V,L) through contact blocks and the hierarchical mesh-transformer U-Net."""

    def __init__(self, latent: int, hidden_layers: int, edge_sets: Sequence[str], config: HcmtConfig | None = None) -> None:
        super().__init__()
        cfg = config or HcmtConfig()
        cfg.validate()
        self.config = cfg
        names = list(edge_sets)
        if "mesh" not in names:
            raise ClodsError(f"edge sets {names} lack 'mesh'", where="HcmtProcessor", hint="the hierarchy is built from mesh edges")
        self.first_names = names  # 'world' (contact) attention only when the scene has obstacles

        def blocks(n: int, sets: Sequence[str]) -> nn.ModuleList:
            return nn.ModuleList(TransformerBlock(latent, cfg.heads, hidden_layers, sets) for _ in range(n))

        self.first = blocks(cfg.first_blocks, names)
        self.down = nn.ModuleList(blocks(cfg.blocks_per_level, ["mesh"]) for _ in range(cfg.levels))
        self.bottom = blocks(cfg.bottom_blocks, ["mesh"])
        self.up = nn.ModuleList(blocks(cfg.blocks_per_level, ["mesh"]) for _ in range(cfg.levels))
        self.edge_encoder = make_mlp(REL_FEATURE_SIZE, latent, hidden_layers, latent)  # shared by all coarse levels
        self.hierarchies = HierarchyCache(cfg.levels)

    def _coarse_edges(self, level: int, inputs: ProcessorInputs, h: Hierarchy) -> dict[str, EdgeSet]:
        """Encoded mesh edge set of coarse `level` (>= 1) at the current positions."""
        idx = h.fine_index[level]
        s, r = h.senders[level], h.receivers[level]
        feats = relative_features(inputs.pos.index_select(0, idx), inputs.mesh_pos.index_select(0, idx), s, r, h.unit[level])
        return {"mesh": EdgeSet(self.edge_encoder(feats), s, r)}

    def forward(self, nodes: torch.Tensor, inputs: ProcessorInputs) -> torch.Tensor:
        """Updated node latents (V,L)."""
        mesh = inputs.edge_sets["mesh"]
        h = self.hierarchies.get(inputs.topology_key, mesh.senders, mesh.receivers, inputs.mesh_pos)
        x = nodes
        first_sets = {n: inputs.edge_sets[n] for n in self.first_names}
        for block in self.first:
            x = block(x, first_sets)
        sets: dict[str, EdgeSet] = {"mesh": mesh}
        skips: list[torch.Tensor] = []
        level_sets: list[dict[str, EdgeSet]] = []
        for level in range(self.config.levels):
            if level > 0:
                sets = self._coarse_edges(level, inputs, h)
            for block in self.down[level]:
                x = block(x, sets)
            skips.append(x)
            level_sets.append(sets)
            x = x.index_select(0, h.kept[level])
        if self.config.levels > 0:
            sets = self._coarse_edges(self.config.levels, inputs, h)
        for block in self.bottom:
            x = block(x, sets)
        for level in reversed(range(self.config.levels)):
            x = skips[level].index_copy(0, h.kept[level], x)
            for block in self.up[level]:
                x = block(x, level_sets[level])
        return x


def build_hcmt(config: HcmtConfig, ctx: object) -> LearnedSimulator:
    """The `hcmt` plugin object for a BuildContext's scene (world edges only if it has obstacles)."""
    return LearnedSimulator("hcmt", config, getattr(ctx, "scene"), lambda latent, hidden, names: HcmtProcessor(latent, hidden, names, config))
