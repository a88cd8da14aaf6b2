"""MeshGraphNets' processor: `message_passing_steps` residual GraphNetBlocks on the mesh (and world) edges.

`build_mgn` makes the `mgn` plugin object: the shared learned simulator around this processor.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from clods_bench.plugins.simulators.learned.blocks import GraphNetBlock
from clods_bench.plugins.simulators.learned.config import MgnConfig
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator


class MgnProcessor(nn.Module):
    """Node latents (V,L) -> (V,L) through a stack of GraphNetBlocks; edge latents are carried between blocks."""

    def __init__(self, latent: int, hidden_layers: int, edge_sets: Sequence[str], steps: int = 15) -> None:
        super().__init__()
        self.edge_names = list(edge_sets)
        self.blocks = nn.ModuleList(GraphNetBlock(latent, hidden_layers, self.edge_names) for _ in range(steps))

    def forward(self, nodes: torch.Tensor, inputs: ProcessorInputs) -> torch.Tensor:
        """Updated node latents (V,L)."""
        sets = {n: inputs.edge_sets[n] for n in self.edge_names}
        x = nodes
        for block in self.blocks:
            x, sets = block(x, sets)
        return x


def build_mgn(config: MgnConfig, ctx: object) -> LearnedSimulator:
    """The `mgn` plugin object for a BuildContext's scene (world edges only if it has obstacles)."""
    steps = config.message_passing_steps
    return LearnedSimulator("mgn", config, getattr(ctx, "scene"), lambda latent, hidden, names: MgnProcessor(latent, hidden, names, steps))
