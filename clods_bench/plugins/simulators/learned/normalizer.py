"""Online feature normaliser (DeepMind `normalization.py`): running mean/std over the first 10^6 calls."""

from __future__ import annotations

import torch
from torch import nn


class Normalizer(nn.Module):
    """Normalise features with statistics accumulated online over the first `max_accumulations` calls.

    Accumulation (count, sum, sum of squares, in float64 so many calls do not lose
    precision) happens only when `accumulate` is true, which defaults to training mode, and
    stops after `max_accumulations` calls. std = max(sqrt(E[x^2] - E[x]^2), std_epsilon);
    the variance is clamped at 0 so a constant feature cannot give NaN by rounding.
    """

    def __init__(self, size: int, max_accumulations: int = 10**6, std_epsilon: float = 1e-8) -> None:
        super().__init__()
        self.size = size
        self.max_accumulations = max_accumulations
        self.std_epsilon = std_epsilon
        self.register_buffer("acc_count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("num_accumulations", torch.zeros((), dtype=torch.int64))
        self.register_buffer("acc_sum", torch.zeros(size, dtype=torch.float64))
        self.register_buffer("acc_sum_squared", torch.zeros(size, dtype=torch.float64))

    def forward(self, batch: torch.Tensor, accumulate: bool | None = None) -> torch.Tensor:
        """Normalise (N, size) data; accumulate its statistics first when asked (default: in training)."""
        if (self.training if accumulate is None else accumulate) and int(self.num_accumulations) < self.max_accumulations:
            self._accumulate(batch.detach())
        return (batch - self.mean) / self.std

    def inverse(self, normalized: torch.Tensor) -> torch.Tensor:
        """Map normalised data back to the original units."""
        return normalized * self.std + self.mean

    @torch.no_grad()
    def _accumulate(self, batch: torch.Tensor) -> None:
        data = batch.reshape(-1, self.size).to(torch.float64)
        self.acc_count += data.shape[0]
        self.acc_sum += data.sum(dim=0)
        self.acc_sum_squared += (data**2).sum(dim=0)
        self.num_accumulations += 1

    @property
    def mean(self) -> torch.Tensor:
        """Accumulated mean (float32)."""
        return (self.acc_sum / self.acc_count.clamp(min=1.0)).to(torch.float32)

    @property
    def std(self) -> torch.Tensor:
        """Accumulated standard deviation, at least `std_epsilon` (float32)."""
        count = self.acc_count.clamp(min=1.0)
        mean = self.acc_sum / count
        var = (self.acc_sum_squared / count - mean**2).clamp(min=0.0)
        return torch.sqrt(var).clamp(min=self.std_epsilon).to(torch.float32)
