"""The fast CPU backend against the plain-torch reference (and gsplat where CUDA is available)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import camera_rig
from clods_bench.splatting import render_gaussians
from clods_bench.splatting.gsplat_backend import gsplat_available
from tests.splatting.conftest import random_scene

TOL = 1e-5  # required agreement; float64 runs agree to ~1e-10


def _render_with_grads(scene: dict, cameras, backend: str, **kw) -> tuple[dict, dict]:
    """Render, backprop a fixed random weighting of rgb, alpha and depth; return outputs and input grads."""
    leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
    bg = torch.tensor([0.2, 0.5, 0.7], dtype=scene["means"].dtype, requires_grad=True)
    out = render_gaussians(leaves["means"], leaves["covars"], leaves["opacities"], leaves["colors"], cameras,
                           backend=backend, background=bg, **kw)  # fmt: skip
    g = torch.Generator().manual_seed(7)
    loss = sum((x * torch.rand(x.shape, generator=g, dtype=x.dtype)).sum() for x in (out.rgb, out.alpha, out.depth))
    loss.backward()
    grads = {k: v.grad for k, v in leaves.items()} | {"background": bg.grad}
    images = {"rgb": out.rgb.detach(), "alpha": out.alpha.detach(), "depth": out.depth.detach(), "radii": out.radii}
    return images, grads


@pytest.mark.parametrize("sh_degree", [None, 2])
def test_fast_backend_matches_reference(sh_degree: int | None) -> None:
    scene = random_scene(300, seed=3, sh_degree=sh_degree)
    scene["opacities"] = scene["opacities"].clamp(max=0.9) + 0.09  # opaque enough for early termination
    cameras = camera_rig(4, np.zeros(3), 3.5, 48, 40)
    ref_img, ref_grad = _render_with_grads(scene, cameras, "reference")
    fast_img, fast_grad = _render_with_grads(scene, cameras, "cpu")
    # empty pixels, and pixels where compositing stopped early (T_final in [1e-4, 1e-3))
    assert (ref_img["alpha"] == 0).any() and (ref_img["alpha"] > 0.999).any()
    for k in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(fast_img[k], ref_img[k], atol=TOL, rtol=0)
    assert torch.equal(fast_img["radii"], ref_img["radii"])
    for k, g in ref_grad.items():
        scale = max(1.0, float(g.abs().max()))
        torch.testing.assert_close(fast_grad[k], g, atol=TOL * scale, rtol=0, msg=f"gradient of {k}")
        assert float(g.abs().max()) > 0, k


def test_float32_backends_agree() -> None:
    scene = random_scene(200, seed=4, dtype=torch.float32)
    cameras = camera_rig(2, np.zeros(3), 2.5, 32, 32)
    ref_img, ref_grad = _render_with_grads(scene, cameras, "reference")
    fast_img, fast_grad = _render_with_grads(scene, cameras, "cpu")
    assert fast_img["rgb"].dtype == torch.float32 and fast_grad["means"].dtype == torch.float32
    for k in ("rgb", "alpha"):
        torch.testing.assert_close(fast_img[k], ref_img[k], atol=1e-5, rtol=0)
    for k, g in ref_grad.items():
        torch.testing.assert_close(fast_grad[k], g, atol=1e-4 * max(1.0, float(g.abs().max())), rtol=0)


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_tile_size_does_not_change_the_image(backend: str) -> None:
    scene = random_scene(120, seed=5)
    cameras = camera_rig(2, np.zeros(3), 2.5, 37, 29)
    a, ga = _render_with_grads(scene, cameras, backend, tile=16)
    b, gb = _render_with_grads(scene, cameras, backend, tile=7)
    for k in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(a[k], b[k], atol=1e-12, rtol=0)
    for k in ga:
        torch.testing.assert_close(ga[k], gb[k], atol=1e-9, rtol=1e-9)
    if backend == "cpu":  # the auto tile (64 px here: one tile per view) and the largest size it picks
        c, gc = _render_with_grads(scene, cameras, backend)
        d, gd = _render_with_grads(scene, cameras, backend, tile=64)
        for k in ("rgb", "alpha", "depth"):
            torch.testing.assert_close(c[k], a[k], atol=1e-12, rtol=0)
            torch.testing.assert_close(d[k], a[k], atol=1e-12, rtol=0)
        for k in ga:
            torch.testing.assert_close(gc[k], ga[k], atol=1e-9, rtol=1e-9)
            torch.testing.assert_close(gd[k], ga[k], atol=1e-9, rtol=1e-9)


def test_auto_tile_cuts_the_rig_into_enough_tiles() -> None:
    from clods_bench.splatting.fast_cpu import auto_tile

    assert auto_tile(8, 128, 128) == 64  # bench render: 32 tiles of 64 px
    assert auto_tile(4, 64, 64) == 32  # ci: 16 tiles of 32 px (64 px would leave 4)
    assert auto_tile(2, 37, 29) == 16  # fewer than 16 tiles at any size: the smallest
    assert auto_tile(30, 800, 800) == 64


def test_forward_without_gradients_renders_the_same_image() -> None:
    """Under no_grad the forward keeps no exponentials for a backward; the image must not change."""
    scene = random_scene(150, seed=9)
    cameras = camera_rig(3, np.zeros(3), 2.5, 40, 32)
    a, _ = _render_with_grads(scene, cameras, "cpu")
    with torch.no_grad():
        out = render_gaussians(scene["means"], scene["covars"], scene["opacities"], scene["colors"], cameras,
                               backend="cpu", background=torch.tensor([0.2, 0.5, 0.7], dtype=torch.float64))  # fmt: skip
    for k in ("rgb", "alpha", "depth"):
        assert torch.equal(getattr(out, k), a[k]), k


def test_kept_visits_fit_the_bound_cover_every_live_pixel_and_match_math_exp() -> None:
    """The visits the forward keeps for the backward: inside their tile's share of the buffer (numba does not check
    bounds), exp(-sigma) of their pixel to a few ulp, on the Gaussian's row ranges, and present for every pixel the
    Gaussian contributes to (brute force over each Gaussian's pixel box)."""
    import math

    from clods_bench.splatting import fast_kernels as K

    kept = {}
    orig = K.raster_fwd

    def spy(*args):
        orig(*args)
        kept["args"] = args

    scene = random_scene(200, seed=11)
    scene["opacities"] = scene["opacities"].clamp(max=0.9) + 0.09  # saturated pixels, whose later visits are not kept
    cameras = camera_rig(2, np.zeros(3), 2.5, 48, 40)
    K.raster_fwd = spy
    try:
        _render_with_grads(scene, cameras, "cpu", tile=16)
    finally:
        K.raster_fwd = orig
    means2d, conics, _, opac, _, radii, thresh, offsets, ids, W, H, tile, tiles_x, tiles_y = kept["args"][:14]
    n_last = kept["args"][18]
    vis_buf, vis_ij, vis_span, tile_buf = kept["args"][-4:]
    per_cam = tiles_x * tiles_y
    n_live = 0
    for t in range(len(offsets) - 1):
        cam, x0, y0, x1, y1 = K.tile_rect(t, per_cam, tiles_x, tile, W, H)
        kmax = int(n_last[cam, y0:y1, x0:x1].max())
        ends = [tile_buf[t]]
        for k in range(offsets[t], offsets[t] + kmax):
            lo, hi = vis_span[k]
            assert lo == ends[-1] and hi >= lo, (t, k)  # contiguous, in Gaussian order
            ends.append(hi)
            g = ids[k]
            (mx, my), (a, b, c), o = means2d[cam, g], conics[cam, g], opac[cam, g]
            visits = {(int(i) + x0, int(j) + y0): vis_buf[e] for e, (i, j) in zip(range(lo, hi), vis_ij[lo:hi])}
            i0, i1 = K._pixel_box(mx, radii[cam, g, 0], x0, x1)
            j0, j1 = K._pixel_box(my, radii[cam, g, 1], y0, y1)
            ell = K._ellipse(a, b, c, thresh[cam, g])
            chords = {(i, j) for j in range(j0, j1 + 1) for i in range(K._row_range(mx, my, ell, j, i0, i1)[0], K._row_range(mx, my, ell, j, i0, i1)[1] + 1)}
            assert set(visits) <= chords, (t, k)
            for (i, j), vis in visits.items():
                dx, dy = i + 0.5 - mx, j + 0.5 - my
                expect = math.exp(-(0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy))
                assert abs(vis - expect) <= 4 * np.spacing(expect), (t, k, i, j)
            for i, j in chords:  # a pixel this Gaussian contributes to must have its visit kept
                dx, dy = i + 0.5 - mx, j + 0.5 - my
                live = k - offsets[t] < n_last[cam, j, i] and o * math.exp(-(0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy)) >= K.ALPHA_MIN
                if live:
                    assert (i, j) in visits, (t, k, i, j)
                    n_live += 1
        assert ends[-1] <= tile_buf[t + 1], t
    assert n_live > 1000


def test_backward_without_kept_visits_gives_the_same_gradients(monkeypatch) -> None:
    """Over the memory budget the forward keeps nothing and the backward recomputes: bit-identical gradients."""
    from clods_bench.splatting import fast_cpu

    scene = random_scene(200, seed=12)
    cameras = camera_rig(3, np.zeros(3), 2.5, 40, 36)
    img, grads = _render_with_grads(scene, cameras, "cpu")
    monkeypatch.setattr(fast_cpu, "KEEP_BYTES", 0)
    img0, grads0 = _render_with_grads(scene, cameras, "cpu")
    for k in img:
        assert torch.equal(img[k], img0[k]), k
    for k in grads:
        assert torch.equal(grads[k], grads0[k]), k


def test_exp_neg_is_within_a_few_ulp_of_numpy() -> None:
    from numba import njit

    from clods_bench.splatting.fast_kernels import exp_neg

    @njit
    def many(x):
        out = np.empty_like(x)
        for i in range(x.size):
            out[i] = exp_neg(x[i])
        return out

    x = np.concatenate([np.random.default_rng(0).uniform(0.0, 8.0, 200_000), np.linspace(0.0, 60.0, 6001), [0.0, 1e-300]])
    expect = np.exp(-x)
    assert np.all(np.abs(many(x) - expect) <= 4 * np.spacing(expect))


def _gsplat_scene(kind: str) -> tuple[dict, list]:
    """Volumetric random Gaussians, or the flat cloth Gaussians of `bench render` (where a float32 projection fails)."""
    if kind == "random":
        return random_scene(300, seed=6, dtype=torch.float32), camera_rig(3, np.zeros(3), 2.5, 64, 48)
    from clods_bench.splatting.flag_scene import bench_scene

    return bench_scene(0, 96, 3)


@pytest.mark.parametrize("kind", ["random", "flat cloth"])
def test_gsplat_backend_matches_the_reference_and_the_cpu(kind: str) -> None:
    """gsplat composites the float32 screen-space Gaussians of our torch projection, as the torch reference does:
    images to 1e-4 and gradients to 1e-3 of their largest. The CPU kernels composite float64 screen-space values,
    which moves a Gaussian across the 1/255 alpha cut at a few pixels: there, at most 2/255, elsewhere 1e-4."""
    ok, why = gsplat_available()
    if not ok:
        pytest.skip(f"gsplat backend needs gsplat and a CUDA GPU: {why}")
    scene, cameras = _gsplat_scene(kind)
    ref_img, ref_grad = _render_with_grads(scene, cameras, "reference")
    gs_img, gs_grad = _render_with_grads(scene, cameras, "gsplat")
    assert torch.equal(gs_img["radii"].cpu(), ref_img["radii"])  # one projection for both
    for k in ("rgb", "alpha"):
        torch.testing.assert_close(gs_img[k].cpu(), ref_img[k], atol=1e-4, rtol=0)
    covered = ref_img["alpha"] > 0.5
    torch.testing.assert_close(gs_img["depth"].cpu()[covered], ref_img["depth"][covered], atol=1e-4, rtol=1e-4)
    for k, g in ref_grad.items():
        torch.testing.assert_close(gs_grad[k].cpu(), g, atol=1e-3 * float(g.abs().max()), rtol=0, msg=f"gradient of {k}")
    cpu_img, _ = _render_with_grads(scene, cameras, "cpu")
    for k in ("rgb", "alpha"):
        diff = (gs_img[k].cpu() - cpu_img[k]).abs()
        assert float(diff.max()) <= 2.0 / 255.0 and float((diff > 1e-4).float().mean()) <= 1e-3, k


def test_fast_backend_matches_reference_flat_dense_and_empty_tiles() -> None:
    # flat Gaussians nearly edge-on (thin slanted ellipses: the kernels' per-row chords), 150 of them crowded
    # into one tile, and tiles with nothing in them
    from tests.splatting.conftest import head_on_camera
    from tests.splatting.test_fast_projection import _flat_edge_on_scene

    scene = _flat_edge_on_scene(250, seed=21)
    scene["means"][:150, :2] = scene["means"][:150, :2] * 0.03 - torch.tensor([0.25, 0.2], dtype=torch.float64)
    cameras = [head_on_camera(80, 64, 90.0)]
    ref_img, ref_grad = _render_with_grads(scene, cameras, "reference")
    fast_img, fast_grad = _render_with_grads(scene, cameras, "cpu")
    assert (ref_img["alpha"][0, 48:, 64:] == 0).all() and float(ref_img["alpha"].max()) > 0.99
    for k in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(fast_img[k], ref_img[k], atol=TOL, rtol=0)
    for k, g in ref_grad.items():
        torch.testing.assert_close(fast_grad[k], g, atol=TOL * max(1.0, float(g.abs().max())), rtol=0, msg=f"gradient of {k}")


def test_order_keys_rank_float64_depths_exactly() -> None:
    """gsplat gets ranks as sort keys: their float32 order is the stable order of the float64 depths, where the
    float32 depths themselves would tie."""
    from clods_bench.splatting.gsplat_backend import order_keys

    d = torch.tensor([[2.6000000015, 2.6000000089, 1.0, 2.6000000015]], dtype=torch.float64)
    assert d[0, 0].float() == d[0, 1].float()  # a float32 tie
    keys = order_keys(d)
    assert keys.dtype == torch.float32 and keys.tolist() == [[2.0, 4.0, 1.0, 3.0]]
    assert torch.equal(torch.argsort(keys, stable=True), torch.argsort(d, stable=True))


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_gaussians_closer_than_a_float32_step_composite_in_float64_order(backend: str) -> None:
    """Two overlapping Gaussians (float32 inputs) whose camera depths differ by less than one float32 step: the
    nearer one, listed second, is composited first (a float32 depth sort would tie them and keep index order)."""
    from clods_bench.datasets.cameras import Camera

    near = np.float32(0.1)
    far = np.nextafter(near, np.float32(1.0))
    means = torch.tensor([[0.0, 0.0, far], [0.0, 0.0, near]], dtype=torch.float32)  # red behind, blue in front
    cam = Camera(np.array([[40.0, 0, 8], [0, 40.0, 8], [0, 0, 1]]), np.eye(3), np.array([0.0, 0.0, 2.5]), 16, 16)
    z = means[:, 2].double() + 2.5
    assert z[0] > z[1] and z[0].float() == z[1].float()
    covars = torch.diag(torch.tensor([0.01, 0.01, 0.01])).expand(2, 3, 3).contiguous() ** 2
    colors = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    out = render_gaussians(means, covars, torch.tensor([0.6, 0.6]), colors, [cam], backend=backend,
                           background=torch.zeros(3))  # fmt: skip
    centre = out.rgb[0, 7:9, 7:9]
    alpha = 1.0 - torch.sqrt(1.0 - out.alpha[0, 7:9, 7:9, 0])  # each one's alpha there (equal): A = 1 - (1 - a)^2
    assert float(alpha.min()) > 0.2
    torch.testing.assert_close(centre[..., 2], alpha, atol=1e-6, rtol=0)  # front: a
    torch.testing.assert_close(centre[..., 0], alpha * (1 - alpha), atol=1e-6, rtol=0)  # behind: a (1 - a)
