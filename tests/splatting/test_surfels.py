"""2DGS surfel renderer: analytic single-surfel cases, ray-splat intersection, CPU backend vs torch reference,
gradients vs finite differences, occlusion and median depth, regularisers, input errors, a fit of a flat square."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.errors import ClodsError
from clods_bench.splatting import surfel_kernels as SK
from clods_bench.splatting.surfel_losses import depth_normals, surfel_losses
from clods_bench.splatting.surfels import intersect_reference, project_surfels, render_surfels

F64 = torch.float64
OUTPUTS = ("rgb", "alpha", "depth_median", "depth_expected", "normal", "distortion")
EDGE_ON = (math.sqrt(0.5), 0.0, -math.sqrt(0.5), 0.0)  # rotation about y by -90 deg: normal along -x


def _camera(size: int = 21, f: float = 100.0) -> Camera:
    """Camera at the origin looking down +z; odd size so pixel (size//2, size//2) is centred on the axis."""
    K = np.array([[f, 0.0, size / 2.0], [0.0, f, size / 2.0], [0.0, 0.0, 1.0]])
    return Camera(K, np.eye(3), np.zeros(3), size, size)


def _surfels(means, quats, scales, opac, colors) -> tuple[torch.Tensor, ...]:
    return tuple(torch.tensor(x, dtype=F64) for x in (means, quats, scales, opac, colors))


def _random_scene(G: int, seed: int, spread: float = 1.0) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    return (
        (torch.rand(G, 3, generator=g, dtype=F64) - 0.5) * spread,
        torch.randn(G, 4, generator=g, dtype=F64),
        torch.rand(G, 2, generator=g, dtype=F64) * 0.1 + 0.03,
        torch.rand(G, generator=g, dtype=F64) * 0.9 + 0.05,
        torch.rand(G, 3, generator=g, dtype=F64),
    )


def test_facing_surfel_alpha_depth_normal() -> None:
    cam = _camera()
    s = _surfels([[0.0, 0.0, 2.0]], [[1.0, 0.0, 0.0, 0.0]], [[0.05, 0.08]], [0.7], [[0.2, 0.4, 0.6]])
    out = render_surfels(*s, [cam], backend="cpu")
    c = 10  # centre pixel: the ray hits the surfel centre, u = v = 0
    assert float(out.alpha[0, c, c, 0]) == pytest.approx(0.7, abs=1e-12)
    assert float(out.depth_median[0, c, c, 0]) == pytest.approx(2.0, abs=1e-12)
    assert float(out.depth_expected[0, c, c, 0]) == pytest.approx(2.0, abs=1e-12)
    np.testing.assert_allclose(out.normal[0, c, c].numpy(), [0.0, 0.0, -0.7], atol=1e-12)  # faces the camera
    np.testing.assert_allclose(out.rgb[0, c, c].numpy(), 0.7 * np.array([0.2, 0.4, 0.6]) + 0.3, atol=1e-12)
    # three pixels right: the ray meets the plane z = 2 at x = 3 * 2 / 100 = 0.06, u = 0.06 / 0.05 = 1.2
    assert float(out.alpha[0, c, c + 3, 0]) == pytest.approx(0.7 * math.exp(-0.5 * 1.2**2), abs=1e-12)
    assert float(out.depth_median[0, c, c + 3, 0]) == 0.0  # alpha <= 0.5: no median depth
    assert float(out.depth_expected[0, c, c + 3, 0]) == pytest.approx(2.0, abs=1e-12)
    assert float(out.distortion.abs().max()) < 1e-15  # one surfel per ray
    # the elongated v axis (s_v = 0.08) reaches further down than u does sideways
    assert float(out.alpha[0, c + 4, c, 0]) > float(out.alpha[0, c, c + 4, 0]) > 0
    ref = render_surfels(*s, [cam], backend="reference")
    for k in OUTPUTS:
        torch.testing.assert_close(getattr(out, k), getattr(ref, k), atol=1e-12, rtol=0)


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_edge_on_surfel_is_the_low_pass_footprint(backend: str) -> None:
    cam = _camera()
    leaves = [x.requires_grad_(True) for x in _surfels([[0.0, 0.0, 2.0]], [EDGE_ON], [[0.1, 0.1]], [0.8], [[1.0, 0.0, 0.0]])]
    out = render_surfels(*leaves, [cam], backend=backend)
    for k in OUTPUTS:
        assert bool(torch.isfinite(getattr(out, k)).all()), k
    a = out.alpha[0, :, :, 0].detach()
    c = 10
    # the plane x = 0 contains the camera: no ray hits it in front of the camera, only the low-pass filter
    # exp(-|d|^2) (sigma = sqrt(2)/2 px) around the projected centre draws it, cut at 3 sigma (|d| <= 2.12 px)
    assert float(a[c, c]) == pytest.approx(0.8, abs=1e-12)
    assert float(a[c, c + 1]) == pytest.approx(0.8 * math.exp(-1.0), abs=1e-12)
    assert float(a[c + 1, c + 1]) == pytest.approx(0.8 * math.exp(-2.0), abs=1e-12)
    assert float(a[c + 2, c]) == pytest.approx(0.8 * math.exp(-4.0), abs=1e-12)
    assert float(a[c + 3, c]) == 0.0 and float(a[c + 2, c + 2]) == 0.0
    assert int((a > 0).sum()) == 13
    assert float(out.depth_median.detach()[0, c, c, 0]) == pytest.approx(2.0, abs=1e-12)  # low-pass branch: centre depth
    loss = sum(getattr(out, k).sum() for k in OUTPUTS)
    loss.backward()
    for x in leaves:
        assert bool(torch.isfinite(x.grad).all())


def _ray_plane_numpy(cam: Camera, mean, quat, scale, rows, cols) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Brute force: solve o + lam d = p + u s_u t_u + v s_v t_v per pixel; (u, v, camera z of the hit)."""
    w, x, y, z = np.asarray(quat, float) / np.linalg.norm(quat)
    rot = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    o = cam.center
    us, vs, zs = [], [], []
    for r, c in zip(rows, cols):
        d = cam.R.T @ np.linalg.solve(cam.K, np.array([c + 0.5, r + 0.5, 1.0]))
        A = np.stack([scale[0] * rot[:, 0], scale[1] * rot[:, 1], -d], axis=1)
        u, v, lam = np.linalg.solve(A, o - np.asarray(mean, float))
        us.append(u)
        vs.append(v)
        zs.append((cam.R @ (o + lam * d) + cam.t)[2])
    return np.array(us), np.array(vs), np.array(zs)


def test_tilted_surfel_intersection_matches_brute_force() -> None:
    cam = camera_rig(1, np.zeros(3), 2.5, 24, 20, phase_deg=30)[0]
    mean, quat, scale = [0.05, -0.1, 0.08], [0.8, 0.3, -0.4, 0.5], [0.3, 0.2]
    s = _surfels([mean], [quat], [scale], [0.9], [[0.5, 0.5, 0.5]])
    proj = project_surfels(s[0], s[1], s[2], s[3], [cam], near=0.01)
    rows, cols = np.meshgrid(np.arange(20), np.arange(24), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    pix = torch.tensor(np.stack([cols + 0.5, rows + 0.5], 1), dtype=F64)
    u, v, z, ok = intersect_reference(pix, proj.M[0], near=0.01)
    bu, bv, bz = _ray_plane_numpy(cam, mean, quat, scale, rows, cols)
    assert bool(ok.all())
    np.testing.assert_allclose(u[:, 0].numpy(), bu, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(v[:, 0].numpy(), bv, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(z[:, 0].numpy(), bz, rtol=1e-9, atol=1e-9)
    Mg = proj.M[0, 0].detach().numpy().reshape(9)
    m2 = proj.means2d[0, 0].detach().numpy()
    for k in range(0, len(rows), 37):  # the numba kernels' own intersection
        _, _, _, use3, ku, kv, kz = SK._eval(cols[k] + 0.5, rows[k] + 0.5, Mg, m2[0], m2[1], 2.5, 0.9, 0.01)
        if use3:
            assert (ku, kv, kz) == pytest.approx((bu[k], bv[k], bz[k]), rel=1e-9, abs=1e-9)
    # the rendered depth follows the tilted plane, not the centre's depth
    out = render_surfels(*s, [cam])
    hit = (out.alpha[0, ..., 0] > 0.5).numpy().ravel() & (u[:, 0] ** 2 + v[:, 0] ** 2 < 1).numpy()
    assert hit.sum() > 10
    np.testing.assert_allclose(out.depth_median[0, ..., 0].numpy().ravel()[hit], bz[hit], rtol=1e-9)
    assert np.ptp(bz[hit]) > 0.05


def _render_with_grads(scene, cameras, backend: str, seed: int = 7):
    leaves = [x.clone().requires_grad_(True) for x in scene]
    bg = torch.tensor([0.2, 0.5, 0.7], dtype=F64, requires_grad=True)
    out = render_surfels(*leaves, cameras, background=bg, backend=backend)
    g = torch.Generator().manual_seed(seed)
    loss = sum((getattr(out, k) * torch.rand(getattr(out, k).shape, generator=g, dtype=F64)).sum() for k in OUTPUTS)
    loss.backward()
    return out, [x.grad for x in leaves] + [bg.grad]


def test_cpu_backend_matches_reference() -> None:
    scene = _random_scene(50, seed=3)
    cameras = camera_rig(2, np.zeros(3), 3.0, 24, 20)
    ref, ref_g = _render_with_grads(scene, cameras, "reference")
    cpu, cpu_g = _render_with_grads(scene, cameras, "cpu")
    assert float((ref.alpha > 0.5).float().mean()) > 0.1 and float((ref.alpha == 0).float().mean()) > 0.1
    assert float(ref.distortion.detach().max()) > 1e-4
    for k in OUTPUTS:
        torch.testing.assert_close(getattr(cpu, k).detach(), getattr(ref, k).detach(), atol=1e-6, rtol=0, msg=k)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors", "background"), cpu_g, ref_g):
        scale = float(b.abs().max())
        assert scale > 0, name
        torch.testing.assert_close(a, b, atol=1e-6 * scale, rtol=0, msg=f"gradient of {name}")


def test_float32_input_gives_float32_output() -> None:
    scene = tuple(x.float() for x in _random_scene(20, seed=4))
    out = render_surfels(*scene, camera_rig(1, np.zeros(3), 3.0, 16, 16))
    assert all(getattr(out, k).dtype == torch.float32 for k in OUTPUTS)


def _tiny_scene() -> tuple[torch.Tensor, ...]:
    """6 overlapping surfels (opacities below the 0.99 clamp) seen by 2 small cameras."""
    g = torch.Generator().manual_seed(11)
    return (
        (torch.rand(6, 3, generator=g, dtype=F64) - 0.5) * 0.25,
        torch.randn(6, 4, generator=g, dtype=F64),
        torch.rand(6, 2, generator=g, dtype=F64) * 0.08 + 0.1,
        torch.rand(6, generator=g, dtype=F64) * 0.3 + 0.6,
        torch.rand(6, 3, generator=g, dtype=F64),
    )


@pytest.mark.parametrize("backend", ["reference", "cpu"])
@pytest.mark.parametrize("key", [*OUTPUTS, "losses"])
def test_gradients_match_finite_differences(backend: str, key: str) -> None:
    cameras = camera_rig(2, np.zeros(3), 2.0, 12, 10)
    scene = _tiny_scene()
    out = render_surfels(*scene, cameras)
    assert float((out.alpha > 0.5).float().mean()) > 0.2 and float(out.distortion.max()) > 1e-4

    def fn(*xs):
        o = render_surfels(*xs, cameras, backend=backend)
        if key == "losses":
            reg = surfel_losses(o, cameras)
            return reg["normal"] + 10.0 * reg["distortion"]
        x = getattr(o, key)
        return (x * torch.rand(x.shape, generator=torch.Generator().manual_seed(3), dtype=F64)).sum()

    inputs = tuple(x.clone().requires_grad_(True) for x in scene)
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_near_surfel_occludes_and_median_depth_picks_the_crossing(backend: str) -> None:
    cam = _camera()
    c = 10

    def centre(op_near: float, op_far: float):
        # far surfel listed first: the order comes from the depth sort
        s = _surfels([[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]], [[1, 0, 0, 0]] * 2, [[0.1, 0.1]] * 2, [op_far, op_near],
                     [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # fmt: skip
        out = render_surfels(*s, [cam], backend=backend, background=(0.0, 0.0, 0.0))
        return out.rgb[0, c, c].numpy(), float(out.depth_median[0, c, c, 0]), float(out.depth_expected[0, c, c, 0])

    rgb, med, exp = centre(0.8, 0.8)
    np.testing.assert_allclose(rgb, [0.8, 0.0, 0.2 * 0.8], atol=1e-12)  # red in front of blue
    assert med == pytest.approx(2.0) and exp == pytest.approx((0.8 * 2 + 0.16 * 3) / 0.96)
    _, med, _ = centre(0.3, 0.6)  # T: 1 -> 0.7 -> 0.28, crosses 0.5 at the far surfel
    assert med == pytest.approx(3.0)
    _, med, _ = centre(0.5, 0.6)  # T = 0.5 after the near one is not below 0.5
    assert med == pytest.approx(3.0)
    _, med, _ = centre(0.2, 0.3)  # T ends at 0.56: no median depth
    assert med == 0.0


def _plane(quat):
    return _surfels([[0.0, 0.0, 2.0]], [quat], [[0.5, 0.5]], [0.99], [[0.5, 0.5, 0.5]])


@pytest.mark.parametrize("quat", [[1.0, 0.0, 0.0, 0.0], [0.9, 0.3, 0.2, 0.1]])
def test_normal_consistency_of_a_plane(quat) -> None:
    cam = _camera(15, 40.0)
    out = render_surfels(*_plane(quat), [cam])
    _, valid = depth_normals(out.depth_median, [cam])
    assert int(valid.sum()) > 30
    reg = surfel_losses(out, [cam])
    # the median depth follows the (tilted) plane, so its normal is the surfel's: n . N = alpha
    expected = float((1.0 - out.alpha[..., 0])[valid].mean())
    assert float(reg["normal"]) == pytest.approx(expected, abs=1e-9)
    assert float(reg["distortion"]) == 0.0
    # rendered normals disagreeing with the depth map are penalised
    other = render_surfels(*_plane([1.0, 0.0, 0.0, 0.0] if quat[0] != 1.0 else [0.9, 0.3, 0.2, 0.1]), [cam])
    bent = surfel_losses(dataclasses.replace(out, normal=other.normal), [cam])
    assert float(bent["normal"]) > float(reg["normal"]) + 0.05


def test_non_unit_quaternions_are_normalised() -> None:
    cameras = camera_rig(2, np.zeros(3), 3.0, 16, 16)
    scene = _random_scene(10, seed=5)
    a = render_surfels(*scene, cameras)
    b = render_surfels(scene[0], scene[1] * 3.7, *scene[2:], cameras)
    for k in OUTPUTS:
        torch.testing.assert_close(getattr(a, k), getattr(b, k), atol=1e-12, rtol=0)


@pytest.mark.parametrize(
    "change, where",
    [
        (lambda s: (s[0][:, :2], *s[1:]), "means"),
        (lambda s: (s[0], s[1][:, :3], *s[2:]), "quats"),
        (lambda s: (*s[:2], s[2].repeat(1, 2)[:, :3], *s[3:]), "scales"),
        (lambda s: (*s[:3], s[3][:-1], s[4]), "opacities"),
        (lambda s: (*s[:4], s[4][:, :2]), "colors"),
        (lambda s: (s[0].index_fill(0, torch.tensor([2]), math.nan), *s[1:]), "means[2]"),
        (lambda s: (s[0], s[1].index_fill(0, torch.tensor([1]), 0.0), *s[2:]), "quats[1]"),
        (lambda s: (*s[:2], s[2].index_fill(0, torch.tensor([3]), -0.1), *s[3:]), "scales[3]"),
        (lambda s: (*s[:3], s[3].index_fill(0, torch.tensor([0]), 1.5), s[4]), "opacities[0]"),
        (lambda s: (*s[:4], s[4].index_fill(0, torch.tensor([4]), math.inf)), "colors[4]"),
    ],
)
def test_bad_input_names_the_argument(change, where: str) -> None:
    scene = change(_random_scene(5, seed=6))
    with pytest.raises(ClodsError) as e:
        render_surfels(*scene, camera_rig(1, np.zeros(3), 3.0, 8, 8))
    assert e.value.where == where


def test_bad_options_name_the_argument() -> None:
    scene = _random_scene(3, seed=6)
    cams = camera_rig(1, np.zeros(3), 3.0, 8, 8)
    for kw, where in (({"backend": "vulkan"}, "backend"), ({"near": 0.0}, "near"), ({"background": (1.0, 0.0)}, "background")):
        with pytest.raises(ClodsError) as e:
            render_surfels(*scene, cams, **kw)
        assert e.value.where == where
    with pytest.raises(ClodsError) as e:
        render_surfels(*scene, [])
    assert e.value.where == "cameras"


# ---------------------------------------------------------------------------------------------------------
# fitting frame 0


def _square_views(size: int = 32):
    """A flat textured unit square in the plane y = 0, seen by 4 rig cameras at 45 deg to it (two from behind)."""
    from clods_bench.datasets.rasterizer import render_depth, render_views
    from clods_bench.datasets.textures import procedural_texture

    verts = np.array([[-0.5, 0.0, -0.5], [0.5, 0.0, -0.5], [0.5, 0.0, 0.5], [-0.5, 0.0, 0.5]])
    cells = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    cameras = camera_rig(4, np.zeros(3), 2.2, size, size, phase_deg=45.0)
    images = torch.from_numpy(render_views(verts, cells, uv, procedural_texture(64, seed=1), cameras)).to(F64)
    depth = np.stack([render_depth(verts, cells, c) for c in cameras])
    return images, cameras, depth


def _box_points(n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(n, 3, generator=g, dtype=F64) - 0.5) * torch.tensor([1.2, 0.3, 1.2], dtype=F64)


def test_fit_smoke() -> None:
    from clods_bench.splatting.surfel_fit import fit_surfels, surfel_depth_maps

    images, cameras, _ = _square_views(16)
    params, hist = fit_surfels(images, cameras, _box_points(60), None, 12, regularize_from=0.5)
    assert hist["l1"][-1] < 0.8 * hist["l1"][0] and len(hist["loss"]) == 12
    assert set(params) == {"means", "quats", "scales", "opacities", "colors"}
    torch.testing.assert_close(params["quats"].norm(dim=-1), torch.ones(len(params["quats"]), dtype=F64))
    depth, alpha = surfel_depth_maps(params, cameras)
    assert depth.shape == alpha.shape == (4, 16, 16)
    assert bool(((depth > 0) == (alpha > 0.5)).all())
    with pytest.raises(ClodsError) as e:
        fit_surfels(images[..., :2], cameras, _box_points(5), None, 1)
    assert e.value.where == "images"
    with pytest.raises(ClodsError) as e:
        fit_surfels(images, cameras, _box_points(5)[:, :2], None, 1)
    assert e.value.where == "init_points"


@pytest.mark.slow
def test_fit_flat_square_recovers_its_depth() -> None:
    from clods_bench.splatting.surfel_fit import fit_surfels, surfel_depth_maps

    images, cameras, gt = _square_views(32)
    params, hist = fit_surfels(images, cameras, _box_points(300), None, 150, seed=0)
    assert hist["l1"][-1] < 0.25 * hist["l1"][0]
    depth, alpha = surfel_depth_maps(params, cameras)
    depth, alpha = depth.numpy(), alpha.numpy()
    square = np.isfinite(gt)
    covered = (alpha > 0.5) & square
    assert covered.sum() > 0.9 * square.sum()  # the square is opaque where it should be ...
    assert ((alpha > 0.5) & ~square).sum() < 0.05 * square.sum()  # ... and little else is
    err = np.abs(depth - gt)[covered]
    assert np.median(err) < 0.01 and np.percentile(err, 90) < 0.03  # square size 1: 1 % and 3 %
