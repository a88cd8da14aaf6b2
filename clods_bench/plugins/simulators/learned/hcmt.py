"""HCMT's processor (Yu et al., ICLR 2024): contact and hierarchical mesh transformers, in PyTorch.

As in yuyudeep/hcmt `core_model.py` (`HCMT`, `GraphTransformerCnt`, `GraphTransformerEdge`): pre-norm blocks
V = V + O(attn(LN(V), LN(E))); V = V + FFN(LN(V)), with a bias-free FFN and bias-free O. The attention is the
code's, channel by channel and without a softmax: for an edge s -> r and channel c,
    w_c = exp(clip(P(e)_c * K(x_s)_c * Q(x_r)_c / sqrt(d), -2, 2)),   out_r,c = sum_edges w_c V(x_s)_c G(e)_c,
with d the head size (latent / heads: heads enter only through this scale). The first blocks (CMT) attend over the
mesh edges and the contact ('world') edges with the same Q, K, V, P and G, each edge set with its own LayerNorm,
and O reads the two results side by side; without obstacles the contact half is absent (the code's is zero then).
The U-Net (HMT): a block at the mesh level on its mesh edges, then per coarse level the kept nodes selected and a
block on that level's edges, a bottom block, and going up the coarse latents written over the kept nodes of the
same level's latents from the way down and a block on that level's edges. Every level's edges, the mesh level's
included, are encoded from their raw relative world/mesh positions and norms by the model's own mesh-edge
normaliser and encoder (`ProcessorInputs.encode_edges`), as the code reuses `encoder_edge_mesh` at every level.

The levels come from `hierarchy.py` (BSMS's bi-stride selection): the code reads them (`m_ids`, `m_gs_s`, `m_gs_r`)
from its data files and has no code that builds them. `examples/studies/hcmt_same_weights.py` runs the authors'
modules beside this one on the same weights and levels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.graph import EdgeSet
from clods_bench.plugins.simulators.learned.hierarchy import HierarchyCache
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator
from clods_bench.plugins.simulators.learned.unet_configs import HcmtConfig
from clods_bench.numerics.truncated_normal import truncated_normal_

SCORE_CLIP = 2.0  # the code's tf.clip_by_value(score, -2, 2)


def sonnet_linear(in_size: int, out_size: int) -> nn.Linear:
    """Bias-free Linear with Sonnet's default initialisation (truncated normal, std 1/sqrt(fan_in)), as `snt.Linear`."""
    layer = nn.Linear(in_size, out_size, bias=False)
    std = 1.0 / math.sqrt(in_size)
    truncated_normal_(layer.weight, std=std, a=-2 * std, b=2 * std)
    return layer


