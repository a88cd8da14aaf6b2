"""MAU video predictor: the recurrent Motion-Aware Unit network, trained and scored exactly like SimVP (the
shared loop in `trainer.py`, checkpoint `mau.pt`).

On a window of 2C frames the network reads frames 0..C-1, then its own predictions, and is scored (MSE) on
frames 1..2C-1, as OpenSTL trains it. With `scheduled_sampling` the true frame replaces the prediction with
a probability falling linearly from 1 to 0 over `sampling_fraction` of training. Prediction reads the C
context frames and rolls out any number of frames one at a time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.video.mau_model import MAU
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig

WHERE = "video_config.mau"


@dataclass(frozen=True)
class MauConfig(WindowTrainConfig):
    """Options of the MAU predictor (`video_config.mau.*`); defaults are OpenSTL's Moving MNIST MAU config."""

    hidden: int = 64
    """Channels of every MAU cell and of the encoder/decoder (OpenSTL MAU: num_hidden 64,64,64,64)."""
    num_layers: int = 4
    """Stacked MAU cells (OpenSTL MAU: 4)."""
    kernel: int = 5
    """Kernel size of the cells' convolutions (OpenSTL MAU: filter_size 5)."""
    tau: int = 5
    """Previous temporal states each cell attends over (MAU: tau 5)."""
    downsamples: int = 2
    """Stride-2 encoder convolutions: latents are 2^downsamples times smaller (OpenSTL MAU: sr_size 4)."""
    scheduled_sampling: bool = False
    """Feed true frames instead of predictions early in training (OpenSTL trains MAU with it; off by default here)."""
    sampling_fraction: float = 1.0
    """Scheduled sampling: fraction of the training steps over which the true-frame probability falls from 1 to 0."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        self.validate_training("mau", ("hidden", "num_layers", "kernel", "tau"))
        if self.kernel % 2 == 0:
            raise ClodsError(f"must be odd, got {self.kernel}", where=f"{WHERE}.kernel")
        if self.downsamples < 0:
            raise ClodsError(f"must be >= 0, got {self.downsamples}", where=f"{WHERE}.downsamples")
        if not 0 < self.sampling_fraction <= 1:
            raise ClodsError(f"must be in (0, 1], got {self.sampling_fraction}", where=f"{WHERE}.sampling_fraction")


class MauPredictor(WindowPredictor[MauConfig]):
    """MAU trained from scratch on the given single-view videos."""

    name = "mau"
    label = "MAU"
    layers_option = "downsamples"

    def build_model(self) -> nn.Module:
        """The MAU network at this config's size."""
        c = self.cfg
        return MAU(c.hidden, c.num_layers, c.kernel, c.tau, c.downsamples)

    def downsample_factor(self) -> int:
        """2^downsamples."""
        return 2**self.cfg.downsamples

    def truth_probability(self, step: int) -> float:
        """Probability of feeding the true frame at this training step (0 without scheduled sampling)."""
        if not self.cfg.scheduled_sampling:
            return 0.0
        return max(0.0, 1.0 - step / (self.cfg.sampling_fraction * self.cfg.train_steps))

    def loss(self, model: nn.Module, window: torch.Tensor, step: int, rng: np.random.Generator) -> torch.Tensor:
        """MSE of the predictions of frames 1..2C-1 (frames 0..C-1 read, then the model's own output or the truth)."""
        c = self.cfg.context_frames
        use_truth = None
        if self.cfg.scheduled_sampling:
            use_truth = torch.from_numpy(rng.random((window.shape[0], c - 1)) < self.truth_probability(step)).to(window.device)
        pred = model(window[:, :c], c, truth=window[:, c:], use_truth=use_truth)
        return torch.nn.functional.mse_loss(pred, window[:, 1:])

    def rollout(self, model: nn.Module, context: torch.Tensor, num_frames: int) -> torch.Tensor:
        """Read the C context frames, then predict `num_frames` frames one at a time."""
        if num_frames < 1:
            return context[:, :0]
        c = context.shape[1]
        return model(context, num_frames)[:, c - 1 :].clamp(0.0, 1.0)
