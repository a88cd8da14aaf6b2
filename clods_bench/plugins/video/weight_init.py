"""Weight initialisations of OpenSTL's video predictors (SimVP v2, TAU, MMVP), written once for every predictor here.

OpenSTL does not use PyTorch's default initialisation everywhere: its encoder/decoder convolutions get a
truncated normal of std 0.02 (timm's `trunc_normal_`, cut at the absolute values -2 and 2, so at std 0.02 it is
a plain normal in practice; drawn here by `clods_bench.numerics.truncated_normal`, the same distribution) with zero bias,
and its VAN-style MLP convolutions a normal of std sqrt(2 / fan_out) with zero bias. Each helper re-initialises the matching layers of a module in place and leaves every other
layer as it is, so a network applies them to exactly the sub-modules its authors' code applies them to.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from clods_bench.numerics.truncated_normal import truncated_normal_


@torch.no_grad()
def trunc_normal_init(module: nn.Module, std: float = 0.02, types: tuple[type[nn.Module], ...] = (nn.Conv2d,)) -> nn.Module:
    """Every layer of `types` in `module`: weight ~ truncated normal(0, std) on [-2, 2], bias 0 (OpenSTL's rule). Returns `module`."""
    for m in module.modules():
        if isinstance(m, types):
            truncated_normal_(m.weight, mean=0.0, std=std, a=-2.0, b=2.0)
            if getattr(m, "bias", None) is not None:
                nn.init.zeros_(m.bias)
    return module


@torch.no_grad()
def fan_out_normal_init(module: nn.Module) -> nn.Module:
    """Every Conv2d in `module`: weight ~ normal(0, sqrt(2 / fan_out)), fan_out = kh*kw*out/groups, bias 0 (VAN's rule,
    OpenSTL's MetaFormer MLPs). Returns `module`."""
    for m in module.modules():
        if isinstance(m, nn.Conv2d):
            fan_out = m.kernel_size[0] * m.kernel_size[1] * m.out_channels // m.groups
            m.weight.normal_(0.0, math.sqrt(2.0 / fan_out))
            if m.bias is not None:
                m.bias.zero_()
    return module
