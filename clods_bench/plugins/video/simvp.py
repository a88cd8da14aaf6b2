"""SimVP video predictor: trained on single-view videos with an MSE loss and Adam, predicts recursively.

Windows of 2*`context_frames` frames of every view (the shared loop in `trainer.py`); longer
horizons are predicted by feeding predicted blocks back in. Training resumes from `simvp.pt`
in the work directory when that checkpoint belongs to the same config and videos.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.video.simvp_model import SimVP, strides
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig

CHECKPOINT_FILE = "simvp.pt"


@dataclass(frozen=True)
class SimvpConfig(WindowTrainConfig):
    """Options of the SimVP predictor (`video_config.simvp.*`); defaults follow SimVP v1 at a small size."""

    hid_s: int = 64
    """Channels of the per-frame encoder/decoder (SimVP: 64)."""
    hid_t: int = 256
    """Channels of the translator (SimVP: 256)."""
    enc_layers: int = 4
    """Encoder (and decoder) ConvSC layers, strides 1,2,1,2,... (SimVP: 4)."""
    trans_layers: int = 8
    """Inception blocks of the translator U-Net (SimVP: 8)."""
    kernels: list[int] = dataclasses.field(default_factory=lambda: [3, 5, 7, 11])
    """Kernel sizes of the Inception branches (SimVP: 3, 5, 7, 11)."""
    groups: int = 8
    """Groups of the Inception convolutions (SimVP: 8)."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        self.validate_training("simvp", ("hid_s", "hid_t", "enc_layers", "trans_layers", "groups"))
        if self.hid_s % 2:
            raise ClodsError(f"must be even (GroupNorm with 2 groups), got {self.hid_s}", where="video_config.simvp.hid_s")
        if not self.kernels or any(k < 1 or k % 2 == 0 for k in self.kernels):
            raise ClodsError(f"must be odd sizes >= 1, got {self.kernels}", where="video_config.simvp.kernels")


class SimvpPredictor(WindowPredictor[SimvpConfig]):
    """SimVP trained from scratch on the given single-view videos."""

    name = "simvp"
    label = "SimVP"

    def build_model(self) -> nn.Module:
        """SimVP v1 at this config's size."""
        c = self.cfg
        return SimVP(c.context_frames, c.hid_s, c.hid_t, c.enc_layers, c.trans_layers, tuple(c.kernels), c.groups)

    def downsample_factor(self) -> int:
        """2 per pair of encoder layers."""
        return 2 ** sum(s == 2 for s in strides(self.cfg.enc_layers))
