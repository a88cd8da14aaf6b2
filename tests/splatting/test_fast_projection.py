"""The numba projection (values and hand-written backward) against torch autograd of `project_gaussians`,
and float32 renders against float64 renders of the same Gaussians (flat, edge-on, near-tied depths)."""

from __future__ import annotations

import numpy as np
import torch

from clods_bench.datasets.cameras import camera_rig
from clods_bench.splatting import camera_tensors, project_gaussians, render_gaussians, tile_bounds
from clods_bench.splatting.fast_cpu import CameraArrays
from clods_bench.splatting.projection import EPS2D
from tests.splatting.conftest import head_on_camera, random_scene


def _flat_edge_on_scene(G: int, seed: int) -> dict:
    """G flat Gaussians (zero thickness) whose planes contain the viewing direction of a head-on camera, give or take 1e-4 rad."""
    g = torch.Generator().manual_seed(seed)
    means = torch.stack([(torch.rand(G, generator=g) - 0.5) * 0.6, (torch.rand(G, generator=g) - 0.5) * 0.4,
                         2.0 + torch.rand(G, generator=g)], dim=1).double()  # fmt: skip
    angle = torch.rand(G, generator=g).double() * np.pi
    tilt = (torch.rand(G, generator=g).double() - 0.5) * 2e-4
    e1 = torch.stack([torch.cos(angle), torch.sin(angle), torch.zeros(G, dtype=torch.float64)], 1) * 0.05
    e2 = torch.stack([torch.sin(tilt) * torch.sin(angle), -torch.sin(tilt) * torch.cos(angle), torch.cos(tilt)], 1) * 0.2
    covars = e1[:, :, None] * e1[:, None, :] + e2[:, :, None] * e2[:, None, :]
    return {"means": means, "covars": covars, "opacities": torch.rand(G, generator=g).double() * 0.5 + 0.45,
            "colors": torch.rand(G, 3, generator=g).double()}  # fmt: skip


def _numba_projection(scene: dict, cameras, tile: int = 16):
    """project_fwd outputs for `scene` (float64)."""
    from clods_bench.splatting import projection_kernels as PK

    Ks, Rs, ts, _ = camera_tensors(cameras)
    W, H = cameras[0].width, cameras[0].height
    cams = CameraArrays.from_tensors(Ks, Rs, ts, W, H)
    C, G = len(cameras), scene["means"].shape[0]
    o = np.ascontiguousarray(np.broadcast_to(scene["opacities"].numpy(), (C, G)))
    out = (np.empty((C, G, 2)), np.empty((C, G)), np.empty((C, G, 3)), np.empty((C, G, 2), np.int32), np.empty((C, G, 4), np.int32), np.empty((C, G)))
    PK.project_fwd(scene["means"].numpy(), scene["covars"].numpy(), o, cams.cams, cams.ts, cams.lims, W, H, 0.01, EPS2D, tile, *out)
    return cams, out


def _check_projection(scene: dict, cameras) -> None:
    from clods_bench.splatting import projection_kernels as PK

    Ks, Rs, ts, _ = camera_tensors(cameras)
    W, H = cameras[0].width, cameras[0].height
    m, S = scene["means"].clone().requires_grad_(True), scene["covars"].clone().requires_grad_(True)
    proj = project_gaussians(m, S, scene["opacities"], Ks, Rs, ts, W, H)
    cams, (means2d, depths, conics, radii, bounds, _) = _numba_projection(scene, cameras)
    valid = proj.valid.numpy()
    assert valid.any() and (~valid).any()
    np.testing.assert_array_equal(radii, proj.radii.numpy())
    np.testing.assert_array_equal(bounds, tile_bounds(proj.means2d, proj.radii, W, H, 16).numpy())
    np.testing.assert_allclose(means2d[valid], proj.means2d.detach().numpy()[valid], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(depths, proj.depths.detach().numpy(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(conics[valid], proj.conics.detach().numpy()[valid], rtol=1e-8, atol=1e-10)
    g = torch.Generator().manual_seed(2)
    mask = proj.valid.double()
    v2, vc, vd = (torch.randn(x.shape, generator=g, dtype=torch.float64) for x in (proj.means2d, proj.conics, proj.depths))
    v2, vc, vd = v2 * mask[..., None], vc * mask[..., None], vd * mask
    ((proj.means2d * v2).sum() + (proj.conics * vc).sum() + (proj.depths * vd).sum()).backward()
    v_means, v_covars = np.zeros(m.shape), np.zeros(S.shape)
    PK.project_bwd(scene["means"].numpy(), scene["covars"].numpy(), cams.cams, cams.ts, cams.lims, EPS2D, radii,
                   v2.numpy(), vc.numpy(), vd.numpy(), v_means, v_covars)  # fmt: skip
    for ours, ref in ((v_means, m.grad), (v_covars, S.grad)):
        scale = float(ref.abs().max())
        assert scale > 0
        np.testing.assert_allclose(ours, ref.numpy(), rtol=0, atol=1e-9 * scale)


def test_numba_projection_matches_torch_autograd_random() -> None:
    scene = random_scene(400, seed=11)
    scene["means"][:20] *= 6.0  # some far outside the field of view (Jacobian clamp) or behind the cameras
    _check_projection(scene, camera_rig(3, np.zeros(3), 2.5, 48, 40))


def test_numba_projection_matches_torch_autograd_flat_edge_on() -> None:
    scene = _flat_edge_on_scene(300, seed=12)
    scene["means"][:10, 2] = -1.0  # behind the camera: culled
    _check_projection(scene, [head_on_camera(64, 48, 80.0)])


def test_float32_render_equals_float64_render_of_the_same_gaussians() -> None:
    # the flat cloth Gaussians of `bench render`, many seen nearly edge-on, at 64 px: the old backend cast depths
    # and centres to float32 between projection and compositing, which reordered near-tied Gaussians (off by 2.2e-2)
    from clods_bench.splatting.flag_scene import bench_scene

    f32, cams = bench_scene(0, 64, 8, dtype=torch.float32)
    same = {k: v.double() for k, v in f32.items()}
    a = render_gaussians(f32["means"], f32["covars"], f32["opacities"], f32["colors"], cams)
    b = render_gaussians(same["means"], same["covars"], same["opacities"], same["colors"], cams)
    diff = max(float((a.rgb.double() - b.rgb).abs().max()), float((a.alpha.double() - b.alpha).abs().max()))
    assert diff <= 1e-6, diff


def test_radix_depth_order_equals_a_stable_sort() -> None:
    """The binning's depth order: an LSD radix sort of the keys' bits, against numpy's stable argsort (ties by index)."""
    from clods_bench.splatting.fast_kernels import stable_argsort_positive

    rng = np.random.default_rng(0)
    for trial in range(120):
        n = int(rng.integers(0, 2500))
        keys = rng.random(n) * rng.choice([1e-6, 1.0, 7.0, 1e8]) + 1e-3
        if trial % 3 == 0:  # many exact ties
            keys = np.round(keys, 1) + 0.5
        if trial % 7 == 0 and n:  # keys spanning many binades, and denormal-free tiny ones
            keys = np.exp(rng.normal(0, 30, n))
        np.testing.assert_array_equal(stable_argsort_positive(keys), np.argsort(keys, kind="stable"))
