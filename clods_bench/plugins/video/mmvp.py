"""MMVP video predictor (Zhong et al. ICCV 2023) with its authors' training recipe, in the shared window loop of
`trainer.py` (checkpoint `mmvp.pt`; longer horizons by feeding predicted blocks back in).

As the authors' `main.py` trains: the whole window of 2C frames goes into the network (the C targets only reach
the filter blocks' BatchNorm statistics, see `mmvp_model`), MSE of the C predicted frames, AdamW (torch's default
weight decay 0.01, which the authors' call keeps) and a cosine learning rate from `learning_rate` down to 1e-6
over the run (the authors' `CosineAnnealingLR_Restart` with one period, stepped per epoch there and per step here).
The network is proven against the authors' code with the same weights by `examples/studies/mmvp_same_weights.py`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.video.mmvp_model import MMVP, total_factor
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig

WHERE = "video_config.mmvp"
FINAL_LEARNING_RATE = 1e-6
"""Where the cosine schedule ends (the authors' `CosineAnnealingLR_Restart` eta_min)."""


@dataclass(frozen=True)
class MmvpConfig(WindowTrainConfig):
    """Options of the MMVP predictor (`video_config.mmvp.*`); defaults are the authors' README command with their
    Moving MNIST / KTH factors."""

    learning_rate: float = 1e-3
    """AdamW learning rate at the start of the cosine schedule (MMVP: 1e-3)."""
    weight_decay: float = 0.01
    """AdamW weight decay (MMVP: torch's default, 0.01)."""
    channels: int = 16
    """Channels after the stem; the three downsampling levels have 2x, 4x, 8x, the enhancer half (MMVP: base_channel 16)."""
    predictor_channels: int = 8
    """Channels of the matrix predictor's U-Net (MMVP: pred_base_channel 8)."""
    downsample: list[int] = dataclasses.field(default_factory=lambda: [2, 2, 2])
    """Factors (2 or 4) of the three downsampling levels; the matrices live on the last two levels' grids
    (MMVP: 2,2,2 for Moving MNIST and KTH, 2,4,2 for UCF Sports at 512 px)."""
    encoder_blocks: int = 2
    """RRDBs after the encoder's stem (MMVP: rrdb_encoder_num 2)."""
    decoder_blocks: int = 2
    """RRDBs before the decoder's readout (MMVP: rrdb_decoder_num 2)."""
    enhancer_blocks: int = 2
    """RRDBs of the enhancer (MMVP: rrdb_enhance_num 2)."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        self.validate_training("mmvp", ("predictor_channels", "encoder_blocks", "decoder_blocks", "enhancer_blocks"))
        if self.context_frames < 2:
            raise ClodsError(f"must be >= 2 (a motion matrix needs two frames), got {self.context_frames}", where=f"{WHERE}.context_frames")
        if self.channels < 4:
            raise ClodsError(f"must be >= 4 (the enhancer's dense blocks grow by channels / 4), got {self.channels}", where=f"{WHERE}.channels")
        if len(self.downsample) != 3 or any(f not in (2, 4) for f in self.downsample):
            raise ClodsError(f"must be three factors, each 2 or 4, got {self.downsample}", where=f"{WHERE}.downsample")
        if self.weight_decay < 0:
            raise ClodsError(f"must be >= 0, got {self.weight_decay}", where=f"{WHERE}.weight_decay")


class MmvpPredictor(WindowPredictor[MmvpConfig]):
    """MMVP trained from scratch on the given single-view videos."""

    name = "mmvp"
    label = "MMVP"
    layers_option = "downsample"

    def build_model(self) -> nn.Module:
        """The MMVP network at this config's size (PyTorch's default initialisation, as the authors' code)."""
        c = self.cfg
        return MMVP(c.context_frames, c.channels, c.predictor_channels, tuple(c.downsample), c.encoder_blocks, c.decoder_blocks, c.enhancer_blocks)

    def downsample_factor(self) -> int:
        """2 for the pixel unshuffle times each level's factor."""
        return total_factor(tuple(self.cfg.downsample))

    def loss(self, model: nn.Module, window: torch.Tensor, step: int, rng: np.random.Generator) -> torch.Tensor:
        """MSE of the C frames predicted from the whole window (B,2C,3,H,W) against its last C (MMVP's training step)."""
        return torch.nn.functional.mse_loss(model(window), window[:, self.cfg.context_frames :])

    def optimizer(self, model: nn.Module) -> tuple[torch.optim.Optimizer, Any]:
        """AdamW and a cosine learning rate from `learning_rate` to 1e-6 over `train_steps` (MMVP's recipe)."""
        c = self.cfg
        opt = torch.optim.AdamW(model.parameters(), lr=c.learning_rate, weight_decay=c.weight_decay)
        return opt, torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=c.train_steps, eta_min=min(FINAL_LEARNING_RATE, c.learning_rate))

