"""SMGS: positional encoding, opacity inputs per ablation switch, gradients through the opacity MLP."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.smgs import SmgsConfig, SmgsRenderer, positional_encoding, sample_grid

from .conftest import grid_mesh, rig
from .test_games import check_vertex_gradient, fitted, randomise


def _opacities(r: SmgsRenderer, verts: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return r.gaussians(torch.tensor(verts))[2].numpy()


def _randomise_mlp(r: SmgsRenderer, seed: int = 0) -> None:
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in r.params.items():
            if name.startswith("mlp_") or name == "mesh_grid":
                p.copy_(torch.randn(p.shape, generator=g) * 0.7)


def test_positional_encoding_values():
    x = torch.tensor([[0.25, -0.5]], dtype=torch.float64)
    out = positional_encoding(x, 2).numpy()[0]
    expected = [0.25, -0.5]
    expected += [math.sin(math.pi * 0.25), math.sin(-math.pi * 0.5), math.sin(2 * math.pi * 0.25), math.sin(-2 * math.pi * 0.5)]
    expected += [math.cos(math.pi * 0.25), math.cos(-math.pi * 0.5), math.cos(2 * math.pi * 0.25), math.cos(-2 * math.pi * 0.5)]
    np.testing.assert_allclose(out, expected, atol=1e-15)
    assert positional_encoding(x, 0) is x


@pytest.mark.parametrize("inputs", ["both", "world", "mesh", "none"])
def test_opacity_depends_on_exactly_its_inputs(mesh, inputs):
    verts, cells, mesh_pos = mesh
    cams = rig(1, 12)
    r = fitted(mesh, SmgsConfig(iterations=0, inputs=inputs), cams, cls=SmgsRenderer)
    _randomise_mlp(r)
    base = _opacities(r, verts)
    moved = _opacities(r, verts + np.array([0.0, 0.2, 0.1]) * verts[:, :1])  # a shear: world positions change
    r2 = fitted((verts, cells, mesh_pos * 1.5 + 0.2), SmgsConfig(iterations=0, inputs=inputs), cams, cls=SmgsRenderer)
    _randomise_mlp(r2)
    other_mesh = _opacities(r2, verts)  # same world positions, mesh-space normalisation box differs -> same inputs
    flipped = fitted((verts, cells, mesh_pos[::-1].copy()), SmgsConfig(iterations=0, inputs=inputs), cams, cls=SmgsRenderer)
    _randomise_mlp(flipped)
    other_uv = _opacities(flipped, verts)  # same world positions, different mesh coordinates per node
    world_moves = not np.allclose(base, moved, atol=1e-9)
    mesh_matters = not np.allclose(base, other_uv, atol=1e-9)
    assert world_moves == (inputs in ("both", "world"))
    assert mesh_matters == (inputs in ("both", "mesh"))
    np.testing.assert_allclose(base, other_mesh, atol=1e-6)  # inputs are normalised to the bounding box
    if inputs == "none":
        assert np.ptp(base) == 0.0
    else:
        assert np.ptp(base) > 1e-3


def test_initial_opacity_is_near_the_configured_value(mesh):
    r = fitted(mesh, SmgsConfig(iterations=0, init_opacity=0.3), rig(1, 12), cls=SmgsRenderer)
    np.testing.assert_allclose(_opacities(r, mesh[0]), 0.3, atol=0.03)


def test_vertex_gradient_through_world_opacity_matches_finite_differences():
    mesh = grid_mesh(2, 1)
    cams = rig(1, 12)
    r = fitted(mesh, SmgsConfig(gaussians_per_face=2, iterations=0, backend="reference", normal_scale=1e-3, hidden=8), cams, cls=SmgsRenderer)
    randomise(r)
    _randomise_mlp(r)
    check_vertex_gradient(r, mesh[0], cams)


def test_fit_trains_the_mlp(mesh):
    cams = rig(2, 16)
    r = SmgsRenderer(SmgsConfig(iterations=20))
    before = None
    stats = r.fit(mesh[0][None], mesh[1], mesh[2], np.full((1, 2, 16, 16, 3), 0.2, np.float32), cams)
    assert stats["loss_final"] < stats["loss_first"]
    before = SmgsRenderer(SmgsConfig(iterations=0))
    before.fit(mesh[0][None], mesh[1], mesh[2], np.full((1, 2, 16, 16, 3), 0.2, np.float32), cams)
    assert not torch.allclose(r.params["mlp_w0"], before.params["mlp_w0"])
    assert not torch.allclose(r.params["mesh_grid"], before.params["mesh_grid"])


def _bilinear_brute_force(grid: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Textbook bilinear interpolation of a (C,R,R) grid whose corner cells sit at -1 and 1; x runs along the last axis."""
    C, R = grid.shape[0], grid.shape[-1]
    out = np.zeros((xy.shape[0], C))
    for n, (x, y) in enumerate(xy):
        fx, fy = (x + 1) / 2 * (R - 1), (y + 1) / 2 * (R - 1)
        i0, j0 = min(int(np.floor(fx)), R - 2), min(int(np.floor(fy)), R - 2)
        tx, ty = fx - i0, fy - j0
        out[n] = (grid[:, j0, i0] * (1 - tx) * (1 - ty) + grid[:, j0, i0 + 1] * tx * (1 - ty)
                  + grid[:, j0 + 1, i0] * (1 - tx) * ty + grid[:, j0 + 1, i0 + 1] * tx * ty)  # fmt: skip
    return out


