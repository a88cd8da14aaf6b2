"""Projection, covariance and spherical-harmonics building blocks, and lazy imports."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import torch

from clods_bench.datasets.cameras import camera_rig
from clods_bench.splatting import (
    camera_tensors,
    covariances_from_quats_scales,
    project_gaussians,
    sh_basis,
    tile_bounds,
    view_colors,
)
from tests.splatting.conftest import random_scene


def test_means_project_like_camera_project_and_conics_invert_covars2d() -> None:
    scene = random_scene(50, seed=1)
    cams = camera_rig(3, np.zeros(3), 3.0, 64, 48)
    Ks, Rs, ts, _ = camera_tensors(cams)
    proj = project_gaussians(scene["means"], scene["covars"], scene["opacities"], Ks, Rs, ts, 64, 48)
    for c, cam in enumerate(cams):
        uv, z = cam.project(scene["means"].numpy())
        np.testing.assert_allclose(proj.means2d[c].numpy(), uv, atol=1e-9)
        np.testing.assert_allclose(proj.depths[c].numpy(), z, atol=1e-12)
    a, b, c_ = proj.conics.unbind(-1)
    inv = torch.stack([torch.stack([a, b], -1), torch.stack([b, c_], -1)], -2)
    eye = torch.eye(2, dtype=torch.float64).expand_as(inv)
    torch.testing.assert_close(inv @ proj.covars2d, eye, atol=1e-9, rtol=0)
    assert (torch.linalg.eigvalsh(proj.covars2d) >= 0.3 - 1e-9).all()  # the dilation is a floor on both axes


def test_covariances_from_quats_scales_are_r_s2_rt() -> None:
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0], [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]], dtype=torch.float64)
    scales = torch.tensor([[1.0, 2.0, 3.0], [1.0, 2.0, 0.0]], dtype=torch.float64)
    cov = covariances_from_quats_scales(quats, scales)
    torch.testing.assert_close(cov[0], torch.diag(torch.tensor([1.0, 4.0, 9.0], dtype=torch.float64)))
    # 90 degrees about z swaps the x and y variances; zero scale gives a flat (rank-2) covariance
    torch.testing.assert_close(cov[1], torch.diag(torch.tensor([4.0, 1.0, 0.0], dtype=torch.float64)), atol=1e-12, rtol=0)


def test_tile_bounds_cover_the_bounding_box() -> None:
    means2d = torch.tensor([[[20.0, 20.0], [0.0, 0.0], [100.0, 5.0]]], dtype=torch.float64)
    radii = torch.tensor([[[4, 4], [3, 3], [0, 0]]], dtype=torch.int32)
    b = tile_bounds(means2d, radii, 40, 24, 16)
    assert b[0, 0].tolist() == [1, 1, 2, 2]  # box [16, 24] x [16, 24] lies in tile (1, 1)
    assert b[0, 1].tolist() == [0, 0, 1, 1]
    assert b[0, 2].tolist() == [0, 0, 0, 0]  # culled


def test_real_sh_basis_is_orthonormal_on_the_sphere() -> None:
    n = 40000  # Fibonacci sphere: near-uniform points, equal area weights
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = torch.sqrt(1 - z * z)
    dirs = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)
    Y = sh_basis(3, dirs)  # (n, 16)
    gram = 4 * math.pi / n * Y.T @ Y
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=2e-3, rtol=0)


def test_sh_colours_follow_3dgs_convention() -> None:
    means = torch.tensor([[0.0, 0.0, 0.0]], dtype=torch.float64)
    centers = torch.tensor([[0.0, 0.0, -2.0]], dtype=torch.float64)  # view direction +z
    coeffs = torch.zeros(1, 4, 3, dtype=torch.float64)
    coeffs[0, 0] = torch.tensor([1.0, -5.0, 0.0])
    coeffs[0, 2] = torch.tensor([0.5, 0.0, 0.0])  # the z band
    rgb = view_colors(coeffs, means, centers, 1)
    expect = torch.tensor([0.28209479177387814 + 0.4886025119029199 * 0.5 + 0.5, 0.0, 0.5], dtype=torch.float64)
    torch.testing.assert_close(rgb[0, 0], expect)  # +0.5 offset, clamped at 0
    assert view_colors(coeffs, means, centers, 0)[0, 0, 2] == 0.5


def test_importing_the_package_loads_neither_numba_kernels_nor_gsplat() -> None:
    code = (
        "import sys, clods_bench.splatting as s; "
        "bad = [m for m in ('clods_bench.splatting.fast_kernels', 'gsplat', 'numba') if m in sys.modules]; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr


def test_quats_and_scales_render_like_their_covariances() -> None:
    from clods_bench.splatting import render_gaussians

    g = torch.Generator().manual_seed(2)
    scene = random_scene(30, seed=2, dtype=torch.float32)
    quats = torch.randn(30, 4, generator=g).requires_grad_(True)
    scales = (torch.rand(30, 3, generator=g) * 0.08 + 0.01).requires_grad_(True)
    cams = camera_rig(2, np.zeros(3), 3.0, 24, 20)
    a = render_gaussians(scene["means"], None, scene["opacities"], scene["colors"], cams, quats=quats, scales=scales)
    # the same covariances computed by hand, R diag(s^2) R^T with R from the normalised quaternion
    q = torch.nn.functional.normalize(quats.detach().double(), dim=-1)
    R = torch.zeros(30, 3, 3, dtype=torch.float64)
    for i, (w, x, y, z) in enumerate(q.tolist()):
        R[i] = torch.tensor([[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                             [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                             [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]])  # fmt: skip
    covars = (R * scales.detach().double()[:, None, :] ** 2) @ R.transpose(1, 2)
    b = render_gaussians(scene["means"], covars.float(), scene["opacities"], scene["colors"], cams)
    torch.testing.assert_close(a.rgb, b.rgb, atol=1e-5, rtol=0)
    a.rgb.sum().backward()
    assert torch.isfinite(quats.grad).all() and float(scales.grad.abs().sum()) > 0
