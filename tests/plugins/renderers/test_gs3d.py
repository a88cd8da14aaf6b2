"""Per-frame 3DGS: initialisations, fitting raises training-view PSNR, the per-frame cache, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import Camera, intrinsics_from_fov, look_at
from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.games import GamesConfig
from clods_bench.plugins.renderers.gs3d import Gs3dConfig, Gs3dRenderer, random_init, rotmat_to_quat, surface_init, visible_faces
from clods_bench.splatting.projection import quat_to_rotmat

from .conftest import grid_mesh, rig
from .test_games import fitted, randomise


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return -10.0 * math.log10(float(((a - b) ** 2).mean()))


def _teacher_images(mesh, cams, seed: int = 3) -> torch.Tensor:
    """(N,H,W,3) images of the mesh covered by opaque random-coloured GaMeS Gaussians (a textured cloth)."""
    teacher = fitted(mesh, GamesConfig(iterations=0, init_opacity=0.9), cams, seed=seed)
    randomise(teacher, seed)
    with torch.no_grad():
        return teacher.render(torch.tensor(mesh[0], dtype=torch.float32), cams).clamp(0, 1)


def _flat_mesh() -> tuple[np.ndarray, np.ndarray]:
    """Two triangles in the plane y = 0.2 (normal along y), areas 0.5 (x + z <= 1) and 0.25 (x + z >= 1)."""
    verts = np.array([[0.0, 0.2, 0.0], [1.0, 0.2, 0.0], [0.0, 0.2, 1.0], [1.0, 0.2, 1.0], [1.0, 0.2, 0.5]])
    cells = np.array([[0, 1, 2], [1, 4, 2]])
    return verts, cells


def test_rotmat_to_quat_inverts_quat_to_rotmat():
    q = torch.randn(500, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    q[:4] = torch.tensor([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]], dtype=torch.float64)  # 0 and 180 degrees
    q = q * torch.where(q[:, :1] < 0, -1.0, 1.0)  # w >= 0: the sign rotmat_to_quat returns
    back = rotmat_to_quat(quat_to_rotmat(q))
    np.testing.assert_allclose(back.numpy(), q.numpy(), atol=1e-12)


def test_surface_init_lies_on_the_faces_and_is_face_aligned():
    verts, cells = _flat_mesh()
    means, quats, log_scales = surface_init(verts, cells, 4000, torch.Generator().manual_seed(0))
    m = means.double().numpy()
    np.testing.assert_allclose(m[:, 1], 0.2, atol=1e-6)  # on the plane
    assert (m[:, 0] >= -1e-6).all() and (m[:, 2] >= -1e-6).all() and (m[:, 0] <= 1 + 1e-6).all()
    assert (m[:, 2] <= 1 - 0.5 * m[:, 0] + 1e-6).all()  # below the far edge of the second triangle
    in_small = m[:, 0] + m[:, 2] > 1.0  # inside the second triangle: 1/3 of the area
    assert abs(in_small.mean() - 1 / 3) < 0.03  # area-weighted sampling
    R = quat_to_rotmat(quats.double())
    s = log_scales.exp()
    thin = R[torch.arange(len(s)), :, s.argmin(-1)]  # axis of the smallest scale
    np.testing.assert_allclose(thin[:, 1].abs().numpy(), 1.0, atol=1e-5)  # along the face normal (y)
    spacing = math.sqrt(0.75 / 4000)
    np.testing.assert_allclose(s.numpy(), np.broadcast_to([0.1 * spacing, 0.5 * spacing, 0.5 * spacing], s.shape), rtol=1e-5)


def test_random_init_fills_the_padded_box():
    verts, _ = _flat_mesh()
    means, quats, log_scales = random_init(verts, 4000, 0.1, torch.Generator().manual_seed(0))
    m = means.numpy()
    lo, hi = verts.min(0) - 0.1, verts.max(0) + 0.1  # largest side 1 -> padding 0.1 on every side
    assert (m >= lo - 1e-6).all() and (m <= hi + 1e-6).all()
    np.testing.assert_allclose(m.mean(0), (lo + hi) / 2, atol=0.02)  # uniform: the mean is the box centre
    assert np.ptp(m[:, 1]) > 0.15  # spread off the cloth's plane, unlike the surface init
    np.testing.assert_allclose(quats.numpy(), np.tile([1.0, 0, 0, 0], (4000, 1)))
    assert torch.allclose(log_scales, log_scales[0, 0])  # isotropic, all equal


def _two_sheets() -> tuple[np.ndarray, np.ndarray]:
    """Two parallel 8x8-quad sheets of 1 m x 1 m facing +y/-y: the near one at y = -0.3, the far one at y = +0.3."""
    verts, cells, _ = grid_mesh(8, 8, size=(1.0, 1.0), wave=0.0)  # in the x-z plane at y = 0
    near, far = verts + [0.0, -0.3, 0.0], verts + [0.0, 0.3, 0.0]
    return np.concatenate([near, far]), np.concatenate([cells, cells + len(verts)])


def _camera_on_y(y: float, size: int = 48) -> Camera:
    R, t = look_at(np.array([0.0, y, 0.0]), np.zeros(3))
    return Camera(intrinsics_from_fov(40.0, size, size), R, t, size, size)


def test_visible_faces_are_the_ones_no_nearer_sheet_hides():
    verts, cells = _two_sheets()
    half = len(cells) // 2
    from_front = visible_faces(verts, cells, [_camera_on_y(-3.0)])  # looks along +y: the near sheet hides the far one
    assert from_front[:half].all() and not from_front[half:].any()
    from_back = visible_faces(verts, cells, [_camera_on_y(3.0)])
    assert from_back[half:].all() and not from_back[:half].any()
    assert visible_faces(verts, cells, [_camera_on_y(-3.0), _camera_on_y(3.0)]).all()  # one camera each side: all
    shifted = verts + [5.0, 0.0, 0.0]  # out of the camera's field of view: nothing is visible
    assert not visible_faces(shifted, cells, [_camera_on_y(-3.0)]).any()


def test_visible_init_puts_every_gaussian_on_the_seen_sheet():
    verts, cells = _two_sheets()
    faces = visible_faces(verts, cells, [_camera_on_y(-3.0)])
    means, _, _ = surface_init(verts, cells, 2000, torch.Generator().manual_seed(0), faces)
    np.testing.assert_allclose(means[:, 1].numpy(), -0.3, atol=1e-6)  # all on the near sheet
    everywhere, _, _ = surface_init(verts, cells, 2000, torch.Generator().manual_seed(0))
    assert abs(float((everywhere[:, 1] > 0).float().mean()) - 0.5) < 0.05  # without the mask: half on each sheet
    nothing = np.zeros(len(cells), bool)  # no face seen: falls back to every face rather than failing
    fallback, _, _ = surface_init(verts, cells, 2000, torch.Generator().manual_seed(0), nothing)
    torch.testing.assert_close(fallback, everywhere)


@pytest.mark.parametrize("init", ["visible", "surface", "random"])
def test_fit_raises_training_psnr_well_above_the_init(mesh, init):
    cams = rig(2, 20)
    target = _teacher_images(mesh, cams)
    cfg = dict(num_gaussians=300, init=init)
    untrained = Gs3dRenderer(Gs3dConfig(iterations=0, **cfg))
    untrained.fit(mesh[0][None], mesh[1], mesh[2], target[None].numpy(), cams)
    trained = Gs3dRenderer(Gs3dConfig(iterations=200, **cfg))
    stats = trained.fit(mesh[0][None], mesh[1], mesh[2], target[None].numpy(), cams)
    v = torch.tensor(mesh[0], dtype=torch.float32)
    with torch.no_grad():
        before, after = _psnr(untrained.render(v, cams), target), _psnr(trained.render(v, cams), target)
    assert after > before + 6.0, (before, after)
    assert stats["loss_final"] < 0.5 * stats["loss_first"]
    assert stats["frames"] == 1 and stats["num_gaussians"] == 300


def test_cache_keeps_one_representation_per_frame(mesh):
    verts, cells, mesh_pos = mesh
    cams = rig(2, 12)
    red = np.broadcast_to(np.array([1.0, 0.1, 0.1], np.float32), (1, 2, 12, 12, 3)).copy()
    blue = red[..., ::-1].copy()
    other = verts + np.array([0.0, 0.3, 0.0])
    r = Gs3dRenderer(Gs3dConfig(num_gaussians=200, iterations=40))
    r.fit(verts[None], cells, mesh_pos, red, cams)
    r.fit(other[None], cells, mesh_pos, blue, cams)
    assert len(r.frames) == 2
    with torch.no_grad():
        a = r.render(torch.tensor(verts, dtype=torch.float32), cams)
        b = r.render(torch.tensor(other, dtype=torch.float32), cams)
        a_again = r.render(torch.tensor(verts + 1e-6, dtype=torch.float32), cams)  # within match_tol
    assert float(a[..., 0].mean() - a[..., 2].mean()) > 0.2  # frame 0 was fitted to red
    assert float(b[..., 2].mean() - b[..., 0].mean()) > 0.2  # frame 1 to blue
    torch.testing.assert_close(a, a_again)
    r.fit(verts[None], cells, mesh_pos, blue, cams)  # refit frame 0: replaces, does not add
    assert len(r.frames) == 2
    with torch.no_grad():
        a2 = r.render(torch.tensor(verts, dtype=torch.float32), cams)
    assert float(a2[..., 2].mean() - a2[..., 0].mean()) > 0.2
    both = Gs3dRenderer(Gs3dConfig(num_gaussians=50, iterations=2))  # B frames in one call: one fit each
    stats = both.fit(np.stack([verts, other]), cells, mesh_pos, np.concatenate([red, blue]), cams)
    assert len(both.frames) == 2 and stats["frames"] == 2


def test_render_of_an_unfitted_mesh_raises(mesh):
    verts, cells, mesh_pos = mesh
    cams = rig(2, 12)
    r = Gs3dRenderer(Gs3dConfig(num_gaussians=20, iterations=0))
    with pytest.raises(ClodsError, match="before fit"):
        r.render(torch.tensor(verts), cams)
    r.fit(verts[None], cells, mesh_pos, np.full((1, 2, 12, 12, 3), 0.5, np.float32), cams)
    moved = verts + np.array([0.0, 0.01, 0.0])  # 1 cm, far above match_tol * diagonal
    with pytest.raises(ClodsError, match="no representation fitted on this mesh"):
        r.render(torch.tensor(moved), cams)
    with pytest.raises(ClodsError, match=r"\(12,3\)"):
        r.render(torch.tensor(verts[:5]), cams)


def test_degenerate_mesh_initialises_and_renders_finite(mesh):
    verts, cells, mesh_pos = mesh
    cams = rig(2, 12)
    point = np.zeros_like(verts)  # every face has zero area: uniform face sampling, identity frames
    r = Gs3dRenderer(Gs3dConfig(num_gaussians=30, iterations=3))
    stats = r.fit(point[None], cells, mesh_pos, np.full((1, 2, 12, 12, 3), 0.5, np.float32), cams)
    assert np.isfinite(stats["loss_final"])
    out = r.render(torch.tensor(point), cams)
    assert torch.isfinite(out).all()
    for name, p in r.frames[0][1].items():
        assert torch.isfinite(p).all(), name


def test_bad_config_raises():
    with pytest.raises(ClodsError, match="init"):
        Gs3dRenderer(Gs3dConfig(init="sphere"))  # type: ignore[arg-type]
    with pytest.raises(ClodsError, match="num_gaussians"):
        Gs3dRenderer(Gs3dConfig(num_gaussians=0))
    with pytest.raises(ClodsError, match="match_tol"):
        Gs3dRenderer(Gs3dConfig(match_tol=0.0))
