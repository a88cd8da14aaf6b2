"""Options of the BSMS, HCMT and DHMP simulators: the shared learned options plus their U-Net's shape.

Kept free of torch so the plugin registry can load them without importing a model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.config import LearnedConfig


PositionScale = Literal["raw", "dataset", "level"]
POSITION_SCALES: tuple[str, ...] = ("raw", "dataset", "level")


def check_choice(value: object, choices: tuple[str, ...], where: str) -> None:
    """Raise ClodsError unless `value` is one of `choices`."""
    if value not in choices:
        raise ClodsError(f"must be one of {', '.join(choices)}; got {value!r}", where=where)


@dataclass(frozen=True)
class HierarchicalConfig(LearnedConfig):
    """The shared learned options plus what the hierarchical models' own codes decode."""

    output: Literal["acceleration", "velocity"] = "acceleration"
    """What the decoder predicts (normalised): 'acceleration' as MGN, or 'velocity' x_{t+1} - x_t as the codes of
    BSMS-GNN and HCMT do."""

    def validate(self, where: str = "sim_config") -> None:
        """Raise ClodsError naming the first field out of range."""
        super().validate(where)
        check_choice(self.output, ("acceleration", "velocity"), f"{where}.output")


@dataclass(frozen=True)
class BsmsConfig(HierarchicalConfig):
    """BSMS-GNN's processor (its bi-stride message-passing U-Net) in the shared model and trainer (latent 128, 2 hidden layers).

    Training defaults are the authors' recipe for their closest configuration to cloth, the Lagrangian `plate`
    (Eydcao/BSMS-GNN before its 2024 rewrite: `configs/plate`, `src/main.py`): noise 0.003 with gamma 1, Adam at 1e-4
    decayed x0.794 an epoch down to 1e-6, batch 12, 50 epochs of 1200 trajectories of 399 samples (1,995,000 steps).
    The decay is expressed per step (x0.1 every 20 % of the steps, plus a floor of 1e-6), and every sample gets noise
    where the code noises about 2 epochs in 3. The `ci` and `small` presets train it by MGN's recipe instead, but
    `small` keeps the authors' noise gamma.
    """

    batch_size: int = 12
    """Training samples per optimiser step (BSMS plate: 12)."""
    train_steps: int = 1_995_000
    """Optimiser steps, warm-up included (BSMS plate: 50 epochs x 1200 x 399 / 12)."""
    noise_gamma: float = 1.0
    """The target keeps (1 - gamma) of the input noise (BSMS: gamma 1, the target is clean)."""
    lr_decay_fraction: float = 0.2
    """x`lr_decay_rate` (0.1) every this fraction of the steps: x0.794 an epoch over 50 epochs (BSMS)."""

    levels: int = 6
    """Coarse levels below the mesh (BSMS `unet_depth`): one GMP per level on the way down and up, one at the bottom."""
    position_scale: PositionScale = "level"
    """What the fibres are built from: 'raw' positions in metres (the port of release 0.2: it trained to a plateau, see
    results/studies/hierarchy_plateau); 'dataset': every rest and world coordinate normalised by running statistics
    (the authors' Lagrangian data pipeline); 'level' (default): each level's fibres normalised by running statistics
    of that level's own fibres, as MGN's cloth frame normalises its edge features (not the authors')."""
    fibre_norms: Literal["joint", "separate"] = "separate"
    """'joint': one norm of the whole (rest, world) difference (the authors' Eulerian GMP); 'separate' (default):
    one norm each (their Lagrangian GMP, used for plates and fonts, as cloth is)."""
    repeat_mesh_level: bool = False
    """Run the mesh level's GMPs and the bottom GMP twice, as the authors' Lagrangian U-Net does."""

    def validate(self, where: str = "sim_config.bsms") -> None:
        """Raise ClodsError naming the first field out of range."""
        super().validate(where)
        if not isinstance(self.levels, int) or self.levels < 0:
            raise ClodsError(f"must be an integer >= 0, got {self.levels!r}", where=f"{where}.levels")
        check_choice(self.position_scale, POSITION_SCALES, f"{where}.position_scale")
        check_choice(self.fibre_norms, ("joint", "separate"), f"{where}.fibre_norms")
        if not isinstance(self.repeat_mesh_level, bool):
            raise ClodsError(f"must be true or false, got {self.repeat_mesh_level!r}", where=f"{where}.repeat_mesh_level")


@dataclass(frozen=True)
class HcmtConfig(HierarchicalConfig):
    """HCMT's processor (contact and hierarchical mesh transformers, latent 128, 4 heads) in the shared model and trainer.

    Training defaults are the authors' (yuyudeep/hcmt `run_model.py`, impact plate, their only configuration): 2M Adam
    steps of one sample, the learning rate 1e-4 decayed by 0.1 over 1M steps (half the run) with no floor, 1000
    warm-up steps, noise 0.003 with gamma 1. Their decoder also has a stress head and predicts velocity; this one
    predicts what `output` says (acceleration by default). The `ci` and `small` presets train it by MGN's recipe,
    but `small` keeps the authors' noise gamma.
    """

    train_steps: int = 2_000_000
    """Optimiser steps, warm-up included (HCMT: 2M)."""
    noise_gamma: float = 1.0
    """The target keeps (1 - gamma) of the input noise (HCMT: gamma 1, the target is clean)."""
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
class DhmpConfig(HierarchicalConfig):
    """DHMP (EvoMesh) processor in the shared model and trainer: anisotropic message passing over learned levels.

    Defaults are the authors' flag settings (hbell99/EvoMesh `main.py`, `models.py`, `configs/flag`, `trainer.py`): 7
    levels of which the first 3 are bi-stride levels, one bottom layer, Gumbel temperature 5 decayed by 0.999 a call
    down to 0.1; Adam at 3e-4 decayed x0.794 an epoch down to 1e-6, batch 16, 50 epochs of 1000 trajectories of 399
    samples (1,250,000 steps), noise 0.003 with gamma 1. The decay is expressed per step (x0.1 every 20 % of the
    steps, plus a floor of 1e-6), and every sample gets noise where the code noises about 2 trajectories in 3. The
    `ci` and `small` presets train it by MGN's recipe instead, but `small` keeps the authors' noise gamma.
    """

    batch_size: int = 16
    """Training samples per optimiser step (EvoMesh flag: 16)."""
    train_steps: int = 1_250_000
    """Optimiser steps, warm-up included (EvoMesh flag: 50 epochs x 1000 x 25 batches)."""
    learning_rate: float = 3e-4
    """Initial Adam learning rate (EvoMesh flag: 3e-4)."""
    noise_gamma: float = 1.0
    """The target keeps (1 - gamma) of the input noise (EvoMesh: gamma 1, the target is clean)."""
    lr_decay_fraction: float = 0.2
    """x`lr_decay_rate` (0.1) every this fraction of the steps: x0.794 an epoch over 50 epochs (EvoMesh)."""

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
    position_scale: PositionScale = "level"
    """As BSMS's: 'raw' metres (the port of release 0.2), 'dataset' (every coordinate normalised by running statistics,
    as the authors' data pipeline) or 'level' (default: each level's fibres normalised by their own running
    statistics, as MGN's cloth frame normalises edge features; not the authors')."""

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
        check_choice(self.position_scale, POSITION_SCALES, f"{where}.position_scale")
        if not 0 < self.tau_decay <= 1:
            raise ClodsError(f"must be in (0, 1], got {self.tau_decay!r}", where=f"{where}.tau_decay")
