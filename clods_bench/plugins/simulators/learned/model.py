"""Encode-process-decode with a pluggable processor, online normalisers and second-order integration.

Shared by every learned simulator (DeepMind `cloth_model.py` + `core_model.py`): raw node and
edge features are normalised online, encoded by MLPs to `latent_size` (the edge sets a processor names in
`encoded_edge_sets`, all when it names none; the others reach it normalised, not encoded), updated by the
simulator's processor, and decoded (no LayerNorm) to a normalised acceleration a; positions
advance as x_{t+1} = 2 x_t - x_{t-1} + a on NORMAL nodes, kinematic nodes are prescribed.
"""

from __future__ import annotations

from typing import Callable, Sequence

import torch
from torch import nn

from clods_bench.plugins.simulators.learned.blocks import make_mlp
from clods_bench.plugins.simulators.learned.graph import (
    NODE_FEATURE_SIZE,
    OUTPUT_SIZE,
    EdgeSet,
    GraphSpec,
    Topology,
    build_features,
)
from clods_bench.plugins.simulators.learned.normalizer import Normalizer
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs

POSITION_SIZE = 2 + 3  # rest (mesh) and world coordinates
OUTPUTS = ("acceleration", "velocity")

ProcessorFactory = Callable[[int, int, Sequence[str]], nn.Module]
"""Builds a processor from (latent_size, hidden_layers, edge set names)."""


class LearnedModel(nn.Module):
    """Normalisers, node/edge encoders, a processor (V,L)->(V,L) and the acceleration decoder."""

    def __init__(
        self,
        spec: GraphSpec,
        processor: nn.Module,
        latent: int = 128,
        hidden_layers: int = 2,
        max_accumulations: int = 10**6,
        output: str = "acceleration",
    ) -> None:
        """`output`: what the decoder predicts, normalised: 'acceleration' (MGN) or 'velocity' x_{t+1} - x_t
        (BSMS-GNN's and HCMT's codes)."""
        super().__init__()
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
        self.output = output
        self.spec = spec
        widths = spec.edge_widths
        self.node_normalizer = Normalizer(NODE_FEATURE_SIZE, max_accumulations)
        self.edge_normalizers = nn.ModuleDict({n: Normalizer(w, max_accumulations) for n, w in widths.items()})
        self.output_normalizer = Normalizer(OUTPUT_SIZE, max_accumulations)
        # rest (2) and world (3) coordinates normalised per coordinate, as BSMS-GNN's and EvoMesh's Lagrangian data
        # pipelines normalise `mesh_pos` and `world_pos` before their networks build fibres from them
        self.position_normalizer = Normalizer(POSITION_SIZE, max_accumulations) if getattr(processor, "normalized_positions", False) else None
        self.node_encoder = make_mlp(NODE_FEATURE_SIZE, latent, hidden_layers, latent)
        encoded = getattr(processor, "encoded_edge_sets", None)  # a processor may read some edge sets raw (None: all encoded)
        self.edge_encoders = nn.ModuleDict(
            {n: make_mlp(w, latent, hidden_layers, latent) for n, w in widths.items() if encoded is None or n in encoded}
        )
        self.processor = processor
        self.decoder = make_mlp(latent, latent, hidden_layers, OUTPUT_SIZE, layer_norm=False)

    def forward(
        self, topo: Topology, topology_key: str, pos: torch.Tensor, prev: torch.Tensor, accumulate: bool = False
    ) -> torch.Tensor:
        """Normalised acceleration (V,3) at positions x_t = `pos`, x_{t-1} = `prev`; `accumulate` updates the input normalisers."""
        raw_nodes, raw_sets = build_features(topo, pos, prev, self.spec)
        x = self.node_encoder(self.node_normalizer(raw_nodes, accumulate))
        sets = {}
        for n, es in raw_sets.items():
            features = self.edge_normalizers[n](es.features, accumulate)
            sets[n] = EdgeSet(self.edge_encoders[n](features) if n in self.edge_encoders else features, es.senders, es.receivers)

        def encode(name: str, raw: torch.Tensor) -> torch.Tensor:  # further edges of a set, e.g. HCMT's coarse levels
            return self.edge_encoders[name](self.edge_normalizers[name](raw, accumulate))

        positions = self.normalized_positions(topo, pos, accumulate)
        x = self.processor(x, ProcessorInputs(sets, pos, topo.mesh_pos, topology_key, encode, positions, bool(accumulate)))
        return self.decoder(x)

    def normalized_positions(self, topo: Topology, pos: torch.Tensor, accumulate: bool = False) -> torch.Tensor | None:
        """(V, 2 + 3) rest then world positions through the position normaliser; None when the processor reads none."""
        if self.position_normalizer is None:
            return None
        return self.position_normalizer(torch.cat([topo.mesh_pos.to(pos.dtype), pos], dim=1), accumulate)

    def acceleration(self, normalized: torch.Tensor, pos: torch.Tensor | None = None, prev: torch.Tensor | None = None) -> torch.Tensor:
        """Acceleration in metres per frame^2 from the decoder's normalised output; a velocity output needs x_t = `pos`
        and x_{t-1} = `prev` (a = v - (x_t - x_{t-1}), in their dtype)."""
        out = self.output_normalizer.inverse(normalized)
        if self.output == "acceleration":
            return out
        if pos is None or prev is None:
            raise ValueError("a velocity output needs pos and prev to give an acceleration")
        return out.to(pos.dtype) - (pos - prev)

    def step(self, topo: Topology, topology_key: str, pos: torch.Tensor, prev: torch.Tensor, kinematic_next: torch.Tensor) -> torch.Tensor:
        """x_{t+1}: 2 x_t - x_{t-1} + a on NORMAL nodes, `kinematic_next` elsewhere (V,3)."""
        return integrate(pos, prev, self.acceleration(self(topo, topology_key, pos, prev), pos, prev), topo.normal, kinematic_next)


def integrate(pos: torch.Tensor, prev: torch.Tensor, accel: torch.Tensor, normal: torch.Tensor, kinematic_next: torch.Tensor) -> torch.Tensor:
    """Second-order update x_{t+1} = 2 x_t - x_{t-1} + a where `normal`, prescribed positions elsewhere."""
    free = 2.0 * pos - prev + accel
    return torch.where(normal.unsqueeze(1), free, kinematic_next)
