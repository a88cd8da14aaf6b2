"""Every renderer plugin: bad input raises ClodsError naming it; degenerate geometry renders finitely; ablation switches."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.games import GamesConfig, GamesRenderer
from clods_bench.plugins.renderers.gs3d import Gs3dConfig, Gs3dRenderer
from clods_bench.plugins.renderers.smgs import SmgsConfig, SmgsRenderer

from .conftest import rig

MAKERS = {
    "games": lambda: GamesRenderer(GamesConfig(iterations=0)),
    "smgs": lambda: SmgsRenderer(SmgsConfig(iterations=0)),
    "gs3d": lambda: Gs3dRenderer(Gs3dConfig(num_gaussians=40, iterations=0)),
}
NAMES = list(MAKERS)


def _with_K(cam: Camera, K: np.ndarray) -> Camera:
    return Camera(K, cam.R, cam.t, cam.width, cam.height)


def _bad_cameras(cams: list[Camera]) -> list[tuple[list[Camera], str]]:
    """(camera list, expected message) pairs with invalid intrinsics in the second camera."""
    K = cams[1].K
    nan_K = K.copy()
    nan_K[0, 2] = np.nan
    return [
        ([cams[0], _with_K(cams[1], np.diag([0.0, K[1, 1], 1.0]) + K * np.array([[0, 0, 1], [0, 0, 1], [0, 0, 0]]))], r"cameras\[1\]\.K.*focal"),
        ([cams[0], _with_K(cams[1], K * np.array([[1, 1, 1], [1, -1, 1], [1, 1, 1]]))], r"cameras\[1\]\.K.*focal"),
        ([cams[0], _with_K(cams[1], nan_K)], r"cameras\[1\]\.K.*finite"),
        ([cams[0], _with_K(cams[1], K[:2])], r"cameras\[1\]\.K.*3x3"),
    ]


def _fit(r, mesh, cams, images=None):
    verts, cells, mesh_pos = mesh
    if images is None:
        images = np.full((1, len(cams), cams[0].height, cams[0].width, 3), 0.5, np.float32)
    return r.fit(verts[None], cells, mesh_pos, images, cams)


@pytest.mark.parametrize("name", NAMES)
def test_invalid_intrinsics_raise_in_fit_and_render(mesh, name):
    cams = rig(2, 12)
    for bad, msg in _bad_cameras(cams):
        with pytest.raises(ClodsError, match=msg):
            _fit(MAKERS[name](), mesh, bad)
    r = MAKERS[name]()
    _fit(r, mesh, cams)
    for bad, msg in _bad_cameras(cams):
        with pytest.raises(ClodsError, match=msg):
            r.render(torch.tensor(mesh[0]), bad)
    skew = _with_K(cams[0], cams[0].K + np.array([[0.0, 0.3, 0.0], [0, 0, 0], [0, 0, 0]]))
    with pytest.raises(ClodsError, match=r"cameras\[0\]\.K.*pinhole"):
        r.render(torch.tensor(mesh[0]), [skew])


@pytest.mark.parametrize("name", NAMES)
def test_images_of_the_wrong_size_raise(mesh, name):
    cams = rig(2, 12)
    with pytest.raises(ClodsError, match=r"images have shape \(1, 2, 12, 13, 3\), expected \(1, 2, 12, 12, 3\)"):
        _fit(MAKERS[name](), mesh, cams, np.full((1, 2, 12, 13, 3), 0.5, np.float32))
    with pytest.raises(ClodsError, match="images have shape"):
        _fit(MAKERS[name](), mesh, cams, np.full((1, 3, 12, 12, 3), 0.5, np.float32))  # one image too many
    with pytest.raises(ClodsError, match="images have shape"):
        _fit(MAKERS[name](), mesh, cams, np.full((1, 2, 12, 12), 0.5, np.float32))  # no colour axis
    mixed = [cams[0], rig(2, 14)[1]]
    with pytest.raises(ClodsError, match=r"cameras\[1\].*14x14, images are 12x12"):
        _fit(MAKERS[name](), mesh, mixed, np.full((1, 2, 12, 12, 3), 0.5, np.float32))
    with pytest.raises(ClodsError, match=r"\[0,1\]"):
        _fit(MAKERS[name](), mesh, cams, np.full((1, 2, 12, 12, 3), 1.5, np.float32))


@pytest.mark.parametrize("name", NAMES)
def test_nan_vertices_raise_in_fit_and_render(mesh, name):
    verts, cells, mesh_pos = mesh
    cams = rig(2, 12)
    bad = verts.copy()
    bad[7, 2] = np.nan
    with pytest.raises(ClodsError, match=r"fit\.verts.*non-finite vertex.*\(0, 7\)"):
        _fit(MAKERS[name](), (bad, cells, mesh_pos), cams)
    inf = verts.copy()
    inf[2, 0] = np.inf
    with pytest.raises(ClodsError, match=r"non-finite vertex.*\(0, 2\)"):
        _fit(MAKERS[name](), (inf, cells, mesh_pos), cams)
    r = MAKERS[name]()
    _fit(r, mesh, cams)
    with pytest.raises(ClodsError, match=r"render\.verts.*non-finite vertex.*\(7,\)"):
        r.render(torch.tensor(bad), cams)


@pytest.mark.parametrize("name", ["games", "smgs"])
def test_degenerate_geometry_gives_finite_images_and_vertex_gradients(mesh, name):
    """Zero-area faces, Gaussians behind the camera and at its centre, huge scales: finite output, no crash."""
    verts, cells, mesh_pos = mesh
    cams = rig(2, 16)  # at distance 2.5 from the origin
    r = MAKERS[name]()
    _fit(r, mesh, cams)
    centre = cams[0].center
    cases = {
        "zero-area faces": np.where(np.arange(len(verts))[:, None] < 6, verts[0], verts),
        "all collinear": np.outer(np.linspace(0, 1, len(verts)), [1.0, 0.5, 0.2]),
        "behind camera 0": verts + 2.0 * centre,  # the cloth at 1.5x the camera's distance, on its own side
        "through camera 0": verts * 0.01 + centre,  # every Gaussian within 1 cm of the camera centre
    }
    for label, v_np in cases.items():
        v = torch.tensor(v_np, requires_grad=True)
        out = r.render(v, cams)
        out.sum().backward()
        assert torch.isfinite(out).all() and torch.isfinite(v.grad).all(), label
    with torch.no_grad():
        back = r.render(torch.tensor(verts + 2.0 * centre), cams[:1])
    torch.testing.assert_close(back, torch.ones_like(back))  # all behind camera 0: its image is the white background
    with torch.no_grad():
        r.params["log_scale"].fill_(25.0)  # scale factor e^25: each Gaussian far larger than the scene
    v = torch.tensor(verts, requires_grad=True)
    out = r.render(v, cams)
    out.sum().backward()
    assert torch.isfinite(out).all() and torch.isfinite(v.grad).all()


@pytest.mark.parametrize("k", [5, 10, 20])
@pytest.mark.parametrize("name", ["games", "smgs"])
def test_gaussians_per_face_switch(mesh, name, k):
    """The paper's 5/10/20 Gaussians per face: F*K Gaussians, each at its own place on its face."""
    cls, cfg = (GamesRenderer, GamesConfig) if name == "games" else (SmgsRenderer, SmgsConfig)
    r = cls(cfg(gaussians_per_face=k, iterations=1))
    cams = rig(1, 12)
    stats = _fit(r, mesh, cams)
    F = mesh[1].shape[0]
    assert stats["num_gaussians"] == F * k == r.num_gaussians
    with torch.no_grad():
        means, covars, opac, colors = r.gaussians(torch.tensor(mesh[0]))
    assert means.shape == (F * k, 3) and covars.shape == (F * k, 3, 3) and opac.shape == (F * k,) and colors.shape == (F * k, 3)
    per_face = means.reshape(F, k, 3)
    gaps = torch.cdist(per_face, per_face) + torch.eye(k) * 1e9
    assert float(gaps.min()) > 1e-4  # no two Gaussians of a face coincide
    centroid = torch.tensor(mesh[0])[torch.from_numpy(mesh[1].astype(np.int64))].mean(1)
    torch.testing.assert_close(per_face.mean(1), centroid, atol=0.15, rtol=0)  # spread around the centroid
    assert torch.isfinite(r.render(torch.tensor(mesh[0]), cams)).all()


def test_ablation_switches_load_from_yaml_config():
    """`renderer_config.smgs.inputs` and `gaussians_per_face` reach the plugin through its config_cls; bad values are named."""
    reg = default_registry()
    for name in ("games", "smgs"):
        spec = reg.get("renderer", name)
        cfg = spec.make_config({"gaussians_per_face": 20}, where=f"renderer_config.{name}")
        assert cfg.gaussians_per_face == 20
    spec = reg.get("renderer", "smgs")
    for inputs in ("both", "world", "mesh", "none"):
        assert spec.make_config({"inputs": inputs}, where="renderer_config.smgs").inputs == inputs
    with pytest.raises(ClodsError, match=r"renderer_config\.smgs.*'inputs' = 'time', expected one of"):
        spec.make_config({"inputs": "time"}, where="renderer_config.smgs")
