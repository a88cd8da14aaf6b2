"""The gsplat 2DGS surfel backend: its conventions against gsplat's own torch projection, its glue around gsplat's
kernels (replaced by a torch copy of their rules) against the CPU backend, its error without CUDA, and, on a GPU,
gsplat's real kernels against the CPU backend."""

from __future__ import annotations

import math
import sys
import types

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.errors import ClodsError
from clods_bench.splatting import gsplat_backend
from clods_bench.splatting.surfel_gsplat import box_radii
from clods_bench.splatting.surfels import project_surfels, render_surfels

F64 = torch.float64
ALL = ("rgb", "alpha", "depth_median", "depth_expected", "normal", "distortion")
FOOTPRINT = ("rgb", "alpha", "normal")  # equal for any surfel; depth maps only where hit z = centre z


def _scene(G: int, seed: int, facing: bool) -> tuple[torch.Tensor, ...]:
    """G surfels with opacities <= 0.3 (so gsplat's missing 3-sigma cut and 0.999 clamp never bind), facing +z
    (planes of constant camera z for cameras with R = I) when `facing`, else randomly turned."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(G, 3, generator=g, dtype=F64) - 0.5) * torch.tensor([1.2, 0.9, 0.6], dtype=F64)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=F64).repeat(G, 1) if facing else torch.randn(G, 4, generator=g, dtype=F64)
    scales = torch.rand(G, 2, generator=g, dtype=F64) * 0.08 + 0.04
    opac = torch.rand(G, generator=g, dtype=F64) * 0.25 + 0.05
    colors = torch.rand(G, 3, generator=g, dtype=F64)
    return means, quats, scales, opac, colors


def _front_cameras(W: int = 40, H: int = 28) -> list[Camera]:
    """Two cameras with R = I, 2.5 in front of the scene, side by side (surfels facing +z face both squarely)."""
    K = np.array([[45.0, 0.0, W / 2], [0.0, 45.0, H / 2], [0.0, 0.0, 1.0]])
    return [Camera(K, np.eye(3), np.array([dx, 0.0, 2.5]), W, H) for dx in (0.0, 0.3)]


def _render(scene, cameras, backend: str, keys=ALL) -> tuple[dict, dict]:
    """Every map, and the gradients of a fixed random weighting of the maps `keys`, w.r.t. every input."""
    leaves = [x.clone().requires_grad_(True) for x in scene]
    out = render_surfels(*leaves, cameras, backend=backend, background=(0.2, 0.3, 0.4))
    g = torch.Generator().manual_seed(1)
    loss = sum((getattr(out, k) * torch.rand(getattr(out, k).shape, generator=g, dtype=F64)).sum() for k in keys)
    loss.backward()
    names = ("means", "quats", "scales", "opacities", "colors")
    return {k: getattr(out, k).detach() for k in ALL}, {n: x.grad for n, x in zip(names, leaves)}


# ---------------------------------------------------------------------------------------------------------
# gsplat's own (pure torch) 2DGS projection: our M is its ray transform


def test_projection_matches_gsplats_torch_projection() -> None:
    torch_impl = pytest.importorskip("gsplat.cuda._torch_impl_2dgs")
    means, quats, scales, opac, _ = _scene(30, seed=3, facing=False)
    cameras = camera_rig(3, np.zeros(3), 2.5, 40, 28)
    proj = project_surfels(means, quats, scales, opac, cameras, near=0.01)
    view = torch.zeros(len(cameras), 4, 4, dtype=F64)
    view[:, :3, :3] = torch.tensor(np.stack([c.R for c in cameras]))
    view[:, :3, 3] = torch.tensor(np.stack([c.t for c in cameras]))
    view[:, 3, 3] = 1.0
    Ks = torch.tensor(np.stack([c.K for c in cameras]))
    scales3 = torch.cat([scales, torch.ones(len(scales), 1, dtype=F64)], dim=-1)  # unit 3rd axis: unit normals
    _, _, depths, M, normals_cam = torch_impl._fully_fused_projection_2dgs(means, quats, scales3, view, Ks, 40, 28)
    torch.testing.assert_close(proj.M, M, atol=1e-12, rtol=1e-12)
    torch.testing.assert_close(proj.depths, depths, atol=1e-12, rtol=0)
    world = torch.einsum("cji,cgj->cgi", view[:, :3, :3], normals_cam)  # R^T n: gsplat's camera-facing normal, in world
    torch.testing.assert_close(proj.normals, world, atol=1e-12, rtol=0)


def test_box_radii_cover_the_boxes_with_gsplats_tile_rule() -> None:
    g = torch.Generator().manual_seed(0)
    means2d = torch.rand(2, 200, 2, generator=g, dtype=F64) * 90 - 10
    lo = torch.floor(means2d - torch.rand(2, 200, 2, generator=g, dtype=F64) * 20)
    hi = torch.floor(means2d + torch.rand(2, 200, 2, generator=g, dtype=F64) * 20)
    boxes = torch.cat([lo, hi], dim=-1).to(torch.int64)
    boxes[0, :5] = torch.tensor([0, 0, -1, -1])  # culled
    radii = box_radii(means2d, boxes)
    assert radii.dtype == torch.int32 and bool((radii[0, :5] == 0).all())
    tile = 16
    for c in range(2):
        for i in range(5 if c == 0 else 0, 200):
            t0 = np.floor((means2d[c, i].numpy() - radii[c, i].numpy()) / tile)  # gsplat isect_tiles (unclamped)
            t1 = np.ceil((means2d[c, i].numpy() + radii[c, i].numpy()) / tile)
            b = boxes[c, i].numpy()
            assert (t0 <= b[0:2] // tile).all() and (t1 >= b[2:4] // tile + 1).all(), (c, i)


# ---------------------------------------------------------------------------------------------------------
# the glue around gsplat's kernels, with the kernels replaced by a torch copy of their rules


def _tile_lists(means2d, radii, depths, tile, tiles_x, tiles_y) -> dict:
    """gsplat's isect_tiles + sort: per (camera, tile) the surfel ids overlapping it, by centre depth (stable)."""
    lists: dict = {}
    C, G = depths.shape
    for c in range(C):
        for g in range(G):
            rx, ry = int(radii[c, g, 0]), int(radii[c, g, 1])
            if rx <= 0 or ry <= 0:
                continue
            mx, my = float(means2d[c, g, 0]) / tile, float(means2d[c, g, 1]) / tile
            x0, x1 = (min(max(0, f(v)), tiles_x) for f, v in ((math.floor, mx - rx / tile), (math.ceil, mx + rx / tile)))
            y0, y1 = (min(max(0, f(v)), tiles_y) for f, v in ((math.floor, my - ry / tile), (math.ceil, my + ry / tile)))
            for ty in range(y0, y1):
                for tx in range(x0, x1):
                    lists.setdefault((c, ty * tiles_x + tx), []).append((float(depths[c, g]), g))
    return {k: [g for _, g in sorted(v, key=lambda e: e[0])] for k, v in lists.items()}


