"""GaMeS: gradients w.r.t. the vertices, fitting, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.games import GamesConfig, GamesRenderer
from clods_bench.plugins.renderers.losses import render_loss

from .conftest import grid_mesh, rig


def fitted(mesh, config: GamesConfig, cams, cls=GamesRenderer, seed: int = 0):
    """A renderer fitted with 0 iterations (parameters at their initial values) on white images."""
    verts, cells, mesh_pos = mesh
    r = cls(config, seed=seed)
    images = np.ones((1, len(cams), cams[0].height, cams[0].width, 3), np.float32)
    r.fit(verts[None], cells, mesh_pos, images, cams)
    return r


def randomise(r: GamesRenderer, seed: int = 0) -> None:
    """Random colours, scales and opacities (in the valid ranges), so gradients are not trivial."""
    g = torch.Generator().manual_seed(seed)
    for name, p in r.params.items():
        if name == "color":
            p.copy_(torch.rand(p.shape, generator=g))
        elif name == "log_scale":
            p.copy_(torch.rand(p.shape, generator=g) - 0.5)
        elif name == "opacity_logit":
            p.copy_(torch.rand(p.shape, generator=g) * 2 - 1)


def check_vertex_gradient(r, verts: np.ndarray, cams, h: float = 1e-6) -> None:
    """Autograd d(loss)/d(verts) through the renderer equals central differences (float64, reference backend)."""
    weights = torch.rand((len(cams), cams[0].height, cams[0].width, 3), generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def loss(v: torch.Tensor) -> torch.Tensor:
        return (r.render(v, cams) * weights).sum()

    v = torch.tensor(verts, dtype=torch.float64, requires_grad=True)
    loss(v).backward()
    grad = v.grad.numpy()
    assert np.abs(grad).max() > 1e-3  # the loss does depend on the vertices
    fd = np.zeros_like(verts)
    for i in range(verts.shape[0]):
        for k in range(3):
            dv = np.zeros_like(verts)
            dv[i, k] = h
            fd[i, k] = (float(loss(torch.tensor(verts + dv))) - float(loss(torch.tensor(verts - dv)))) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


def test_vertex_gradient_matches_finite_differences():
    mesh = grid_mesh(2, 1)
    cams = rig(1, 12)
    r = fitted(mesh, GamesConfig(gaussians_per_face=2, iterations=0, backend="reference", normal_scale=1e-3), cams)
    randomise(r)
    check_vertex_gradient(r, mesh[0], cams)


def test_render_is_differentiable_and_shaped(mesh):
    cams = rig(2, 16)
    r = fitted(mesh, GamesConfig(iterations=0), cams)
    v = torch.tensor(mesh[0], dtype=torch.float32, requires_grad=True)
    out = r.render(v, cams)
    assert out.shape == (2, 16, 16, 3) and out.dtype == torch.float32
    out.mean().backward()
    assert torch.isfinite(v.grad).all() and v.grad.abs().max() > 0


def test_fit_reduces_loss_towards_a_teacher(mesh):
    """Fit grey Gaussians to images rendered by a teacher with random colours: the loss falls a lot."""
    cams = rig(2, 20)
    teacher = fitted(mesh, GamesConfig(iterations=0, init_opacity=0.9), cams, seed=3)
    randomise(teacher, 3)
    with torch.no_grad():
        target = teacher.render(torch.tensor(mesh[0], dtype=torch.float32), cams)
    student = GamesRenderer(GamesConfig(iterations=60))
    stats = student.fit(mesh[0][None], mesh[1], mesh[2], target[None].numpy(), cams)
    with torch.no_grad():
        final = float(render_loss(student.render(torch.tensor(mesh[0], dtype=torch.float32), cams), target))
    assert stats["loss_final"] < 0.4 * stats["loss_first"]
    assert final < 0.4 * stats["loss_first"]
    assert stats["num_gaussians"] == mesh[1].shape[0] * 5


def test_sh_colours_fit_and_render(mesh):
    cams = rig(2, 16)
    r = GamesRenderer(GamesConfig(iterations=3, sh_degree=2))
    r.fit(mesh[0][None], mesh[1], mesh[2], np.full((1, 2, 16, 16, 3), 0.3, np.float32), cams)
    assert r.params["sh_rest"].shape == (r.num_gaussians, 8, 3)
    out = r.render(torch.tensor(mesh[0]), cams)
    assert torch.isfinite(out).all()


def test_fit_on_several_frames(mesh):
    cams = rig(2, 16)
    frames = np.stack([mesh[0], mesh[0] + [0.0, 0.05, 0.0]])
    stats = GamesRenderer(GamesConfig(iterations=4)).fit(frames, mesh[1], mesh[2], np.full((2, 2, 16, 16, 3), 0.5, np.float32), cams)
    assert np.isfinite(stats["loss_final"])


def test_degenerate_faces_render_finite(mesh):
    verts, cells, mesh_pos = mesh
    cams = rig(2, 16)
    r = fitted(mesh, GamesConfig(iterations=0), cams)
    squashed = verts.copy()
    squashed[cells[0]] = squashed[cells[0][0]]  # first face collapses to a point
    squashed[:, 1] = 0.0  # and every face lies in one plane seen edge-on by nobody
    v = torch.tensor(squashed, requires_grad=True)
    out = r.render(v, cams)
    out.sum().backward()
    assert torch.isfinite(out).all() and torch.isfinite(v.grad).all()


def test_bad_input_raises(mesh):
    verts, cells, mesh_pos = mesh
    cams = rig(2, 16)
    good = np.full((1, 2, 16, 16, 3), 0.5, np.float32)
    r = GamesRenderer(GamesConfig(iterations=0))
    with pytest.raises(ClodsError, match="before fit"):
        r.render(torch.tensor(verts), cams)
    with pytest.raises(ClodsError, match="images have shape"):
        r.fit(verts[None], cells, mesh_pos, np.full((1, 2, 16, 17, 3), 0.5, np.float32), cams)
    with pytest.raises(ClodsError, match="images have shape"):
        r.fit(verts[None], cells, mesh_pos, good[:, :1], cams)
    bad = verts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ClodsError, match=r"non-finite vertex.*\(0, 3\)"):
        r.fit(bad[None], cells, mesh_pos, good, cams)
    with pytest.raises(ClodsError, match="leading frame axis"):
        r.fit(verts, cells, mesh_pos, good, cams)
    with pytest.raises(ClodsError, match="triangle indices"):
        r.fit(verts[None], cells + 100, mesh_pos, good, cams)
    with pytest.raises(ClodsError, match="floats in"):
        r.fit(verts[None], cells, mesh_pos, (good * 255).astype(np.uint8), cams)
    r.fit(verts[None], cells, mesh_pos, good, cams)
    with pytest.raises(ClodsError, match="non-finite vertex"):
        r.render(torch.tensor(bad), cams)
    with pytest.raises(ClodsError, match=r"\(12,3\)"):
        r.render(torch.tensor(verts[:5]), cams)


def test_bad_config_raises():
    with pytest.raises(ClodsError, match="gaussians_per_face"):
        GamesRenderer(GamesConfig(gaussians_per_face=0))
    with pytest.raises(ClodsError, match="backend"):
        GamesRenderer(GamesConfig(backend="opengl"))  # type: ignore[arg-type]
    with pytest.raises(ClodsError, match="init_opacity"):
        GamesRenderer(GamesConfig(init_opacity=1.0))