class EdgeAttention(nn.Module):
    """HCMT's multi-head edge attention over one or more edge sets sharing Q, K, V, P and G (`MultiHeadAttention*`)."""

    def __init__(self, latent: int, heads: int) -> None:
        super().__init__()
        if latent % heads:
            raise ClodsError(f"latent {latent} is not divisible by heads {heads}", where="sim_config.hcmt.heads")
        self.scale = math.sqrt(latent // heads)
        self.query, self.key, self.value = (sonnet_linear(latent, latent) for _ in range(3))
        self.proj, self.gate = sonnet_linear(latent, latent), sonnet_linear(latent, latent)

    def propagate(self, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, edges: EdgeSet) -> torch.Tensor:
        """Per-channel messages of one edge set summed at the receivers (V, latent)."""
        s, r = edges.senders, edges.receivers
        score = self.proj(edges.features) * k.index_select(0, s) * q.index_select(0, r) / self.scale
        msg = v.index_select(0, s) * self.gate(edges.features) * torch.exp(score.clamp(-SCORE_CLIP, SCORE_CLIP))
        return q.new_zeros(q.shape).index_add(0, r, msg)

    def forward(self, x: torch.Tensor, edge_sets: Sequence[EdgeSet]) -> torch.Tensor:
        """Node latents x (V, latent) and normalised edge latents per set -> (V, latent * number of sets)."""
        q, k, v = self.query(x), self.key(x), self.value(x)
        return torch.cat([self.propagate(q, k, v, es) for es in edge_sets], dim=1)


def feed_forward(latent: int, hidden_layers: int) -> nn.Sequential:
    """HCMT's `FFN`: hidden_layers + 1 bias-free Linear layers of width `latent` with ReLU between (the code: 3)."""
    layers: list[nn.Module] = []
    for i in range(hidden_layers + 1):
        layers += [sonnet_linear(latent, latent)] + ([nn.ReLU()] if i < hidden_layers else [])
    return nn.Sequential(*layers)


class TransformerBlock(nn.Module):
    """`GraphTransformerEdge` (one edge set) or `GraphTransformerCnt` (mesh and contact edges)."""

    def __init__(self, latent: int, heads: int, hidden_layers: int, edge_sets: Sequence[str]) -> None:
        super().__init__()
        self.edge_names = list(edge_sets)
        self.node_norm = nn.LayerNorm(latent)
        self.edge_norms = nn.ModuleDict({n: nn.LayerNorm(latent) for n in self.edge_names})
        self.attention = EdgeAttention(latent, heads)
        self.out = sonnet_linear(latent * len(self.edge_names), latent)
        self.ffn_norm = nn.LayerNorm(latent)
        self.ffn = feed_forward(latent, hidden_layers)

    def forward(self, x: torch.Tensor, sets: dict[str, EdgeSet]) -> torch.Tensor:
        """x + O(attention) then + FFN, each on layer-normalised inputs; edge latents are not updated."""
        normed = [sets[n]._replace(features=self.edge_norms[n](sets[n].features)) for n in self.edge_names]
        x = x + self.out(self.attention(self.node_norm(x), normed))
        return x + self.ffn(self.ffn_norm(x))


def raw_mesh_features(pos: torch.Tensor, mesh_pos: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor) -> torch.Tensor:
    """(E, 7): sender minus receiver in world space and its norm, then in mesh space and its norm (`EncoderEdgeMesh`)."""
    dw = pos.index_select(0, senders) - pos.index_select(0, receivers)
    dm = (mesh_pos.index_select(0, senders) - mesh_pos.index_select(0, receivers)).to(pos.dtype)
    norm = torch.linalg.vector_norm
    return torch.cat([dw, norm(dw, dim=1, keepdim=True), dm, norm(dm, dim=1, keepdim=True)], dim=1)


class HcmtProcessor(nn.Module):
    """Node latents (V,L) -> (V,L) through the contact mesh transformer and the hierarchical mesh transformer."""

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
        self.hierarchies = HierarchyCache(cfg.levels)

    def forward(self, nodes: torch.Tensor, inputs: ProcessorInputs) -> torch.Tensor:
        """Updated node latents (V,L)."""
        if inputs.encode_edges is None:
            raise ClodsError("the model passed no edge encoder", where="HcmtProcessor", hint="HCMT encodes every level's edges with the mesh-edge encoder")
        mesh = inputs.edge_sets["mesh"]
        h = self.hierarchies.get(inputs.topology_key, mesh.senders, mesh.receivers, inputs.mesh_pos)
        x = nodes
        first_sets = {n: inputs.edge_sets[n] for n in self.first_names}
        for block in self.first:
            x = block(x, first_sets)

        def level_edges(level: int) -> dict[str, EdgeSet]:
            idx, s, r = h.fine_index[level], h.senders[level], h.receivers[level]
            feats = raw_mesh_features(inputs.pos.index_select(0, idx), inputs.mesh_pos.index_select(0, idx), s, r)
            return {"mesh": EdgeSet(inputs.encode_edges("mesh", feats), s, r)}

        skips: list[torch.Tensor] = []
        level_sets: list[dict[str, EdgeSet]] = []
        for level in range(self.config.levels):
            sets = level_edges(level)
            for block in self.down[level]:
                x = block(x, sets)
            skips.append(x)
            level_sets.append(sets)
            x = x.index_select(0, h.kept[level])
        sets = level_edges(self.config.levels)
        for block in self.bottom:
            x = block(x, sets)
        for level in reversed(range(self.config.levels)):
            x = skips[level].index_copy(0, h.kept[level], x)
            for block in self.up[level]:
                x = block(x, level_sets[level])
        return x


def build_hcmt(config: HcmtConfig, ctx: object) -> LearnedSimulator:
    """The `hcmt` plugin object for a BuildContext's scene (contact edges only if it has obstacles)."""
    return LearnedSimulator("hcmt", config, getattr(ctx, "scene"), lambda latent, hidden, names: HcmtProcessor(latent, hidden, names, config))