def _composite(pix, M, m2, feats, opac, normals):
    """gsplat RasterizeToPixels2DGSFwd for P pixels over n surfels in order: (P, channels + 1 + 3 + 1 + 1)."""
    Tu, Tv, Tw = M[:, 0], M[:, 1], M[:, 2]
    hu = pix[:, 0, None, None] * Tw[None] - Tu[None]
    hv = pix[:, 1, None, None] * Tw[None] - Tv[None]
    cr = torch.linalg.cross(hu, hv, dim=-1)
    ok = cr[..., 2] != 0
    cz = torch.where(ok, cr[..., 2], torch.ones_like(cr[..., 2]))
    g3 = (cr[..., 0] / cz) ** 2 + (cr[..., 1] / cz) ** 2
    d = m2[None] - pix[:, None, :]
    g2 = 2.0 * (d * d).sum(-1)
    alpha = torch.clamp(opac[None] * torch.exp(-0.5 * torch.minimum(g3, g2)), max=0.999)
    alpha = torch.where(ok & (alpha >= 1.0 / 255.0), alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        keep = torch.cumprod(1.0 - alpha, dim=1) > 1e-4  # next_T <= 1e-4: done, exclusive
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    t_after = torch.cumprod(1.0 - alpha, dim=1)
    t_before = torch.cat([torch.ones_like(t_after[:, :1]), t_after[:, :-1]], dim=1)
    w = alpha * t_before
    depth = feats[:, -1]
    acc_wd = torch.cumsum(w * depth[None], 1) - w * depth[None]
    distort = (2.0 * (w * depth[None] * (1.0 - t_before) - w * acc_wd)).sum(1, keepdim=True)
    with torch.no_grad():
        mark = (alpha > 0) & (t_before > 0.5)
        last = torch.where(mark, torch.arange(mark.shape[1])[None].expand_as(mark), torch.full_like(mark, -1, dtype=torch.int64))
        idx = last.max(1).values
    median = torch.where(idx >= 0, depth[idx.clamp(min=0)], torch.zeros_like(idx, dtype=depth.dtype))[:, None]
    return torch.cat([w @ feats, 1.0 - t_after[:, -1:], w @ normals, distort, median], dim=1)


GSPLAT_CHANNELS = (1, 2, 3, 4, 8, 16, 32, 64, 128, 256, 512)
"""Channel counts gsplat's 2DGS rasterizer takes as they are; it pads any other count (`_wrapper.py`)."""


def _fake_wrapper() -> types.ModuleType:
    """gsplat.cuda._wrapper's isect_tiles / isect_offset_encode / rasterize_to_pixels_2dgs, in torch on the CPU. Like
    gsplat 1.5.3, a channel count it has no kernel for is padded before the last channel with uninitialised memory
    (`torch.empty`), here NaN: the forward drops those channels, but 0 x NaN poisons the alpha gradient."""

    def isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height):
        assert means2d.dtype == depths.dtype == torch.float32 and radii.dtype == torch.int32 and radii.shape == means2d.shape
        return None, _tile_lists(means2d, radii, depths, tile_size, tile_width, tile_height), None

    def isect_offset_encode(isect_ids, n_images, tile_width, tile_height):
        return (isect_ids, n_images, tile_width, tile_height)

    def rasterize_to_pixels_2dgs(means2d, ray_transforms, colors, opacities, normals, densify, image_width, image_height,
                                 tile_size, isect_offsets, flatten_ids, distloss=False):  # fmt: skip
        assert distloss and densify.shape == means2d.shape
        assert all(x.dtype == torch.float32 for x in (means2d, ray_transforms, colors, opacities, normals))
        lists, C, tiles_x, _ = isect_offsets
        given = colors.shape[-1]
        if given not in GSPLAT_CHANNELS:  # gsplat 1.5.3 pads before the last channel with torch.empty: garbage, NaN here
            pad = (1 << (given - 1).bit_length()) - given
            colors = torch.cat([colors[..., :-1], torch.full((*colors.shape[:-1], pad), float("nan")), colors[..., -1:]], -1)
        ch = colors.shape[-1]
        out = torch.zeros(C * image_height * image_width, ch + 6, dtype=torch.float32)
        for (c, t), ids in lists.items():
            ty, tx = divmod(t, tiles_x)
            rows = torch.arange(ty * tile_size, min((ty + 1) * tile_size, image_height))
            cols = torch.arange(tx * tile_size, min((tx + 1) * tile_size, image_width))
            rr, cc = torch.meshgrid(rows, cols, indexing="ij")
            pix = torch.stack([cc.flatten() + 0.5, rr.flatten() + 0.5], dim=-1).to(torch.float32)
            sel = torch.tensor(ids)
            vals = _composite(pix, ray_transforms[c, sel], means2d[c, sel], colors[c, sel], opacities[c, sel], normals[c, sel])
            out = out.index_copy(0, c * image_height * image_width + (rr * image_width + cc).flatten(), vals)
        out = out.reshape(C, image_height, image_width, ch + 6)
        render = out[..., :ch] if ch == given else torch.cat([out[..., : given - 1], out[..., ch - 1 : ch]], -1)
        return render, out[..., ch : ch + 1], out[..., ch + 1 : ch + 4], out[..., ch + 4 : ch + 5], out[..., ch + 5 :]

    wrapper = types.ModuleType("gsplat.cuda._wrapper")
    wrapper.isect_tiles, wrapper.isect_offset_encode = isect_tiles, isect_offset_encode
    wrapper.rasterize_to_pixels_2dgs = rasterize_to_pixels_2dgs
    return wrapper


