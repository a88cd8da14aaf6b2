"""MAU video predictor: the recurrent Motion-Aware Unit network, trained as its authors train it (ZhengChang467/MAU,
configs/mnist_train_configs.py and core/models/model_factory.py) on the shared loop in `trainer.py` (checkpoint `mau.pt`).

On a window of 2C frames the network reads frames 0..C-1, then, for each later input, the true frame with the
scheduled-sampling probability or else its own prediction, and is scored (MSE) on frames 1..2C-1. The true-frame
probability at step k (from 0) is 1 - (k+1)/S down to 0 at S = `sampling_fraction` x train_steps and 0 after (the
authors: eta falls by 2e-5 per iteration until iteration 50,000 of 80,000). Adam at a constant learning rate until
S, then x`lr_decay` every `lr_decay_every` x train_steps (the authors: x0.9 every 2,000 iterations from 50,000).
Presets keep these fractions and shrink widths, layers, steps and batch. Prediction reads the C context frames and
rolls out any number of frames one at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.video.mau_model import MAU
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig

WHERE = "video_config.mau"


@dataclass(frozen=True)
class MauConfig(WindowTrainConfig):
    """Options of the MAU predictor (`video_config.mau.*`); defaults are the MAU authors' Moving MNIST run."""

    hidden: int = 64
    """Channels of every MAU cell and of the encoder/decoder (MAU: num_hidden 64)."""
    num_layers: int = 4
    """Stacked MAU cells (MAU: 4)."""
    kernel: int = 5
    """Kernel size of the cells' convolutions (MAU: filter_size 5)."""
    tau: int = 5
    """Previous temporal states each cell attends over (MAU: tau 5)."""
    downsamples: int = 2
    """Stride-2 encoder convolutions: latents are 2^downsamples times smaller (MAU: sr_size 4)."""
    scheduled_sampling: bool = True
    """Feed true frames instead of predictions early in training, with a falling probability (MAU: on)."""
    sampling_fraction: float = 0.625
    """Fraction of the training steps over which the true-frame probability falls from 1 to 0 (MAU: 50,000 of 80,000)."""
    lr_decay: float = 0.9
    """Factor of each learning-rate decay after the scheduled sampling ends (MAU: 0.9; 1 keeps it constant)."""
    lr_decay_every: float = 0.025
    """Fraction of the training steps between two decays (MAU: 2,000 of 80,000 iterations)."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        self.validate_training("mau", ("hidden", "num_layers", "kernel", "tau"))
        if self.kernel % 2 == 0:
            raise ClodsError(f"must be odd, got {self.kernel}", where=f"{WHERE}.kernel")
        if self.downsamples < 0:
            raise ClodsError(f"must be >= 0, got {self.downsamples}", where=f"{WHERE}.downsamples")
        if not 0 < self.sampling_fraction <= 1:
            raise ClodsError(f"must be in (0, 1], got {self.sampling_fraction}", where=f"{WHERE}.sampling_fraction")
        if not 0 < self.lr_decay <= 1:
            raise ClodsError(f"must be in (0, 1], got {self.lr_decay}", where=f"{WHERE}.lr_decay")
        if self.lr_decay_every <= 0:
            raise ClodsError(f"must be > 0, got {self.lr_decay_every}", where=f"{WHERE}.lr_decay_every")


class MauPredictor(WindowPredictor[MauConfig]):
    """MAU trained from scratch on the given single-view videos."""

    name = "mau"
    label = "MAU"
    layers_option = "downsamples"

    def build_model(self) -> nn.Module:
        """The MAU network at this config's size, for frames of the size `fit` found (its LayerNorms are per size)."""
        if self.size is None:
            raise ClodsError("the MAU network is built for one frame size: fit sets it", where="mau.build_model")
        c = self.cfg
        return MAU(c.hidden, c.num_layers, c.kernel, c.tau, c.downsamples, self.size)

    def downsample_factor(self) -> int:
        """2^downsamples."""
        return 2**self.cfg.downsamples

    def truth_probability(self, step: int) -> float:
        """Probability of feeding the true frame at training step `step` (from 0): 1 - (step+1)/S, at least 0, with
        S = sampling_fraction x train_steps (0 without scheduled sampling)."""
        if not self.cfg.scheduled_sampling:
            return 0.0
        return max(0.0, 1.0 - (step + 1) / (self.cfg.sampling_fraction * self.cfg.train_steps))

    def lr_factor(self, step: int) -> float:
        """Learning rate at step `step` over the initial one: lr_decay^(decays before it), one decay after the steps
        S, S + D, S + 2D, ... (S the end of scheduled sampling, D = lr_decay_every x train_steps), as the authors."""
        c = self.cfg
        stop, every = c.sampling_fraction * c.train_steps, c.lr_decay_every * c.train_steps
        return c.lr_decay ** max(0, math.ceil((step - stop) / every))

    def optimizer(self, model: nn.Module) -> tuple[torch.optim.Optimizer, Any]:
        """Adam (no weight decay) with the authors' step decay after scheduled sampling."""
        opt = torch.optim.Adam(model.parameters(), lr=self.cfg.learning_rate)
        return opt, torch.optim.lr_scheduler.LambdaLR(opt, self.lr_factor)

    def loss(self, model: nn.Module, window: torch.Tensor, step: int, rng: np.random.Generator) -> torch.Tensor:
        """MSE of the predictions of frames 1..2C-1 (frames 0..C-1 read, then the truth or the model's own output)."""
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
