"""A network's function pinned by one number triple: weights from a seeded numpy stream (bit-identical on every CPU,
unlike torch's initialisers, whose vectorised paths differ between instruction sets), a fixed float64 input, and
three sums of the output that any change of the computed function moves far beyond float64 rounding (~1e-15)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

NORMS = (nn.GroupNorm, nn.LayerNorm, nn.BatchNorm2d)


@torch.no_grad()
def set_weights(model: nn.Module, seed: int = 0) -> nn.Module:
    """float64 weights in place: u ~ U(-1, 1) from numpy's seeded stream, conv/linear weights u * sqrt(3 / fan_in)
    (unit-variance activations), norm scales 1 + 0.2u, biases and norm shifts 0.1u, layer scales 1 + 0.5u,
    BatchNorm running means 0.1u and variances 1 + 0.5u. Returns the model in eval mode."""
    model.double().eval()
    rng = np.random.default_rng(seed)
    for module in model.modules():
        for name, t in [*module.named_parameters(recurse=False), *module.named_buffers(recurse=False)]:
            if not t.is_floating_point():
                continue
            u = torch.from_numpy(rng.uniform(-1.0, 1.0, tuple(t.shape)))
            if name == "running_var" or "layer_scale" in name:
                t.copy_(1.0 + 0.5 * u)
            elif name == "weight" and isinstance(module, NORMS):
                t.copy_(1.0 + 0.2 * u)
            elif name == "weight" and t.ndim >= 2:
                t.copy_(u * np.sqrt(3.0 / (t[0].numel())))
            else:
                t.copy_(0.1 * u)
    return model


def fixed_input(shape: tuple[int, ...], seed: int = 1) -> torch.Tensor:
    """float64 frames in [0, 1) from numpy's seeded stream."""
    return torch.from_numpy(np.random.default_rng(seed).random(shape))


def summary(out: torch.Tensor, seed: int = 2) -> list[float]:
    """[sum, sum of squares, sum against a fixed random pattern] of an output."""
    proj = torch.from_numpy(np.random.default_rng(seed).uniform(-1.0, 1.0, tuple(out.shape)))
    return [float(out.sum()), float((out**2).sum()), float((out * proj).sum())]


def assert_summary(got: list[float], want: list[float]) -> None:
    """Equal to 1e-9 relative to the output's scale (the square root of its sum of squares times its size)."""
    scale = max(abs(want[1]), 1.0)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * scale)
