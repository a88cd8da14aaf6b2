"""Face-anchored flat Gaussians (GaMeS frame): the formula, degenerate faces, and gradients to the vertices."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import camera_rig
from clods_bench.splatting import render_gaussians
from clods_bench.splatting.flag_scene import BARYCENTRICS, face_gaussians

F64 = torch.float64
BACKENDS = ["cpu", "reference"]


def test_covariance_is_the_games_frame() -> None:
    g = torch.Generator().manual_seed(0)
    verts = torch.randn(9, 3, generator=g, dtype=F64)
    faces = torch.arange(9).reshape(3, 3)
    means, cov = face_gaussians(verts, faces, scale=1.3)
    assert means.shape == (15, 3) and cov.shape == (15, 3, 3)
    for f in range(3):  # the GaMeS recipe step by step with explicit normalisations
        v0, v1, v2 = verts[faces[f]].numpy()
        c = (v0 + v1 + v2) / 3
        r2 = (v1 - c) / np.linalg.norm(v1 - c)
        r3 = (v2 - c) - np.dot(v2 - c, r2) * r2
        r3 /= np.linalg.norm(r3)
        s2, s3 = 1.3 * np.linalg.norm(v1 - c) / 2, 1.3 * np.dot(v2 - c, r3) / 2
        expect = s2**2 * np.outer(r2, r2) + s3**2 * np.outer(r3, r3)
        for k in range(5):
            np.testing.assert_allclose(cov[5 * f + k].numpy(), expect, atol=1e-12)
            np.testing.assert_allclose(means[5 * f + k].numpy(), np.array(BARYCENTRICS[k]) @ np.stack([v0, v1, v2]), atol=1e-12)
        normal = np.cross(v1 - v0, v2 - v0)
        np.testing.assert_allclose(cov[5 * f].numpy() @ normal, 0.0, atol=1e-12)  # zero thickness along the normal


def _mesh_with_degenerate_faces() -> tuple[torch.Tensor, torch.Tensor]:
    """A proper triangle, a zero-area (collinear) one and one collapsed to a point, near the origin."""
    verts = torch.tensor(
        [[-0.3, -0.2, 0.0], [0.2, -0.25, 0.05], [0.0, 0.3, -0.05],  # proper
         [-0.2, 0.1, 0.1], [0.0, 0.15, 0.1], [0.2, 0.2, 0.1],  # collinear
         [0.1, -0.1, -0.1], [0.1, -0.1, -0.1], [0.1, -0.1, -0.1]],  # collapsed
        dtype=F64,
    )  # fmt: skip
    return verts, torch.arange(9).reshape(3, 3)


def test_degenerate_faces_give_rank_one_and_zero_covariances() -> None:
    verts, faces = _mesh_with_degenerate_faces()
    _, cov = face_gaussians(verts, faces)
    ranks = [int(torch.linalg.matrix_rank(cov[5 * f], atol=1e-12)) for f in range(3)]
    assert ranks == [2, 1, 0] and torch.isfinite(cov).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_degenerate_faces_render_finitely_with_finite_vertex_gradients(backend: str) -> None:
    verts, faces = _mesh_with_degenerate_faces()
    verts = verts.clone().requires_grad_(True)
    means, cov = face_gaussians(verts, faces)
    G = means.shape[0]
    colors = torch.rand(G, 3, generator=torch.Generator().manual_seed(1), dtype=F64)
    out = render_gaussians(means, cov, torch.full((G,), 0.8, dtype=F64), colors, camera_rig(2, np.zeros(3), 2.0, 24, 20),
                           backend=backend)  # fmt: skip
    assert all(torch.isfinite(getattr(out, k)).all() for k in ("rgb", "alpha", "depth"))
    assert int((out.radii > 0).sum()) == 2 * G  # degenerate faces still show (the 0.3 px^2 dilation)
    (out.rgb.sum() + out.depth.sum()).backward()
    assert torch.isfinite(verts.grad).all() and float(verts.grad[:3].abs().sum()) > 0


@pytest.mark.parametrize("backend", BACKENDS)
def test_vertex_gradients_through_face_gaussians_match_finite_differences(backend: str) -> None:
    verts = torch.tensor([[-0.3, -0.25, 0.0], [0.3, -0.2, 0.05], [0.0, 0.3, -0.05], [0.35, 0.3, 0.1]], dtype=F64)
    faces = torch.tensor([[0, 1, 2], [1, 3, 2]])
    cameras = camera_rig(2, np.zeros(3), 2.0, 20, 16)
    G = 10
    colors = torch.rand(G, 3, generator=torch.Generator().manual_seed(2), dtype=F64)
    opac = torch.linspace(0.3, 0.8, G, dtype=F64)
    w = torch.rand(2, 16, 20, 5, generator=torch.Generator().manual_seed(3), dtype=F64)

    def loss(v: torch.Tensor) -> torch.Tensor:
        means, cov = face_gaussians(v, faces, scale=0.8)
        out = render_gaussians(means, cov, opac, colors, cameras, backend=backend)
        return (torch.cat([out.rgb, out.alpha, out.depth], dim=-1) * w).sum()

    v = verts.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(loss(v), v)
    assert float(grad.abs().min()) > 0  # every vertex moves the image: the comparison is not 0 == 0
    assert torch.autograd.gradcheck(loss, (v,), eps=1e-7, atol=1e-5, rtol=1e-4)
