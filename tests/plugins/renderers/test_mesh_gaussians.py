"""Face-anchored Gaussians: frames, scales, layout, rigid motion with the mesh, degenerate faces."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.mesh_gaussians import (
    anchor_gaussians,
    barycentric_layout,
    face_frames,
    mesh_space_means,
)


def _faces(seed: int = 0, n: int = 6) -> torch.Tensor:
    return torch.tensor(np.random.default_rng(seed).standard_normal((n, 3, 3)))


def test_rotation_is_orthonormal_with_the_face_normal_first():
    tri = _faces()
    rot, _ = face_frames(tri, 1e-6)
    eye = torch.eye(3, dtype=torch.float64).expand_as(rot)
    torch.testing.assert_close(rot.transpose(-1, -2) @ rot, eye, atol=1e-12, rtol=0)
    t = tri.numpy()
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    np.testing.assert_allclose(rot[..., 0].numpy(), n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-12)
    c = t.mean(1)
    e = (t[:, 1] - c) / np.linalg.norm(t[:, 1] - c, axis=1, keepdims=True)
    np.testing.assert_allclose(rot[..., 1].numpy(), e, atol=1e-12)  # second axis towards vertex 1


def test_scales_of_a_known_triangle():
    tri = torch.tensor([[[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 3.0, 0.0]]], dtype=torch.float64)
    rot, scales = face_frames(tri, 1e-6)
    c = np.array([1.0, 1.0, 0.0])
    a = np.array([3.0, 0.0, 0.0]) - c  # (2,-1,0)
    b = np.array([0.0, 3.0, 0.0]) - c  # (-1,2,0)
    r3 = b - (b @ a) / (a @ a) * a
    np.testing.assert_allclose(rot[0, :, 0].numpy(), [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(scales[0].numpy(), [1e-6, np.linalg.norm(a) / 2, np.linalg.norm(r3) / 2], rtol=1e-12)


def test_layout_weights_are_inside_and_spread():
    for k in (1, 2, 5, 10, 20):
        w = barycentric_layout(k)
        assert w.shape == (k, 3)
        np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-12)
        assert (w >= 0).all()
        assert len({tuple(np.round(r, 9)) for r in w}) == k  # no two Gaussians share a place
    np.testing.assert_allclose(barycentric_layout(1), [[1 / 3] * 3])
    with pytest.raises(ClodsError, match="at least 1"):
        barycentric_layout(0)


def test_gaussians_move_rigidly_with_the_faces():
    rng = np.random.default_rng(1)
    verts = torch.tensor(rng.standard_normal((5, 3)))
    cells = torch.tensor([[0, 1, 2], [1, 3, 2], [2, 3, 4]])
    bary = torch.tensor(barycentric_layout(4))
    factor = torch.tensor(rng.uniform(0.5, 2.0, 12))
    means, covars, rot = anchor_gaussians(verts, cells, bary, factor, 1e-3)
    Q = torch.tensor(Rotation.random(random_state=3).as_matrix())
    shift = torch.tensor([0.3, -1.0, 2.0], dtype=torch.float64)
    means2, covars2, rot2 = anchor_gaussians(verts @ Q.T + shift, cells, bary, factor, 1e-3)
    torch.testing.assert_close(means2, means @ Q.T + shift, atol=1e-12, rtol=0)
    torch.testing.assert_close(covars2, Q @ covars @ Q.T, atol=1e-12, rtol=0)
    torch.testing.assert_close(rot2, Q @ rot, atol=1e-12, rtol=0)


def test_means_are_barycentric_combinations_and_covariance_is_flat():
    verts = _faces(2, 1)[0]
    bary = torch.tensor(barycentric_layout(3))
    means, covars, rot = anchor_gaussians(verts, torch.tensor([[0, 1, 2]]), bary, torch.ones(3, dtype=torch.float64), 1e-4)
    torch.testing.assert_close(means, bary @ verts)
    normal = rot[0, :, 0]
    var_n = normal @ covars[0] @ normal  # variance along the normal: eps^2
    assert float(var_n) == pytest.approx(1e-8, rel=1e-6)
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(covars[0].numpy()))[0], 1e-8, rtol=1e-6)


def test_mesh_space_means_use_the_same_weights():
    mesh_pos = torch.tensor([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0], [2.0, 1.0]], dtype=torch.float64)
    cells = torch.tensor([[0, 1, 2], [1, 3, 2]])
    bary = torch.tensor(barycentric_layout(2))
    out = mesh_space_means(mesh_pos, cells, bary)
    expected = torch.cat([bary @ mesh_pos[cells[0]], bary @ mesh_pos[cells[1]]])
    torch.testing.assert_close(out, expected)


def test_degenerate_faces_give_finite_gaussians_and_gradients():
    verts = torch.tensor([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 5, 5]], dtype=torch.float64, requires_grad=True)
    cells = torch.tensor([[0, 1, 2], [3, 3, 3]])  # collinear, and all three corners at one point
    means, covars, rot = anchor_gaussians(verts, cells, torch.tensor(barycentric_layout(2)), torch.ones(4, dtype=torch.float64), 1e-6)
    assert torch.isfinite(means).all() and torch.isfinite(covars).all() and torch.isfinite(rot).all()
    (covars.sum() + means.sum()).backward()
    assert torch.isfinite(verts.grad).all()
