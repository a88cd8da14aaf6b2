"""Options of the LIP-style particle simulator: the shared learned options plus its radius graph and depth.

Kept free of torch so the plugin registry can load them without importing a model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.config import LearnedConfig


@dataclass(frozen=True)
class LipConfig(LearnedConfig):
    """GNS-style particle simulator (Sanchez-Gonzalez et al. 2020) as LIP's dynamics model: no mesh edges.

    Defaults: GNS's 10 message-passing steps on latent 128; the radius, scale-free, reaches the second ring of
    neighbours on a regular grid (about 20 nodes), as GNS's radii do on its particle sets.
    """

    message_passing_steps: int = 10
    """Residual message-passing blocks over the radius graph (GNS: 10)."""
    radius_factor: float = 2.5
    """Connectivity radius as a multiple of the rest mesh's median nearest-neighbour spacing."""
    max_neighbours: int | None = 24
    """Each node receives from at most this many nearest nodes within the radius (None: no cap)."""

    def validate(self, where: str = "sim_config.lip") -> None:
        """Raise ClodsError naming the first field out of range."""
        super().validate(where)
        if not isinstance(self.message_passing_steps, int) or self.message_passing_steps < 1:
            raise ClodsError(f"must be an integer >= 1, got {self.message_passing_steps!r}", where=f"{where}.message_passing_steps")
        if not (isinstance(self.radius_factor, (int, float)) and math.isfinite(self.radius_factor) and self.radius_factor > 0):
            raise ClodsError(f"must be a finite number > 0, got {self.radius_factor!r}", where=f"{where}.radius_factor",
                             hint="the radius is this times the rest mesh's median nearest-neighbour spacing")  # fmt: skip
        if self.max_neighbours is not None and (not isinstance(self.max_neighbours, int) or self.max_neighbours < 1):
            raise ClodsError(f"must be an integer >= 1 or null, got {self.max_neighbours!r}", where=f"{where}.max_neighbours")
