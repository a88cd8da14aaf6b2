"""DHMP-style processor: a U-Net of anisotropic layers over a hierarchy selected per input (Deng et al.).

Following the authors' public code (hbell99/EvoMesh `EvoMesh.forward`, see `dhmp_ops` for the blocks): at each
level going down, an anisotropic layer, REDUCE with its edge weights, then selection of the next level's nodes
(bi-stride on the first `fixed_levels`, learned Gumbel-softmax scores below) and the coarse graph A u A^2 among
them; anisotropic layers at the bottom; going up, EXPAND with the down pass's weights, an anisotropic layer and
the skip from the same level. Every level's edges get self loops. Level 0 uses the encoder's mesh edge latents;
a coarse level encodes relative world/mesh positions over the component's mean rest edge length (as BSMS does)
with one MLP per level; a self loop's latent is a learned vector per level.

Where this differs from that code, on purpose: in evaluation the selection is the most probable one (no Gumbel
noise), so a trained model rolls out deterministically; a connected component left without a kept node keeps its
most probable node; the training noise comes from a generator seeded by (a seed drawn at construction, the
call count), both buffers in the state dict, so a resumed run repeats an uninterrupted one; contact ('world')
edges, with obstacles, get one MeshGraphNets block at the mesh level before the U-Net.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence

import numpy as np
import torch
from scipy.sparse.csgraph import connected_components
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.blocks import GraphNetBlock, make_mlp
from clods_bench.plugins.simulators.learned.dhmp_ops import (
    AnisotropicLayer,
    expand,
    gumbel_noise,
    reduce,
    relaxed_keep,
    select_nodes,
    top_fraction,
    two_hop_edges_among,
    with_self_loops,
)
from clods_bench.plugins.simulators.learned.graph import EdgeSet
from clods_bench.plugins.simulators.learned.hierarchy import REL_FEATURE_SIZE, Hierarchy, HierarchyCache, _adjacency, relative_features
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator
from clods_bench.plugins.simulators.learned.unet_configs import DhmpConfig


class DhmpProcessor(nn.Module):
    """Node latents (V,L) -> (V,L) through the anisotropic U-Net over a per-input hierarchy."""

    def __init__(self, latent: int, hidden_layers: int, edge_sets: Sequence[str], config: DhmpConfig | None = None) -> None:
        super().__init__()
        cfg = config or DhmpConfig()
        cfg.validate()
        self.config = cfg
        names = list(edge_sets)
        if "mesh" not in names:
            raise ClodsError(f"edge sets {names} lack 'mesh'", where="DhmpProcessor", hint="the hierarchy is built from mesh edges")
        self.contact = GraphNetBlock(latent, hidden_layers, names) if len(names) > 1 else None
        self.contact_names = names
        self.down = nn.ModuleList(AnisotropicLayer(latent, hidden_layers, scores=level >= cfg.fixed_levels) for level in range(cfg.levels))
        self.bottom = nn.ModuleList(AnisotropicLayer(latent, hidden_layers) for _ in range(cfg.bottom_blocks))
        self.up = nn.ModuleList(AnisotropicLayer(latent, hidden_layers) for _ in range(cfg.levels))
        self.edge_encoders = nn.ModuleList(make_mlp(REL_FEATURE_SIZE, latent, hidden_layers, latent) for _ in range(cfg.levels))
        self.self_loops = nn.Parameter(torch.randn(cfg.levels + 1, latent))
        self.register_buffer("calls", torch.zeros((), dtype=torch.int64))  # training calls so far: temperature and noise
        self.register_buffer("noise_seed", torch.randint(0, 2**31 - 1, ()))  # from the (seeded) global RNG at build time
        self.fixed = HierarchyCache(cfg.fixed_levels)
        self._components: OrderedDict[str, torch.Tensor] = OrderedDict()
        self.last_kept: list[torch.Tensor] = []  # level-0 indices of each level's nodes in the latest call (inspection)

    @property
    def temperature(self) -> float:
        """The Gumbel-softmax temperature of the next training call."""
        cfg = self.config
        return max(cfg.tau_start * cfg.tau_decay ** int(self.calls), cfg.tau_min)

    def _component(self, key: str, senders: torch.Tensor, receivers: torch.Tensor, n: int) -> torch.Tensor:
        """Connected-component label (V,) of every mesh node, cached per topology."""
        key = f"{key}@{senders.device}"
        if key not in self._components:
            s, r = senders.detach().cpu().numpy(), receivers.detach().cpu().numpy()
            labels = connected_components(_adjacency(s, r, n), directed=False)[1]
            self._components[key] = torch.as_tensor(labels.astype(np.int64), device=senders.device)
            if len(self._components) > 64:
                self._components.popitem(last=False)
        self._components.move_to_end(key)
        return self._components[key]

    def forward(self, nodes: torch.Tensor, inputs: ProcessorInputs) -> torch.Tensor:
        """Updated node latents (V,L)."""
        cfg = self.config
        mesh = inputs.edge_sets["mesh"]
        n0 = nodes.shape[0]
        h: Hierarchy = self.fixed.get(inputs.topology_key, mesh.senders, mesh.receivers, inputs.mesh_pos)
        component = self._component(inputs.topology_key, mesh.senders, mesh.receivers, n0)
        x = nodes
        if self.contact is not None:
            x, sets = self.contact(x, {name: inputs.edge_sets[name] for name in self.contact_names})
            mesh = sets["mesh"]
        tau, generator = self.temperature, None
        if self.training:
            generator = torch.Generator().manual_seed((int(self.noise_seed) << 20) + int(self.calls))
            self.calls += 1
        fine = torch.arange(n0, device=nodes.device)
        self.last_kept = [fine]
        level_edges: list[EdgeSet] = []
        weights, skips, kept_at = [], [], []
        edges = with_self_loops(mesh, self.self_loops[0], n0)
        for level in range(cfg.levels):
            x, w, scores = self.down[level](x, edges)
            skips.append(x)
            level_edges.append(edges)
            weights.append(w)
            x = reduce(x, edges, w)
            n = x.shape[0]
            if scores is None:  # a fixed (bi-stride) level
                kept, gate = h.kept[level], None
                s, r = h.senders[level + 1], h.receivers[level + 1]
            else:
                noise = gumbel_noise(tuple(scores.shape), generator, scores.device) if generator is not None else None
                keep, soft, margin = relaxed_keep(scores, tau, noise)
                if cfg.keep_ratio is not None:
                    keep = top_fraction(margin, component, cfg.keep_ratio)
                kept, gate = select_nodes(keep, soft, component)
                s, r = two_hop_edges_among(edges.senders, edges.receivers, n, kept)  # its self loops are the I
            x = x.index_select(0, kept)
            if gate is not None:
                x = x * gate.unsqueeze(1)
            kept_at.append(kept)
            component, fine = component.index_select(0, kept), fine.index_select(0, kept)
            self.last_kept.append(fine)
            feats = relative_features(
                inputs.pos.index_select(0, fine), inputs.mesh_pos.index_select(0, fine), s, r, h.unit[0].index_select(0, fine)
            )  # fmt: skip
            edges = with_self_loops(EdgeSet(self.edge_encoders[level](feats), s, r), self.self_loops[level + 1], len(kept))
        for layer in self.bottom:
            x = layer(x, edges)[0]
        for level in reversed(range(cfg.levels)):
            coarse = skips[level].new_zeros(skips[level].shape).index_copy(0, kept_at[level], x)
            x = expand(coarse, level_edges[level], weights[level])
            x = self.up[level](x, level_edges[level])[0] + skips[level]
        return x


def build_dhmp(config: DhmpConfig, ctx: object) -> LearnedSimulator:
    """The `dhmp` plugin object for a BuildContext's scene (world edges only if it has obstacles)."""
    return LearnedSimulator("dhmp", config, getattr(ctx, "scene"), lambda latent, hidden, names: DhmpProcessor(latent, hidden, names, config))
