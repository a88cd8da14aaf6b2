"""BSMS-GNN's processor: its message-passing U-Net over bi-stride levels (Cao et al., ICML 2023), in PyTorch.

As in Eydcao/BSMS-GNN's `BSGMP` (src/ops/BSMS.py): going down, at each level a GMP on that level's edges and
positions, the latents and the positions pooled with BSMS's edge weights, then the kept nodes selected; a GMP at
the bottom; going up, unpooling (the coarse latents at the kept nodes over zeros, sent back along the pooling edges
with the same weights), a GMP on that level's edges and positions, and the skip from the way down added. The
same-weights study `examples/studies/bsms_same_weights.py` runs the authors' modules beside this one.

The position a GMP's fibre is built from is the authors' `pos` input: here the rest (mesh) position and the world
position of a node side by side, (V, 2 + 3), so the fibre is their difference across an edge and its norm, or one
norm each (`fibre_norms`, the authors' Lagrangian GMP). `position_scale` says whether these positions are metres,
coordinates normalised as the authors' data pipeline does, or fibres normalised per level. With obstacles, the
level-0 GMPs also take contact edges (BSMS-GNN 2023's contact block); coarse levels have mesh edges only.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.bistride import BistrideCache, BistrideLevels
from clods_bench.plugins.simulators.learned.gmp import ContactGmp, Gmp, fibre
from clods_bench.plugins.simulators.learned.normalizer import Normalizer
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator
from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig

MESH_DIM, WORLD_DIM = 2, 3
FIBRE_GROUPS = ((0, MESH_DIM + WORLD_DIM),)  # one norm over the whole (mesh, world) difference
SEPARATE_FIBRE_GROUPS = ((0, MESH_DIM), (MESH_DIM, MESH_DIM + WORLD_DIM))  # a norm for the rest and one for the world difference
FIBRE_SIZE = MESH_DIM + WORLD_DIM + len(FIBRE_GROUPS)
CONTACT_FIBRE_SIZE = WORLD_DIM + 1


def node_positions(inputs: ProcessorInputs) -> torch.Tensor:
    """(V, 5): rest (mesh) position then world position of every node, in the world positions' dtype; the model's
    normalised coordinates where it passes them (`ProcessorInputs.positions`)."""
    if inputs.positions is not None:
        return inputs.positions
    return torch.cat([inputs.mesh_pos.to(inputs.pos.dtype), inputs.pos], dim=1)


class BsmsProcessor(nn.Module):
    """Node latents (V,L) -> (V,L) through BSMS-GNN's bi-stride message-passing U-Net."""

    encoded_edge_sets: tuple[str, ...] = ()  # messages are rebuilt from positions: no edge set is encoded

    def __init__(self, latent: int, hidden_layers: int, edge_sets: Sequence[str], config: BsmsConfig | None = None) -> None:
        super().__init__()
        cfg = config or BsmsConfig()
        cfg.validate()
        self.config = cfg
        names = list(edge_sets)
        if "mesh" not in names:
            raise ClodsError(f"edge sets {names} lack 'mesh'", where="BsmsProcessor", hint="the hierarchy is built from mesh edges")
        self.contact = "world" in names
        self.normalized_positions = cfg.position_scale == "dataset"  # read by LearnedModel
        self.groups = FIBRE_GROUPS if cfg.fibre_norms == "joint" else SEPARATE_FIBRE_GROUPS
        size = MESH_DIM + WORLD_DIM + len(self.groups)
        # 'level': running statistics of each level's fibres (down, bottom and up at a level share them)
        self.fibre_normalizers = nn.ModuleList(Normalizer(size) for _ in range(cfg.levels + 1)) if cfg.position_scale == "level" else None

        def gmp(level: int) -> nn.Module:
            if level == 0 and self.contact:
                return ContactGmp(latent, hidden_layers, size, CONTACT_FIBRE_SIZE)
            return Gmp(latent, hidden_layers, size)

        self.down = nn.ModuleList(gmp(level) for level in range(cfg.levels))
        self.bottom = gmp(cfg.levels)
        self.up = nn.ModuleList(gmp(level) for level in range(cfg.levels))  # indexed by level, like `down`
        self.levels = BistrideCache(cfg.levels, "nearest_centroid")

    def _fibre(self, pos: torch.Tensor, level: int, h: BistrideLevels, inputs: ProcessorInputs) -> torch.Tensor:
        """The fibres of a level's edges, through that level's normaliser under position_scale 'level'."""
        fib = fibre(pos, h.senders[level], h.receivers[level], self.groups)
        if self.fibre_normalizers is not None:
            fib = self.fibre_normalizers[level](fib, inputs.accumulate)
        return fib

    def _gmp(self, block: nn.Module, x: torch.Tensor, fib: torch.Tensor, level: int, h: BistrideLevels, inputs: ProcessorInputs) -> torch.Tensor:
        s, r = h.senders[level], h.receivers[level]
        for _ in range(2 if self.config.repeat_mesh_level and level in (0, self.config.levels) else 1):
            if isinstance(block, ContactGmp):
                w = inputs.edge_sets["world"]
                cfib = fibre(inputs.pos, w.senders, w.receivers, ((0, WORLD_DIM),))
                x = block(x, fib, s, r, cfib, w.senders, w.receivers)
            else:
                x = block(x, fib, s, r)
        return x

    def forward(self, nodes: torch.Tensor, inputs: ProcessorInputs) -> torch.Tensor:
        """Updated node latents (V,L)."""
        mesh = inputs.edge_sets["mesh"]
        h = self.levels.get(inputs.topology_key, mesh.senders, mesh.receivers, inputs.mesh_pos)
        x, pos = nodes, node_positions(inputs)
        skips: list[torch.Tensor] = []
        fibres: list[torch.Tensor] = []  # a level's fibres, built on the way down and read again on the way up
        for level in range(self.config.levels):
            fibres.append(self._fibre(pos, level, h, inputs))
            x = self._gmp(self.down[level], x, fibres[level], level, h, inputs)
            skips.append(x)
            x, pos = h.pool[level].apply(x), h.pool[level].apply(pos)
        x = self._gmp(self.bottom, x, self._fibre(pos, self.config.levels, h, inputs), self.config.levels, h, inputs)
        for level in reversed(range(self.config.levels)):
            x = h.unpool[level].apply(x)
            x = self._gmp(self.up[level], x, fibres[level], level, h, inputs) + skips[level]
        return x


def build_bsms(config: BsmsConfig, ctx: object) -> LearnedSimulator:
    """The `bsms` plugin object for a BuildContext's scene (contact edges at the mesh level only with obstacles)."""
    return LearnedSimulator("bsms", config, getattr(ctx, "scene"), lambda latent, hidden, names: BsmsProcessor(latent, hidden, names, config))
