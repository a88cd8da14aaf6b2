"""Options of the BSMS-style and HCMT-style simulators: the shared learned options plus their U-Net's shape.

Kept free of torch so the plugin registry can load them without importing a model.
"""

from __future__ import annotations

from dataclasses import dataclass

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.config import LearnedConfig


@dataclass(frozen=True)
class BsmsConfig(LearnedConfig):
    """BSMS-GNN-style simulator: the shared model and trainer (latent 128, 2 hidden layers) with a bi-stride U-Net."""

    levels: int = 6
    """Coarse levels below the mesh (BSMS `unet_depth`); levels that have shrunk to one node per component stay as they are."""
    blocks_per_level: int = 1
    """Message-passing blocks at each level on the way down and again on the way up (BSMS: 1)."""
    bottom_blocks: int = 1
    """Message-passing blocks at the coarsest level."""

    def validate(self, where: str = "sim_config.bsms") -> None:
        """Raise ClodsError naming the first field out of range."""
        super().validate(where)
        for name, least in (("levels", 0), ("blocks_per_level", 1), ("bottom_blocks", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or value < least:
                raise ClodsError(f"must be an integer >= {least}, got {value!r}", where=f"{where}.{name}")


@dataclass(frozen=True)
class HcmtConfig(LearnedConfig):
    """HCMT-style simulator: the shared model and trainer (latent 128) with a hierarchical mesh transformer (4 heads)."""

    levels: int = 6
    """Coarse levels below the mesh (HCMT `l_n`)."""
    heads: int = 4
    """Attention heads; must divide the latent size."""
    first_blocks: int = 2
    """Blocks at the mesh level before the U-Net, with contact attention when the scene has obstacles."""
    blocks_per_level: int = 1
    """Transformer blocks at each level on the way down and again on the way up."""
    bottom_blocks: int = 1
    """Transformer blocks at the coarsest level."""

    def validate(self, where: str = "sim_config.hcmt") -> None:
        """Raise ClodsError naming the first field out of range."""
        super().validate(where)
        for name, least in (("levels", 0), ("heads", 1), ("first_blocks", 0), ("blocks_per_level", 1), ("bottom_blocks", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or value < least:
                raise ClodsError(f"must be an integer >= {least}, got {value!r}", where=f"{where}.{name}")
        if self.latent_size % self.heads:
            raise ClodsError(f"must divide latent_size {self.latent_size}, got {self.heads}", where=f"{where}.heads")
