"""TAU video predictor: SimVP v2 with Temporal Attention Units, MSE plus the differential divergence
regularisation, trained and scored exactly like SimVP (the shared loop in `trainer.py`, checkpoint `tau.pt`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.video.simvp_model import strides
from clods_bench.plugins.video.tau_model import TAU, differential_divergence, lka_kernels
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig

WHERE = "video_config.tau"


@dataclass(frozen=True)
class TauConfig(WindowTrainConfig):
    """Options of the TAU predictor (`video_config.tau.*`); defaults are OpenSTL's Moving MNIST TAU config."""

    hid_s: int = 64
    """Channels of the per-frame encoder/decoder (OpenSTL TAU: hid_S 64)."""
    hid_t: int = 512
    """Channels of the translator's inner blocks (OpenSTL TAU: hid_T 512)."""
    enc_layers: int = 4
    """Encoder (and decoder) ConvSC layers, strides 1,2,1,2,... (OpenSTL TAU: N_S 4)."""
    trans_layers: int = 8
    """TAU blocks of the translator, >= 2 (OpenSTL TAU: N_T 8)."""
    kernel_size: int = 21
    """Receptive field of the statical attention, decomposed into a 5x5 depthwise and a dilation-3 depthwise conv (TAU: 21)."""
    mlp_ratio: float = 8.0
    """Hidden width of each block's MLP over its input width (OpenSTL SimVP v2: 8)."""
    alpha: float = 0.1
    """Weight of the differential divergence regularisation (TAU: 0.1)."""
    temperature: float = 0.1
    """Softmax temperature of the regularisation (OpenSTL's `diff_div_reg`: tau 0.1)."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        self.validate_training("tau", ("hid_s", "hid_t", "enc_layers", "kernel_size"))
        if self.hid_s % 2:
            raise ClodsError(f"must be even (GroupNorm with 2 groups), got {self.hid_s}", where=f"{WHERE}.hid_s")
        if self.trans_layers < 2:
            raise ClodsError(f"must be >= 2 (first and last blocks change the width), got {self.trans_layers}", where=f"{WHERE}.trans_layers")
        if min(lka_kernels(self.kernel_size, 3)) < 1:
            raise ClodsError(f"must be >= 3 for a dilation-3 decomposition, got {self.kernel_size}", where=f"{WHERE}.kernel_size")
        if self.mlp_ratio <= 0 or self.alpha < 0 or self.temperature <= 0:
            raise ClodsError("mlp_ratio and temperature must be > 0, alpha >= 0", where=WHERE)


class TauPredictor(WindowPredictor[TauConfig]):
    """TAU trained from scratch on the given single-view videos."""

    name = "tau"
    label = "TAU"

    def build_model(self) -> nn.Module:
        """SimVP v2 with TAU blocks at this config's size."""
        c = self.cfg
        return TAU(c.context_frames, c.hid_s, c.hid_t, c.enc_layers, c.trans_layers, c.kernel_size, c.mlp_ratio)

    def downsample_factor(self) -> int:
        """2 per pair of encoder layers."""
        return 2 ** sum(s == 2 for s in strides(self.cfg.enc_layers))

    def loss(self, model: nn.Module, window: torch.Tensor, step: int, rng: np.random.Generator) -> torch.Tensor:
        """MSE of the next C frames plus alpha x the differential divergence of their frame differences."""
        c = self.cfg.context_frames
        pred, truth = model(window[:, :c]), window[:, c:]
        return torch.nn.functional.mse_loss(pred, truth) + self.cfg.alpha * differential_divergence(pred, truth, self.cfg.temperature)
