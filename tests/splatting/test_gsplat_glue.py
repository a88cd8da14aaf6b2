"""The gsplat backend's glue on any machine: gsplat's three kernels replaced by the torch reference rasterizer.

The real kernels run only on CUDA (test_backends.py compares them with the CPU backend there); this checks
what surrounds them everywhere: the projection shared with the CPU backends, the conic layout, colour and
depth packed as four channels, background and depth normalisation, radii, and gradients through all of it.
"""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import camera_rig
from clods_bench.splatting import gsplat_backend
from clods_bench.splatting.projection import tile_bounds
from clods_bench.splatting.reference import rasterize_reference
from tests.splatting.conftest import random_scene
from tests.splatting.test_backends import _render_with_grads


def _fake_gsplat() -> types.ModuleType:
    """A module with gsplat's isect_tiles / isect_offset_encode / rasterize_to_pixels signatures, in torch."""

    def isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height):
        assert means2d.dtype == depths.dtype == torch.float32 and radii.dtype == torch.int32
        assert radii.shape == means2d.shape and depths.shape == means2d.shape[:-1]
        return None, (radii, depths, tile_width, tile_height), None

    def isect_offset_encode(isect_ids, n_images, tile_width, tile_height):
        assert isect_ids[2:] == (tile_width, tile_height) and isect_ids[0].shape[0] == n_images
        return isect_ids

    def rasterize_to_pixels(means2d, conics, colors, opacities, image_width, image_height, tile_size, isect_offsets, flatten_ids):
        radii, keys = isect_offsets[:2]
        assert colors.shape[-1] == 4 and opacities.shape == means2d.shape[:-1]
        G = keys.shape[-1]  # the sort keys are the ranks 1..G of the float64 depths, per camera
        assert torch.equal(torch.sort(keys, dim=-1).values, torch.arange(1, G + 1, dtype=keys.dtype).expand_as(keys))
        bounds = tile_bounds(means2d, radii, image_width, image_height, tile_size)
        # depth from the fourth channel, so its gradient reaches the depths through `colors` as in gsplat; order by the keys
        color, alpha, dacc = rasterize_reference(means2d, conics, colors[..., :3], opacities, colors[..., 3], bounds,
                                                 image_width, image_height, tile_size, order=keys)  # fmt: skip
        return torch.cat([color, dacc], dim=-1), alpha

    wrapper = types.ModuleType("gsplat.cuda._wrapper")
    wrapper.isect_tiles, wrapper.isect_offset_encode, wrapper.rasterize_to_pixels = isect_tiles, isect_offset_encode, rasterize_to_pixels
    return wrapper


@pytest.fixture
def fake_gsplat(monkeypatch):
    wrapper = _fake_gsplat()
    for name, module in (("gsplat", types.ModuleType("gsplat")), ("gsplat.cuda", types.ModuleType("gsplat.cuda")),
                         ("gsplat.cuda._wrapper", wrapper)):  # fmt: skip
        monkeypatch.setitem(sys.modules, name, module)
    monkeypatch.setattr(gsplat_backend, "gsplat_available", lambda: (True, ""))
    monkeypatch.setattr(gsplat_backend, "gpu_for", lambda means: means.device)


@pytest.mark.parametrize("sh_degree", [None, 1])
@pytest.mark.parametrize("depth_mode", ["expected", "accumulated"])
def test_gsplat_glue_matches_the_cpu_backend(fake_gsplat, sh_degree: int | None, depth_mode: str) -> None:
    scene = random_scene(150, seed=9, dtype=torch.float32, sh_degree=sh_degree)
    cameras = camera_rig(2, np.zeros(3), 2.5, 40, 28)
    cpu_img, cpu_grad = _render_with_grads(scene, cameras, "cpu", depth_mode=depth_mode)
    gs_img, gs_grad = _render_with_grads(scene, cameras, "gsplat", depth_mode=depth_mode)
    assert torch.equal(gs_img["radii"], cpu_img["radii"])
    for k in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(gs_img[k], cpu_img[k], atol=1e-5, rtol=1e-5)
    for k, g in cpu_grad.items():
        assert float(g.abs().max()) > 0, k
        torch.testing.assert_close(gs_grad[k], g, atol=1e-4 * float(g.abs().max()), rtol=0, msg=f"gradient of {k}")