@pytest.fixture
def fake_gsplat(monkeypatch):
    for name, module in (("gsplat", types.ModuleType("gsplat")), ("gsplat.cuda", types.ModuleType("gsplat.cuda")),
                         ("gsplat.cuda._wrapper", _fake_wrapper())):  # fmt: skip
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setattr(gsplat_backend, "gsplat_available", lambda: (True, ""))
    monkeypatch.setattr(gsplat_backend, "gpu_for", lambda means: means.device)


def _compare(a: dict, b: dict, keys, atol: float) -> None:
    for k in keys:
        torch.testing.assert_close(a[k], b[k], atol=atol, rtol=0, msg=k)


def _compare_grads(a: dict, b: dict, rel: float, skip=()) -> None:
    """Gradients equal up to float32 compositing: within `rel` of the largest component."""
    for k, g in b.items():
        if k not in skip:
            assert float(g.abs().max()) > 0, k
            torch.testing.assert_close(a[k], g, atol=rel * float(g.abs().max()), rtol=0, msg=f"gradient of {k}")


@pytest.mark.parametrize("facing", [False, True])
def test_gsplat_glue_matches_the_cpu_backend(fake_gsplat, facing: bool) -> None:
    scene = _scene(60, seed=5, facing=facing)
    cameras = _front_cameras() if facing else camera_rig(2, np.zeros(3), 2.5, 40, 28)
    keys = ALL if facing else FOOTPRINT
    cpu_img, cpu_grad = _render(scene, cameras, "cpu", keys)
    gs_img, gs_grad = _render(scene, cameras, "gsplat", keys)
    assert float(cpu_img["alpha"].max()) > 0.6 and float((cpu_img["depth_median"] > 0).float().mean()) > 0.02
    _compare(gs_img, cpu_img, keys, atol=2e-5)
    _compare_grads(gs_grad, cpu_grad, rel=2e-4, skip=("quats",) if facing else ())
    if facing:  # turning a facing surfel moves its hit's z, not its centre's: compare quats on the footprint maps
        _compare_grads(_render(scene, cameras, "gsplat", FOOTPRINT)[1], _render(scene, cameras, "cpu", FOOTPRINT)[1], rel=2e-4)


