"""SimVP (v1) video predictor: trained on single-view videos with an MSE loss and Adam, predicts recursively.

The network is SimVP v1 (Gao et al. CVPR 2022) as in its authors' code, A4Bio/SimVP (the paper the CloDS paper
cites, `gao2022simvp`); OpenSTL's `SimVP` is another model (v2 encoder/decoder; gSTA translator by default). The
recipe is the authors': Adam with a one-cycle schedule peaking at 0.01, MSE, batch 16, 4 encoder and 8
translator layers, hid_s 64, hid_t 256, Inception kernels 3, 5, 7, 11 in 8 groups, PyTorch's default
initialisation. Windows of 2*`context_frames` frames of every view (the shared loop in `trainer.py`); longer
horizons are predicted by feeding predicted blocks back in. Training resumes from `simvp.pt` in the work
directory when that checkpoint belongs to the same config and videos.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.video.simvp_model import SimVP, inception_groups, strides
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig

CHECKPOINT_FILE = "simvp.pt"
WHERE = "video_config.simvp"


@dataclass(frozen=True)
class SimvpConfig(WindowTrainConfig):
    """Options of the SimVP (v1) predictor (`video_config.simvp.*`); defaults are the authors' Moving MNIST run
    (A4Bio/SimVP main.py); presets shrink widths, layers, steps and batch, never the structure."""

    learning_rate: float = 0.01
    """Adam's peak learning rate of the one-cycle schedule (SimVP v1: 0.01)."""
    hid_s: int = 64
    """Channels of the per-frame encoder/decoder (SimVP v1: 64)."""
    hid_t: int = 256
    """Channels of the translator (SimVP v1: 256; its Inception blocks work at hid_t / 2 inside)."""
    enc_layers: int = 4
    """Encoder (and decoder) ConvSC layers, strides 1,2,1,2,... (SimVP v1: 4)."""
    trans_layers: int = 8
    """Inception blocks of each half of the translator U-Net, >= 2 (SimVP v1: 8)."""
    kernels: list[int] = dataclasses.field(default_factory=lambda: [3, 5, 7, 11])
    """Kernel sizes of the Inception branches (SimVP v1: 3, 5, 7, 11)."""
    groups: int = 8
    """Groups of the Inception convolutions, 1 where hid_t / 2 is not divisible by it (SimVP v1: 8)."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        self.validate_training("simvp", ("hid_s", "hid_t", "enc_layers", "trans_layers", "groups"))
        if self.hid_s % 2:
            raise ClodsError(f"must be even (GroupNorm with 2 groups), got {self.hid_s}", where=f"{WHERE}.hid_s")
        if self.hid_t < 2:
            raise ClodsError(f"must be >= 2 (the Inception blocks work at hid_t / 2), got {self.hid_t}", where=f"{WHERE}.hid_t")
        if self.trans_layers < 2:
            raise ClodsError(f"must be >= 2 (a U-Net of encoder and decoder blocks), got {self.trans_layers}", where=f"{WHERE}.trans_layers")
        if not self.kernels or any(k < 1 or k % 2 == 0 for k in self.kernels):
            raise ClodsError(f"must be odd sizes >= 1, got {self.kernels}", where=f"{WHERE}.kernels")
        g = inception_groups(self.hid_t // 2, self.groups)
        for width, what in ((self.hid_t, "hid_t"), (self.context_frames * self.hid_s, "context_frames x hid_s")):
            if width % g:
                raise ClodsError(f"{what} = {width} is not divisible by the {g} Inception groups", where=f"{WHERE}.groups")


class SimvpPredictor(WindowPredictor[SimvpConfig]):
    """SimVP (v1) trained from scratch on the given single-view videos."""

    name = "simvp"
    label = "SimVP"
    version: ClassVar[str] = "v1 (Gao et al. CVPR 2022; the authors' code A4Bio/SimVP)"
    """Which published SimVP this is."""

    def build_model(self) -> nn.Module:
        """SimVP v1 at this config's size."""
        c = self.cfg
        return SimVP(c.context_frames, c.hid_s, c.hid_t, c.enc_layers, c.trans_layers, tuple(c.kernels), c.groups)

    def downsample_factor(self) -> int:
        """2 per pair of encoder layers."""
        return 2 ** sum(s == 2 for s in strides(self.cfg.enc_layers))