def test_sample_grid_matches_brute_force_bilinear():
    rng = np.random.default_rng(0)
    grid = rng.normal(size=(3, 5, 5))
    xy = np.concatenate([rng.uniform(-1, 1, size=(40, 2)), [[-1.0, -1.0], [1.0, 1.0], [0.0, 0.5]]])
    got = sample_grid(torch.tensor(grid), torch.tensor(xy)).numpy()
    np.testing.assert_allclose(got, _bilinear_brute_force(grid, xy), atol=1e-12)
    corner = sample_grid(torch.tensor(grid), torch.tensor([[-1.0, 1.0]])).numpy()[0]
    np.testing.assert_allclose(corner, grid[:, -1, 0], atol=1e-12)  # x=-1 -> first column, y=1 -> last row
    grid3 = rng.normal(size=(2, 3, 3, 3))
    centre = sample_grid(torch.tensor(grid3), torch.zeros(1, 3, dtype=torch.float64)).numpy()[0]
    np.testing.assert_allclose(centre, grid3[:, 1, 1, 1], atol=1e-12)  # 3-D mesh space: the middle node


def test_mesh_grid_gradient_matches_finite_differences():
    """d loss / d grid feature through the opacity MLP and the rasteriser, against central differences."""
    mesh = grid_mesh(2, 1)
    cams = rig(1, 12)
    r = fitted(mesh, SmgsConfig(gaussians_per_face=2, iterations=0, backend="reference", normal_scale=1e-3, hidden=8, mesh_grid=3), cams, cls=SmgsRenderer)
    randomise(r)
    _randomise_mlp(r)
    grid = r.params["mesh_grid"] = r.params["mesh_grid"].double()  # float64, so differences of 1e-6 resolve
    target = torch.rand(1, 12, 12, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def loss() -> torch.Tensor:
        return ((r.render(torch.tensor(mesh[0]), cams) - target) ** 2).sum()

    grid.requires_grad_(True)
    (g,) = torch.autograd.grad(loss(), grid)
    fd = torch.zeros_like(grid)
    with torch.no_grad():
        for idx in np.ndindex(*grid.shape):
            old = grid[idx].item()
            grid[idx] = old + 1e-6
            up = loss().item()
            grid[idx] = old - 1e-6
            fd[idx] = (up - loss().item()) / 2e-6
            grid[idx] = old
    assert g.abs().max() > 1e-4
    np.testing.assert_allclose(g.numpy(), fd.numpy(), atol=1e-6, rtol=1e-4)


def test_mesh_grid_switch(mesh):
    """mesh_grid=0 drops the grid; 'world' and 'none' never build one."""
    cams = rig(1, 12)
    assert "mesh_grid" in fitted(mesh, SmgsConfig(iterations=0), cams, cls=SmgsRenderer).params
    assert "mesh_grid" not in fitted(mesh, SmgsConfig(iterations=0, mesh_grid=0), cams, cls=SmgsRenderer).params
    for inputs in ("world", "none"):
        assert "mesh_grid" not in fitted(mesh, SmgsConfig(iterations=0, inputs=inputs), cams, cls=SmgsRenderer).params


def test_bad_config_raises():
    with pytest.raises(ClodsError, match="inputs"):
        SmgsRenderer(SmgsConfig(inputs="time"))  # type: ignore[arg-type]
    with pytest.raises(ClodsError, match="hidden"):
        SmgsRenderer(SmgsConfig(hidden=0))
    with pytest.raises(ClodsError, match="mesh_grid"):
        SmgsRenderer(SmgsConfig(mesh_grid=1))
    with pytest.raises(ClodsError, match="grid_features"):
        SmgsRenderer(SmgsConfig(grid_features=0))


def _general_path(r: SmgsRenderer, verts: torch.Tensor) -> torch.Tensor:
    """Opacities through the full MLP (features, every layer), as while fitting: the frozen cache switched off by
    marking the first layer trainable for the call."""
    w0 = r.params["mlp_w0"]
    w0.requires_grad_(True)
    try:
        means = r.gaussians(verts)[0]
        return r.opacities(means, verts)
    finally:
        w0.requires_grad_(False)


@pytest.mark.parametrize("inputs,grid", [("both", 48), ("both", 0), ("mesh", 8), ("world", 8), ("none", 8)])
def test_frozen_mlp_cache_gives_the_full_mlps_opacities_and_gradients(mesh, inputs, grid):
    r = fitted(mesh, SmgsConfig(iterations=0, inputs=inputs, mesh_grid=grid, world_freqs=1), rig(1, 12), cls=SmgsRenderer)
    _randomise_mlp(r)
    x = torch.tensor(mesh[0], dtype=torch.float64, requires_grad=True)  # float64: only the summation order differs
    frozen = r.opacities(r.gaussians(x)[0], x)
    assert (getattr(r, "_frozen", None) is not None) == (inputs in ("both", "mesh"))  # only a mesh input is worth caching
    y = x.detach().clone().requires_grad_(True)
    full = _general_path(r, y)
    torch.testing.assert_close(frozen, full, atol=1e-12, rtol=1e-12)
    if inputs in ("mesh", "none"):
        assert not frozen.requires_grad  # no path from the vertices
        return
    weights = torch.linspace(-1.0, 1.0, frozen.numel(), dtype=torch.float64)
    (frozen * weights).sum().backward()
    (full * weights).sum().backward()
    torch.testing.assert_close(x.grad, y.grad, atol=1e-12, rtol=1e-10)
    assert float(x.grad.abs().max()) > 0  # the world position reaches the opacity


def test_frozen_mlp_cache_follows_changed_weights_and_is_not_pickled(mesh):
    import pickle

    r = fitted(mesh, SmgsConfig(iterations=0), rig(1, 12), cls=SmgsRenderer)
    x = torch.tensor(mesh[0], dtype=torch.float32)
    before = r.opacities(r.gaussians(x)[0], x)
    _randomise_mlp(r, seed=3)  # in place: the weights' versions move
    after = r.opacities(r.gaussians(x)[0], x)
    assert not torch.allclose(before, after)
    torch.testing.assert_close(after, _general_path(r, x).detach(), atol=1e-5, rtol=1e-5)  # float32 summation order
    assert "_frozen" in vars(r) and "_frozen" not in vars(pickle.loads(pickle.dumps(r)))