def test_gsplat_glue_depth_is_the_centres_for_slanted_surfels(fake_gsplat) -> None:
    """The documented difference: gsplat carries depth per surfel, so a slanted surfel's expected depth is its
    centre's z everywhere it covers, where the CPU backend gives the hit's z."""
    cam = [Camera(np.array([[60.0, 0, 16], [0, 60.0, 16], [0, 0, 1]]), np.eye(3), np.zeros(3), 32, 32)]
    tilt = (math.cos(0.3), math.sin(0.3), 0.0, 0.0)  # 0.6 rad about x
    scene = tuple(torch.tensor(v, dtype=F64) for v in ([[0.0, 0.0, 2.0]], [tilt], [[0.1, 0.1]], [0.3], [[1.0, 0.5, 0.0]]))
    gs = render_surfels(*scene, cam, backend="gsplat")
    cpu = render_surfels(*scene, cam, backend="cpu")
    covered = cpu.alpha[..., 0] > 1.0 / 255.0
    torch.testing.assert_close(gs.depth_expected[..., 0][covered], torch.full_like(gs.depth_expected[..., 0][covered], 2.0), atol=1e-4, rtol=0)
    assert float((cpu.depth_expected[..., 0][covered] - 2.0).abs().max()) > 0.05  # the hit's z changes across it
    torch.testing.assert_close(gs.alpha, cpu.alpha, atol=2e-5, rtol=0)


def test_gsplat_backend_without_cuda_says_what_to_install(monkeypatch) -> None:
    monkeypatch.setattr(gsplat_backend, "gsplat_available", lambda: (False, "no CUDA GPU (torch.cuda.is_available() is False)"))
    with pytest.raises(ClodsError) as e:
        render_surfels(*_scene(4, seed=0, facing=True), _front_cameras(), backend="gsplat")
    assert e.value.where == "render_surfels(backend='gsplat')" and "pip install gsplat" in str(e.value) and "no CUDA GPU" in str(e.value)


# ---------------------------------------------------------------------------------------------------------
# on a GPU: gsplat's real kernels


@pytest.mark.parametrize("facing", [False, True])
def test_gsplat_kernels_match_the_cpu_backend(facing: bool) -> None:
    ok, why = gsplat_backend.gsplat_available()
    if not ok:
        pytest.skip(f"surfel backend gsplat needs gsplat and a CUDA GPU: {why}")
    scene = _scene(60, seed=5, facing=facing)
    cameras = _front_cameras() if facing else camera_rig(2, np.zeros(3), 2.5, 40, 28)
    keys = ALL if facing else FOOTPRINT
    cpu_img, cpu_grad = _render(scene, cameras, "cpu", keys)
    gs_img, gs_grad = _render(scene, cameras, "gsplat", keys)
    _compare(gs_img, cpu_img, keys, atol=1e-4)
    _compare_grads(gs_grad, cpu_grad, rel=1e-3, skip=("quats",) if facing else ())
