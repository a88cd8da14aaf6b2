"""MMVP video predictor: motion matrices between consecutive feature maps, a predicted future matrix composed
with the last frame's features, trained and scored exactly like SimVP (the shared loop in `trainer.py`,
MSE on the next C frames, checkpoint `mmvp.pt`; longer horizons by feeding predicted blocks back in)."""

from __future__ import annotations

from dataclasses import dataclass

from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.video.mmvp_model import MMVP
from clods_bench.plugins.video.simvp_model import strides
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig

WHERE = "video_config.mmvp"


@dataclass(frozen=True)
class MmvpConfig(WindowTrainConfig):
    """Options of the MMVP predictor (`video_config.mmvp.*`); defaults follow the MMVP repository's README command."""

    hid_s: int = 64
    """Channels of the appearance features at the matrix resolution (MMVP: base_channel 16 x 4 at that scale)."""
    motion_channels: int = 16
    """Channels of the motion features the matrices are built from (MMVP: base_channel / translate_factor = 16)."""
    predictor_hidden: int = 8
    """Channels of the matrix predictor (MMVP: pred_base_channel 8)."""
    enc_layers: int = 6
    """Encoder ConvSC layers, strides 1,2,1,2,...: matrices at 1/8 of the image side with 6 (MMVP: 8x8 for 64 px)."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        self.validate_training("mmvp", ("hid_s", "motion_channels", "predictor_hidden", "enc_layers"))
        if self.context_frames < 2:
            raise ClodsError(f"must be >= 2 (a motion matrix needs two frames), got {self.context_frames}", where=f"{WHERE}.context_frames")
        for name in ("hid_s", "motion_channels"):
            if getattr(self, name) % 2:
                raise ClodsError(f"must be even (GroupNorm with 2 groups), got {getattr(self, name)}", where=f"{WHERE}.{name}")


class MmvpPredictor(WindowPredictor[MmvpConfig]):
    """MMVP trained from scratch on the given single-view videos."""

    name = "mmvp"
    label = "MMVP"

    def build_model(self) -> nn.Module:
        """The MMVP network at this config's size."""
        c = self.cfg
        return MMVP(c.context_frames, c.hid_s, c.motion_channels, c.predictor_hidden, c.enc_layers)

    def downsample_factor(self) -> int:
        """2 per pair of encoder layers."""
        return 2 ** sum(s == 2 for s in strides(self.cfg.enc_layers))
