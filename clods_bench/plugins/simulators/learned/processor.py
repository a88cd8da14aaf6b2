"""The processor interface shared by the learned simulators (MGN, BSMS, HCMT, DHMP, LIP-style).

All learned simulators share one encode-process-decode model and one trainer; they differ only
in the processor that maps encoded node latents to updated node latents. A processor must be a
`torch.nn.Module` whose `forward` has this signature; `ProcessorInputs` holds what it may read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import torch

from clods_bench.plugins.simulators.learned.graph import EdgeSet


@dataclass(frozen=True)
class ProcessorInputs:
    """What a processor sees besides the latents.

    `edge_sets`: encoded edge latents by name ('mesh' always; 'world' only with obstacles), each
    with senders/receivers (E,) int64 in the node indexing of `nodes` (several meshes may be
    batched as a disjoint union). `pos` (V,3) world positions at the current step and
    `mesh_pos` (V,2) rest-space positions, for processors that build coarse-level edge features.
    `topology_key` identifies the (possibly batched) static mesh topology, so a processor can
    cache per-topology structures such as a bi-stride hierarchy. `encode_edges(name, raw)` normalises and encodes
    raw features (E, width) of edge set `name` with the model's own normaliser and encoder (HCMT encodes every
    level's edges so); None where the model offers none. `positions` (V, 2 + 3): rest then world position of every
    node, each coordinate normalised by the model's position normaliser, for a processor that asks for it with a
    true class attribute `normalized_positions` (None otherwise). `accumulate`: whether this call may update
    normalisers (a processor's own statistics accumulate only then).
    """

    edge_sets: dict[str, EdgeSet]
    pos: torch.Tensor
    mesh_pos: torch.Tensor
    topology_key: str
    encode_edges: Callable[[str, torch.Tensor], torch.Tensor] | None = None
    positions: torch.Tensor | None = None
    accumulate: bool = False


class Processor(Protocol):
    """Maps node latents (V,L) to node latents (V,L); must be differentiable (it is trained)."""

    def __call__(self, nodes: torch.Tensor, inputs: ProcessorInputs) -> torch.Tensor: ...
