"""Lighting and cast shadows of the ground-truth rasterizer against hand-computed shading, a brute-force ray
test of an occluder's shadow, and the bytes the renderer produced before shadows existed."""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.datasets.cloths import FlagCloth
from clods_bench.datasets.data_config import DataConfig
from clods_bench.datasets.generate import scene_identity, scene_raster_settings
from clods_bench.datasets.lighting import DirectionalLight
from clods_bench.datasets.rasterizer import RasterSettings, render, render_depth, render_views
from clods_bench.datasets.scenes import SceneSpec, get_scene
from clods_bench.errors import ClodsError

WHITE = np.ones((2, 2, 3), np.float32)
AMBIENT, DIFFUSE = 0.2, 0.5
QUAD = np.array([[0, 1, 2], [0, 2, 3]])


def camera(size: int, f: float) -> Camera:
    """Camera at the origin looking along +z (world = camera frame), principal point at the image centre."""
    return Camera(np.array([[f, 0.0, size / 2], [0.0, f, size / 2], [0.0, 0.0, 1.0]]), np.eye(3), np.zeros(3), size, size)


def light_at(angle_deg: float, azimuth_deg: float = 30.0, **kw) -> DirectionalLight:
    """A light travelling at `angle_deg` from +z (the camera's viewing axis), shadows on."""
    a, b = np.radians(angle_deg), np.radians(azimuth_deg)
    kw = {"ambient": AMBIENT, "diffuse": DIFFUSE, "shadow_map_size": 256, **kw}
    return DirectionalLight(direction=(np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)), **kw)


def lit_image(verts: np.ndarray, cells: np.ndarray, cam: Camera, light: DirectionalLight) -> np.ndarray:
    return render(verts, cells, np.zeros((len(verts), 2)), WHITE, cam, RasterSettings(supersample=1, light=light))[..., 0]


@pytest.mark.parametrize("tilt_deg", [0.0, 35.0])
@pytest.mark.parametrize("angle_deg", [0.0, 30.0, 60.0, 85.0])
@pytest.mark.parametrize("map_size", [16, 512])
def test_flat_quad_is_ambient_plus_diffuse_cos_everywhere(tilt_deg, angle_deg, map_size):
    """A single flat quad casts no shadow on itself (no acne at any angle, even at grazing light or a coarse map):
    every pixel it covers is ambient + diffuse * cos(angle between its normal and the light)."""
    cam = camera(32, 24.0)
    t = np.radians(tilt_deg)  # quad rotated about the y axis: normal (sin t, 0, cos t)
    corners = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    verts = np.column_stack([corners[:, 0] * np.cos(t), corners[:, 1], 2.0 - corners[:, 0] * np.sin(t)])
    light = light_at(angle_deg, shadow_map_size=map_size)
    normal = np.array([np.sin(t), 0.0, np.cos(t)])
    expected = AMBIENT + DIFFUSE * abs(normal @ light.unit_direction())
    img = lit_image(verts, QUAD, cam, light)
    covered = np.isfinite(render_depth(verts, QUAD, cam))
    assert covered.sum() > 100
    np.testing.assert_allclose(img[covered], expected, atol=1e-6)
    assert np.all(img[~covered] == 1.0)
    if (tilt_deg, angle_deg) == (0.0, 60.0):  # by hand: 0.2 + 0.5 * cos 60 deg
        np.testing.assert_allclose(img[covered], 0.45, atol=1e-6)


def test_occluder_shadow_is_where_the_light_ray_hits_the_occluder():
    """An occluder quad 0.8 m in front of a receiver quad: the receiver's shadowed pixels are exactly those whose
    world point, traced back toward the light, hits the occluder (brute force; 1-pixel border allowed), and they
    get only the ambient term."""
    size, f, z_rec, z_occ, half = 48, 24.0, 2.0, 1.2, 0.3
    cam = camera(size, f)
    rec = np.array([[-1.0, -1.0, z_rec], [1.0, -1.0, z_rec], [1.0, 1.0, z_rec], [-1.0, 1.0, z_rec]])
    occ = np.array([[-half, -half, z_occ], [half, -half, z_occ], [half, half, z_occ], [-half, half, z_occ]])
    verts, cells = np.concatenate([rec, occ]), np.concatenate([QUAD, QUAD + 4])
    light = light_at(45.0, azimuth_deg=40.0, shadow_map_size=512)
    img = lit_image(verts, cells, cam, light)
    depth = render_depth(verts, cells, cam)
    receiver = np.abs(depth - z_rec) < 1e-9  # pixels where the receiver is the visible surface
    # brute force: the pixel centre's ray hits the receiver at depth z_rec; trace that point back toward the light
    cc, rr = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5, indexing="xy")
    p = np.stack([(cc - size / 2) * z_rec / f, (rr - size / 2) * z_rec / f, np.full(cc.shape, z_rec)], axis=-1)
    lit_dir = light.unit_direction()
    q = p - ((z_rec - z_occ) / lit_dir[2]) * lit_dir  # where the ray toward the light crosses the occluder's plane
    expected = receiver & (np.abs(q[..., 0]) <= half) & (np.abs(q[..., 1]) <= half)
    shadowed = receiver & np.isclose(img, AMBIENT, rtol=0.0, atol=1e-6)
    lit_value = AMBIENT + DIFFUSE * lit_dir[2]
    assert expected.sum() > 30  # the shadow is really in view, beside the occluder
    assert np.all(np.isclose(img[receiver], AMBIENT, atol=1e-6) | np.isclose(img[receiver], lit_value, atol=1e-6))
    grown = _dilate(expected)
    shrunk = ~_dilate(~expected)
    assert np.all(shadowed <= grown) and np.all(shrunk & receiver <= shadowed)
    assert (shadowed != expected).sum() <= 0.15 * expected.sum()
    np.testing.assert_allclose(img[~receiver & np.isfinite(depth)], lit_value, atol=1e-6)  # the occluder is lit


