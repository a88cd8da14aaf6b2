"""Analytic gradients (autograd through projection + each backend's backward) against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import camera_rig
from clods_bench.splatting import covariances_from_quats_scales, render_gaussians

BACKENDS = ["cpu", "reference"]


def _tiny(seed: int = 0) -> dict:
    """4 overlapping Gaussians (float64), opacities below the 0.99 clamp."""
    g = torch.Generator().manual_seed(seed)
    f64 = torch.float64
    return {
        "means": (torch.rand(4, 3, generator=g, dtype=f64) - 0.5) * 0.5,
        "quats": torch.randn(4, 4, generator=g, dtype=f64),
        "scales": torch.rand(4, 3, generator=g, dtype=f64) * 0.1 + 0.05,
        "opacities": torch.rand(4, generator=g, dtype=f64) * 0.6 + 0.2,
        "colors": torch.rand(4, 3, generator=g, dtype=f64),
        "sh": torch.randn(4, 4, 3, generator=g, dtype=f64) * 0.3,
        "background": torch.tensor([0.3, 0.6, 0.9], dtype=f64),
    }


def _loss_fn(cameras, backend: str, colour_key: str):
    """Scalar loss of the render as a function of the differentiable inputs (fixed random weights)."""
    weights = {}

    def loss(means, quats, scales, opacities, colors, background):
        covars = covariances_from_quats_scales(quats, scales)
        out = render_gaussians(means, covars, opacities, colors, cameras, background=background, backend=backend)
        total = 0.0
        for name in ("rgb", "alpha", "depth"):
            x = getattr(out, name)
            if name not in weights:
                weights[name] = torch.rand(x.shape, generator=torch.Generator().manual_seed(len(weights)), dtype=x.dtype)
            total = total + (x * weights[name]).sum()
        return total

    return loss


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("colour_key", ["colors", "sh"])
def test_gradients_match_finite_differences(backend: str, colour_key: str) -> None:
    s = _tiny()
    cameras = camera_rig(2, np.zeros(3), 2.0, 20, 16)
    inputs = tuple(s[k].clone().requires_grad_(True) for k in ("means", "quats", "scales", "opacities", colour_key, "background"))
    fn = _loss_fn(cameras, backend, colour_key)
    out = render_gaussians(s["means"], covariances_from_quats_scales(s["quats"], s["scales"]), s["opacities"], s["colors"], cameras)
    assert float(out.alpha.max()) > 0.5 and int((out.radii > 0).sum()) == 8  # every Gaussian visible in both views
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


@pytest.mark.parametrize("backend", BACKENDS)
def test_gradient_wrt_covariance_entries(backend: str) -> None:
    s = _tiny(seed=1)
    cameras = camera_rig(2, np.zeros(3), 2.0, 20, 16)
    covars = covariances_from_quats_scales(s["quats"], s["scales"]).detach().requires_grad_(True)
    means = s["means"].clone().requires_grad_(True)

    def fn(means, covars):
        out = render_gaussians(means, covars, s["opacities"], s["colors"], cameras, backend=backend)
        w = torch.linspace(0.0, 1.0, out.rgb.numel(), dtype=torch.float64).reshape(out.rgb.shape)
        return (out.rgb * w).sum() + out.depth.sum()

    assert torch.autograd.gradcheck(fn, (means, covars), eps=1e-8, atol=1e-5, rtol=1e-4)
