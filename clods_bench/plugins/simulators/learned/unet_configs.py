"""Options of the BSMS, HCMT and DHMP simulators: the shared learned options plus their U-Net's shape.

Kept free of torch so the plugin registry can load them without importing a model.
"""

from __future__ import annotations

from dataclasses import dataclass

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.config import LearnedConfig


@dataclass(frozen=True)
class BsmsConfig(LearnedConfig):
    """BSMS-GNN's processor (its bi-stride message-passing U-Net) in the shared model and trainer (latent 128, 2 hidden layers)."""

    levels: int = 6
    """Coarse levels below the mesh (BSMS `unet_depth`): one GMP per level on the way down and up, one at the bottom."""

    def validate(self, where: str = "sim_config.bsms") -> None:
        """Raise ClodsError naming the first field out of range."""
        super().validate(where)
        if not isinstance(self.levels, int) or self.levels < 0:
            raise ClodsError(f"must be an integer >= 0, got {self.levels!r}", where=f"{where}.levels")


@dataclass(frozen=True)
class HcmtConfig(LearnedConfig):
    """HCMT's processor (contact and hierarchical mesh transformers, latent 128, 4 heads) in the shared model and trainer.

    Training defaults are the authors' (yuyudeep/hcmt `run_model.py`): 2M Adam steps, the learning rate 1e-4 decayed
    by 0.1 over 1M steps (half the run) with no floor, 1000 warm-up steps.
    """

    train_steps: int = 2_000_000
    """Optimiser steps, warm-up included (HCMT: 2M)."""
    lr_floor: float = 0.0
    """Constant added to the decayed learning rate (HCMT: none)."""
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


@dataclass(frozen=True)
class DhmpConfig(LearnedConfig):
    """DHMP (EvoMesh) processor in the shared model and trainer: anisotropic message passing over learned levels.

    Defaults are the authors' flag settings (hbell99/EvoMesh `main.py`, `models.py`, `configs/flag`): 7 levels of
    which the first 3 are bi-stride levels, one bottom layer, Gumbel temperature 5 decayed by 0.999 a call down to 0.1.
    """

    levels: int = 7
    """Coarse levels below the mesh (`multi_mesh_layer`)."""
    fixed_levels: int = 3
    """The first levels use EvoMesh's bi-stride selection (`pre_layer_num`); the rest select nodes with learned scores."""
    bottom_blocks: int = 1
    """Anisotropic layers at the coarsest level (`bottom_layer_num`; the first runs twice, as the code does on cloth)."""
    tau_start: float = 5.0
    """Gumbel-softmax temperature before the first training call; the k-th training call uses
    max(tau_start * tau_decay^k, tau_min), as the code's per-call decay (which also decays in evaluation)."""
    tau_decay: float = 0.999
    """Factor per training call of the processor..."""
    tau_min: float = 0.1
    """...down to this floor."""
    keep_ratio: float | None = None
    """None: a node is kept when its sampled 'keep' wins, so a level's size is learned (the authors' rule; this
    implementation keeps at least one node per component). A fraction r in (0, 1], not in the authors' code: each
    connected component keeps its max(1, round(r n)) nodes of highest sampled keep-minus-drop margin (Gumbel top-k)."""

    def validate(self, where: str = "sim_config.dhmp") -> None:
        """Raise ClodsError naming the first field out of range."""
        super().validate(where)
        for name, least in (("levels", 0), ("fixed_levels", 0), ("bottom_blocks", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or value < least:
                raise ClodsError(f"must be an integer >= {least}, got {value!r}", where=f"{where}.{name}")
        if self.fixed_levels > self.levels:
            raise ClodsError(f"must be <= levels ({self.levels}), got {self.fixed_levels}", where=f"{where}.fixed_levels")
        if not self.tau_min > 0 or not self.tau_start >= self.tau_min:
            raise ClodsError(f"need 0 < tau_min <= tau_start, got {self.tau_min!r}, {self.tau_start!r}", where=f"{where}.tau_min")
        if self.keep_ratio is not None and not 0 < self.keep_ratio <= 1:
            raise ClodsError(f"must be in (0, 1] or null, got {self.keep_ratio!r}", where=f"{where}.keep_ratio")
        if not 0 < self.tau_decay <= 1:
            raise ClodsError(f"must be in (0, 1], got {self.tau_decay!r}", where=f"{where}.tau_decay")
