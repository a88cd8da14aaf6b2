"""BSMS-style processor: a message-passing U-Net over a bi-stride hierarchy (Cao et al., ICML 2023).

As in BSMS-GNN's `BSGMP`: at each level going down, residual message passing then pooling;
message passing at the bottom; going up, unpooling, message passing and adding the skip from
the same level. Level 0 uses the encoded edge sets it is given (mesh, and world with
obstacles); a coarse level builds its edge features from relative world/mesh positions and
their norms (BSMS's "fiber"), in units of the component's mean rest edge length, encoded by
one MLP per level. Blocks are MeshGraphNets GraphNetBlocks (edge and node residuals).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.blocks import GraphNetBlock, make_mlp
from clods_bench.plugins.simulators.learned.graph import EdgeSet
from clods_bench.plugins.simulators.learned.hierarchy import (
    REL_FEATURE_SIZE,
    Hierarchy,
    HierarchyCache,
    relative_features,
)
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator
from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig


class BsmsProcessor(nn.Module):
    """Node latents (V,L) -> (V,L) through the bi-stride message-passing U-Net."""

    def __init__(self, latent: int, hidden_layers: int, edge_sets: Sequence[str], config: BsmsConfig | None = None) -> None:
        super().__init__()
        cfg = config or BsmsConfig()
        cfg.validate()
        self.config = cfg
        names = list(edge_sets)
        if "mesh" not in names:
            raise ClodsError(f"edge sets {names} lack 'mesh'", where="BsmsProcessor", hint="the hierarchy is built from mesh edges")
        self.edge_names = names

        def blocks(level: int, n: int) -> nn.ModuleList:
            sets = names if level == 0 else ["mesh"]  # world (contact) edges exist at the mesh level only
            return nn.ModuleList(GraphNetBlock(latent, hidden_layers, sets) for _ in range(n))

        self.down = nn.ModuleList(blocks(level, cfg.blocks_per_level) for level in range(cfg.levels))
        self.bottom = blocks(cfg.levels, cfg.bottom_blocks)
        self.up = nn.ModuleList(blocks(level, cfg.blocks_per_level) for level in range(cfg.levels))
        self.edge_encoders = nn.ModuleList(make_mlp(REL_FEATURE_SIZE, latent, hidden_layers, latent) for _ in range(cfg.levels))
        self.hierarchies = HierarchyCache(cfg.levels)

    def _coarse_edges(self, level: int, inputs: ProcessorInputs, h: Hierarchy) -> dict[str, EdgeSet]:
        """Encoded mesh edge set of coarse `level` (>= 1) at the current positions."""
        idx = h.fine_index[level]
        s, r = h.senders[level], h.receivers[level]
        feats = relative_features(inputs.pos.index_select(0, idx), inputs.mesh_pos.index_select(0, idx), s, r, h.unit[level])
        return {"mesh": EdgeSet(self.edge_encoders[level - 1](feats), s, r)}

    def forward(self, nodes: torch.Tensor, inputs: ProcessorInputs) -> torch.Tensor:
        """Updated node latents (V,L)."""
        mesh = inputs.edge_sets["mesh"]
        h = self.hierarchies.get(inputs.topology_key, mesh.senders, mesh.receivers, inputs.mesh_pos)
        x = nodes
        sets: dict[str, EdgeSet] = {n: inputs.edge_sets[n] for n in self.edge_names}
        skips: list[torch.Tensor] = []
        level_sets: list[dict[str, EdgeSet]] = []
        for level in range(self.config.levels):
            if level > 0:
                sets = self._coarse_edges(level, inputs, h)
            for block in self.down[level]:
                x, sets = block(x, sets)
            skips.append(x)
            level_sets.append(sets)
            x = h.pool[level].apply(x)
        sets = self._coarse_edges(self.config.levels, inputs, h) if self.config.levels > 0 else sets
        for block in self.bottom:
            x, sets = block(x, sets)
        for level in reversed(range(self.config.levels)):
            x = h.unpool[level].apply(x)
            sets = level_sets[level]
            for block in self.up[level]:
                x, sets = block(x, sets)
            x = x + skips[level]
        return x


def build_bsms(config: BsmsConfig, ctx: object) -> LearnedSimulator:
    """The `bsms` plugin object for a BuildContext's scene (world edges only if it has obstacles)."""
    return LearnedSimulator("bsms", config, getattr(ctx, "scene"), lambda latent, hidden, names: BsmsProcessor(latent, hidden, names, config))
