"""Closed-form images: one isotropic Gaussian seen head-on, and front-to-back compositing order."""

from __future__ import annotations

import math

import pytest
import torch

from clods_bench.splatting import render_gaussians
from tests.splatting.conftest import head_on_camera

BACKENDS = ["cpu", "reference"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_isotropic_gaussian_matches_analytic_image(backend: str) -> None:
    cam = head_on_camera(width=40, height=24, f=100.0)
    z, sigma, opacity = 2.0, 0.03, 0.8
    colour, bg = torch.tensor([0.9, 0.2, 0.1], dtype=torch.float64), torch.tensor([0.1, 0.3, 1.0], dtype=torch.float64)
    out = render_gaussians(
        torch.tensor([[0.0, 0.0, z]], dtype=torch.float64),
        (sigma**2 * torch.eye(3, dtype=torch.float64))[None],
        torch.tensor([opacity], dtype=torch.float64),
        colour[None],
        [cam],
        background=bg,
        backend=backend,
    )
    s2 = (100.0 * sigma / z) ** 2 + 0.3  # projected variance plus the 0.3 px^2 dilation
    v, u = torch.meshgrid(torch.arange(24.0, dtype=torch.float64) + 0.5, torch.arange(40.0, dtype=torch.float64) + 0.5, indexing="ij")
    alpha = opacity * torch.exp(-0.5 * ((u - 20.0) ** 2 + (v - 12.0) ** 2) / s2)
    alpha = torch.where(alpha >= 1 / 255, alpha, torch.zeros_like(alpha))  # the rasterizer skips fainter ones
    assert (alpha == 0).any() and (alpha > 0.7).any()
    torch.testing.assert_close(out.alpha[0, ..., 0], alpha, atol=1e-12, rtol=0)
    expected = alpha[..., None] * colour + (1 - alpha[..., None]) * bg
    torch.testing.assert_close(out.rgb[0], expected, atol=1e-12, rtol=0)
    covered = alpha > 0
    torch.testing.assert_close(out.depth[0, ..., 0][covered], torch.full_like(alpha[covered], z))
    assert (out.depth[0, ..., 0][~covered] == 0).all()
    # opacity-aware radius: sqrt(2 ln(255 o)) sigma, rounded up
    assert int(out.radii[0, 0]) == math.ceil(math.sqrt(2 * math.log(255 * opacity)) * math.sqrt(s2))


@pytest.mark.parametrize("backend", BACKENDS)
def test_nearer_gaussian_dominates_whatever_the_input_order(backend: str) -> None:
    cam = head_on_camera(width=32, height=32, f=100.0)
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0]], dtype=torch.float64)  # red near, green far
    covars = torch.stack([0.05**2 * torch.eye(3), (0.075**2) * torch.eye(3)]).to(torch.float64)
    opac = torch.tensor([0.9, 0.9], dtype=torch.float64)
    colors = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
    renders = []
    for perm in ([0, 1], [1, 0]):
        out = render_gaussians(means[perm], covars[perm], opac[perm], colors[perm], [cam], background=(0, 0, 0), backend=backend)
        renders.append(out)
    torch.testing.assert_close(renders[0].rgb, renders[1].rgb, atol=0, rtol=0)
    centre = renders[0].rgb[0, 16, 16]
    a_near = 0.9 * math.exp(-0.5 * 0.5 / ((100 * 0.05 / 2) ** 2 + 0.3))  # pixel centre is 0.5 px off in x and y
    a_far = 0.9 * math.exp(-0.5 * 0.5 / ((100 * 0.075 / 3) ** 2 + 0.3))
    torch.testing.assert_close(centre, torch.tensor([a_near, (1 - a_near) * a_far, 0.0], dtype=torch.float64))
    assert centre[0] > 5 * centre[1]
    torch.testing.assert_close(renders[0].radii, renders[1].radii.flip(1))


@pytest.mark.parametrize("backend", BACKENDS)
def test_compositing_stops_before_transmittance_drops_below_1e_4(backend: str) -> None:
    cam = head_on_camera(width=16, height=16, f=100.0)
    n = 6
    means = torch.tensor([[0.0, 0.0, 2.0 + 0.1 * i] for i in range(n)], dtype=torch.float64)
    covars = (0.2**2 * torch.eye(3, dtype=torch.float64)).expand(n, 3, 3)
    opac = torch.full((n,), 0.95, dtype=torch.float64)
    colors = torch.rand(n, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    out = render_gaussians(means, covars, opac, colors, [cam], background=(0, 0, 0), backend=backend)
    # sequential 3DGS rule at pixel (8, 8), centre (8.5, 8.5): a Gaussian that would bring T below 1e-4 is dropped
    T, rgb, used = 1.0, torch.zeros(3, dtype=torch.float64), 0
    for i in range(n):
        s2 = (100 * 0.2 / float(means[i, 2])) ** 2 + 0.3
        a = min(0.99, 0.95 * math.exp(-0.5 * 0.5 / s2))
        if T * (1 - a) < 1e-4:
            break
        rgb, T, used = rgb + colors[i] * a * T, T * (1 - a), used + 1
    assert used == 3  # 0.05^3 > 1e-4 > 0.05^4: the 4th Gaussian terminates compositing
    torch.testing.assert_close(out.rgb[0, 8, 8], rgb, atol=1e-12, rtol=0)
    torch.testing.assert_close(out.alpha[0, 8, 8, 0], torch.tensor(1 - T, dtype=torch.float64), atol=1e-12, rtol=0)
