"""DHMP's processor: EvoMesh's U-Net of anisotropic blocks over a hierarchy selected per input (Deng et al.).

As in the authors' public code (hbell99/EvoMesh `EvoMesh.forward`, with its cloth settings: `lagrangian`,
`enhance`, no position pooling): going down, at each level an anisotropic block on the level's edges plus self
loops (run twice at the mesh level), REDUCE with its edge weights, then the next level's nodes (EvoMesh's
bi-stride levels for the first `fixed_levels`, learned Gumbel-softmax selection below, whose coarse graph is
A u A^2 among the kept nodes) with their positions; anisotropic blocks at the bottom, without self loops (the first
run twice); going up, EXPAND with the down pass's weights, an anisotropic block (twice at the mesh level) and the
skip from the same level. Fibres are built from a node's rest (mesh) and world positions: their differences across
an edge and one norm each. `examples/studies/dhmp_same_weights.py` runs the authors' modules beside this one.

Where this differs from that code, on purpose: in evaluation the selection is the most probable one (no Gumbel
noise), so a trained model rolls out deterministically; a connected component left without a kept node keeps its
most probable node; the selection is per sample of a batch (the code averages the scores over a batch of one
mesh); the temperature decays per training call only; the training noise comes from a generator seeded by (a seed
drawn at construction, the call count), both buffers in the state dict, so a resumed run repeats an uninterrupted
one; the code's zero third rest coordinate (its cloth data pads the 2-D mesh positions) is left out; with
obstacles, contact edges get one BSMS contact block at the mesh level before the U-Net.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence

import numpy as np
import torch
from scipy.sparse.csgraph import connected_components
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.bistride import BistrideCache
from clods_bench.plugins.simulators.learned.bsms import CONTACT_FIBRE_SIZE, MESH_DIM, WORLD_DIM, node_positions
from clods_bench.plugins.simulators.learned.dhmp_ops import (
    expand,
    gumbel_noise,
    reduce,
    relaxed_keep,
    select_nodes,
    top_fraction,
    two_hop_edges_among,
    with_self_loops,
)
from clods_bench.plugins.simulators.learned.gmp import ContactGmp, WeightedGmp, fibre
from clods_bench.plugins.simulators.learned.hierarchy import _adjacency
from clods_bench.plugins.simulators.learned.normalizer import Normalizer
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator
from clods_bench.plugins.simulators.learned.unet_configs import DhmpConfig

FIBRE_GROUPS = ((0, MESH_DIM), (MESH_DIM, MESH_DIM + WORLD_DIM))  # a norm for the rest and one for the world difference
FIBRE_SIZE = MESH_DIM + WORLD_DIM + len(FIBRE_GROUPS)


class DhmpProcessor(nn.Module):
    """Node latents (V,L) -> (V,L) through EvoMesh's anisotropic U-Net over a per-input hierarchy."""

    encoded_edge_sets: tuple[str, ...] = ()  # messages are rebuilt from positions: no edge set is encoded

    def __init__(self, latent: int, hidden_layers: int, edge_sets: Sequence[str], config: DhmpConfig | None = None) -> None:
        super().__init__()
        cfg = config or DhmpConfig()
        cfg.validate()
        self.config = cfg
        names = list(edge_sets)
        if "mesh" not in names:
            raise ClodsError(f"edge sets {names} lack 'mesh'", where="DhmpProcessor", hint="the hierarchy is built from mesh edges")
        self.contact = ContactGmp(latent, hidden_layers, FIBRE_SIZE, CONTACT_FIBRE_SIZE) if "world" in names else None
        self.normalized_positions = cfg.position_scale == "dataset"  # read by LearnedModel
        # 'level': running statistics of each level's fibres (down, bottom and up at a level share them)
        self.fibre_normalizers = nn.ModuleList(Normalizer(FIBRE_SIZE) for _ in range(cfg.levels + 1)) if cfg.position_scale == "level" else None

        def block(scores: bool = False) -> WeightedGmp:
            return WeightedGmp(latent, hidden_layers, FIBRE_SIZE, scores)

        self.down = nn.ModuleList(block(scores=level >= cfg.fixed_levels) for level in range(cfg.levels))
        self.bottom = nn.ModuleList(block() for _ in range(cfg.bottom_blocks))
        self.up = nn.ModuleList(block() for _ in range(cfg.levels))  # indexed by level, like `down`
        self.register_buffer("calls", torch.zeros((), dtype=torch.int64))  # training calls so far: temperature and noise
        self.register_buffer("noise_seed", torch.randint(0, 2**31 - 1, ()))  # from the (seeded) global RNG at build time
        self.fixed = BistrideCache(cfg.fixed_levels, "min_average")
        self._components: OrderedDict[str, torch.Tensor] = OrderedDict()
        self.last_kept: list[torch.Tensor] = []  # level-0 indices of each level's nodes in the latest call (inspection)

    @property
    def temperature(self) -> float:
        """The Gumbel-softmax temperature of the next training call."""
        cfg = self.config
        return max(cfg.tau_start * cfg.tau_decay ** (int(self.calls) + 1), cfg.tau_min)

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

    def _select(self, scores: torch.Tensor, component: torch.Tensor, tau: float, generator: torch.Generator | None) -> tuple[torch.Tensor, torch.Tensor]:
        """(kept indices (K,), straight-through gate (K,)) from a level's [keep, drop] scores."""
        noise = gumbel_noise(tuple(scores.shape), generator, scores.device, scores.dtype) if generator is not None else None
        keep, soft, margin = relaxed_keep(scores, tau, noise)
        if self.config.keep_ratio is not None:
            keep = top_fraction(margin, component, self.config.keep_ratio)
        return select_nodes(keep, soft, component)

    def _fibre(self, pos: torch.Tensor, senders: torch.Tensor, receivers: torch.Tensor, level: int, inputs: ProcessorInputs) -> torch.Tensor:
        """The fibres of a level's edges, through that level's normaliser under position_scale 'level'."""
        fib = fibre(pos, senders, receivers, FIBRE_GROUPS)
        if self.fibre_normalizers is not None:
            fib = self.fibre_normalizers[level](fib, inputs.accumulate)
        return fib

    def forward(self, nodes: torch.Tensor, inputs: ProcessorInputs) -> torch.Tensor:
        """Updated node latents (V,L)."""
        cfg = self.config
        mesh = inputs.edge_sets["mesh"]
        n0 = nodes.shape[0]
        h = self.fixed.get(inputs.topology_key, mesh.senders, mesh.receivers, inputs.mesh_pos)
        component = self._component(inputs.topology_key, mesh.senders, mesh.receivers, n0)
        x, pos = nodes, node_positions(inputs)
        if self.contact is not None:
            w = inputs.edge_sets["world"]
            cfib = fibre(inputs.pos, w.senders, w.receivers, ((0, WORLD_DIM),))
            x = self.contact(x, fibre(pos, mesh.senders, mesh.receivers, FIBRE_GROUPS), mesh.senders, mesh.receivers, cfib, w.senders, w.receivers)
        tau, generator = self.temperature, None
        if self.training:
            generator = torch.Generator().manual_seed((int(self.noise_seed) << 20) + int(self.calls))
            self.calls += 1
        fine = torch.arange(n0, device=nodes.device)
        self.last_kept = [fine]
        s, r = mesh.senders, mesh.receivers
        skips, fibres, loops, weights, kept_at = [], [], [], [], []
        for level in range(cfg.levels):
            n = x.shape[0]
            sl, rl = with_self_loops(s, r, n)
            fib = self._fibre(pos, sl, rl, level, inputs)
            for _ in range(2 if level == 0 else 1):  # the code runs the mesh level's block twice on cloth
                x, w, scores = self.down[level](x, fib, sl, rl)
            skips.append(x)
            fibres.append(fib)  # the way up reads the same positions and edges
            loops.append((sl, rl))
            weights.append(w)
            x = reduce(x, sl, rl, w)
            if scores is None:  # a fixed (bi-stride) level
                kept = h.kept[level]
                x, pos = x.index_select(0, kept), pos.index_select(0, kept)
                s, r = h.senders[level + 1], h.receivers[level + 1]
            else:
                if level == 0 and generator is not None:  # the code samples in both runs of the block and keeps the second
                    gumbel_noise(tuple(scores.shape), generator, scores.device, scores.dtype)
                kept, gate = self._select(scores, component, tau, generator)
                x = x.index_select(0, kept) * gate.unsqueeze(1)
                pos = pos.index_select(0, kept) * gate.unsqueeze(1)  # the code gates positions too: 1, with the gate's gradient
                s, r = two_hop_edges_among(s, r, n, kept)
            kept_at.append(kept)
            component, fine = component.index_select(0, kept), fine.index_select(0, kept)
            self.last_kept.append(fine)
        if cfg.bottom_blocks:
            fib = self._fibre(pos, s, r, cfg.levels, inputs)
            for i, block in enumerate(self.bottom):
                for _ in range(2 if i == 0 else 1):  # the first bottom block runs twice, as the code does on cloth
                    x = block(x, fib, s, r)[0]
        for level in reversed(range(cfg.levels)):
            sl, rl = loops[level]
            coarse = skips[level].new_zeros(skips[level].shape).index_copy(0, kept_at[level], x)
            x = expand(coarse, sl, rl, weights[level])
            for _ in range(2 if level == 0 else 1):
                x = self.up[level](x, fibres[level], sl, rl)[0]
            x = x + skips[level]
        return x


def build_dhmp(config: DhmpConfig, ctx: object) -> LearnedSimulator:
    """The `dhmp` plugin object for a BuildContext's scene (a contact block first with obstacles)."""
    return LearnedSimulator("dhmp", config, getattr(ctx, "scene"), lambda latent, hidden, names: DhmpProcessor(latent, hidden, names, config))
