"""A truncated-normal weight initialisation whose draws do not depend on the installed torch version.

`torch.nn.init.trunc_normal_` changed its algorithm in torch 2.13: up to 2.12 it mapped uniform draws through the
inverse error function (the method timm's `trunc_normal_` also uses); from 2.13 it draws normals and redraws those
outside the interval. The same seed therefore gives other initial weights under torch 2.11 (the GPU machines'
build) than under the pinned 2.13, and every fit after it other numbers. This module fixes one algorithm, the
redraw one the committed tables were made with, so any torch version (and any device, the draws being made on the
tensor's device by its generator) starts a model from the same weights as the pinned one on the same device.
"""

from __future__ import annotations

import math

import torch

MIN_MASS = 0.3
"""The interval must hold more than this share of the normal's mass (redrawing would be slow otherwise)."""


@torch.no_grad()
def truncated_normal_(
    tensor: torch.Tensor,
    mean: float = 0.0,
    std: float = 1.0,
    a: float = -2.0,
    b: float = 2.0,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Fill `tensor` in place with normal(mean, std) draws restricted to [a, b]; returns `tensor`.

    Every value is drawn from the normal; while some lie outside [a, b] (bounds rounded to the tensor's dtype), a whole
    fresh normal tensor is drawn and its values replace just those. This is the sequence of generator calls torch
    2.13's `trunc_normal_` makes for such intervals, so the result equals it bit for bit under every torch version.
    """
    if not std > 0.0:
        raise ValueError(f"truncated_normal_: std must be positive, got {std}")
    if not a < b:
        raise ValueError(f"truncated_normal_: the interval [a, b] = [{a}, {b}] is empty")
    mass = 0.5 * (math.erf((b - mean) / (std * math.sqrt(2.0))) - math.erf((a - mean) / (std * math.sqrt(2.0))))
    if mass <= MIN_MASS:
        raise ValueError(
            f"truncated_normal_: [{a}, {b}] holds {mass:.3g} of normal({mean}, {std}), at most {MIN_MASS}; "
            "redrawing would rarely land inside it (use torch.nn.init.trunc_normal_)"
        )
    if tensor.is_meta or tensor.numel() == 0:
        return tensor
    lo = tensor.new_tensor(a, device="cpu").item()
    hi = tensor.new_tensor(b, device="cpu").item()
    result = tensor.normal_(mean, std, generator=generator)
    while True:
        outside = (result < lo) | (result > hi)
        if not bool(outside.any()):
            break
        fresh = torch.empty_like(result).normal_(mean, std, generator=generator)
        result = torch.where(outside, fresh, result)
    if result is not tensor:
        tensor.copy_(result)
    return tensor