def _dilate(mask: np.ndarray) -> np.ndarray:
    """Mask grown by one pixel (8-neighbourhood)."""
    out = mask.copy()
    padded = np.pad(mask, 1)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            out |= padded[1 + dr : 1 + dr + mask.shape[0], 1 + dc : 1 + dc + mask.shape[1]]
    return out


# Hashes of the uint8 frames (as the generator stores them) rendered by the rasterizer before shadows existed
# (commit 0d4d9a0): unlit, and lit by the generator's shadowless light.
BEFORE_SHADOWS = {"unlit": "484cba93371e093d", "lit": "aface7d9f2aaa66a"}


@pytest.mark.parametrize("case", ["unlit", "lit"])
def test_frames_without_shadows_are_unchanged(case):
    mesh = get_scene("flag").build_mesh((9, 5))
    rng = np.random.default_rng(7)
    verts = mesh.rest_pos + 0.05 * rng.standard_normal(mesh.rest_pos.shape)
    tex = rng.random((16, 16, 3)).astype(np.float32)
    cams = camera_rig(3, verts.mean(0), 3.0, 24, 24, 40.0)
    light = DirectionalLight((-0.3, 0.8, -0.5), 0.3, 0.7) if case == "lit" else None
    img = render_views(verts, mesh.cells, mesh.texture_uv(), tex, cams, RasterSettings(supersample=2, light=light))
    frames = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
    assert hashlib.sha256(frames.tobytes()).hexdigest()[:16] == BEFORE_SHADOWS[case]


def test_flag_lit_differs_from_flag_only_in_its_light():
    """(The fingerprints of the scenes from before lights existed are pinned in test_cloths.)"""
    flag, lit = scene_identity(get_scene("flag")), scene_identity(get_scene("flag-lit"))
    assert lit.pop("has_lighting") is True and flag.pop("has_lighting") is False
    assert lit.pop("light")["shadow_map_size"] > 0 and "light" not in flag
    lit.pop("name"), flag.pop("name")
    assert lit == flag  # same cloth, physics and random ranges: the same trajectories, only the frames are lit
    d = DataConfig()
    assert scene_raster_settings(d, get_scene("flag")).light is None
    assert scene_raster_settings(d, get_scene("flag-lit")).light == get_scene("flag-lit").light


def test_bad_lights_are_one_error_naming_the_scene_and_field():
    def scene(**kw) -> SceneSpec:
        return SceneSpec("my-lit", "a scene", FlagCloth(), get_scene("flag").params, **kw)

    with pytest.raises(ClodsError) as info:
        scene(has_lighting=True, light=DirectionalLight((0.0, 0.0, 0.0)))
    assert info.value.where == "scene my-lit" and "light.direction" in info.value.what
    with pytest.raises(ClodsError, match="light.shadow_map_size") as info:
        scene(has_lighting=True, light=DirectionalLight(shadow_map_size=2))
    assert info.value.where == "scene my-lit"
    with pytest.raises(ClodsError, match="light.shadow_bias"):
        scene(has_lighting=True, light=DirectionalLight(shadow_bias=-1.0))
    with pytest.raises(ClodsError, match="has_lighting") as info:
        scene(light=DirectionalLight())
    assert info.value.where == "scene my-lit"
    scene(has_lighting=True, light=dataclasses.replace(get_scene("flag-lit").light))  # a good light is accepted
    with pytest.raises(ClodsError, match="light.direction") as info:
        render(np.zeros((3, 3)), QUAD[:1], np.zeros((3, 2)), WHITE, camera(8, 8.0), RasterSettings(light=DirectionalLight((0, 0, 0))))
    assert info.value.where == "settings"
