"""Degenerate Gaussians render finitely; bad inputs raise ClodsError naming the argument and index."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError
from clods_bench.splatting import render_gaussians
from tests.splatting.conftest import head_on_camera, random_scene

BACKENDS = ["cpu", "reference"]
F64 = torch.float64


def _degenerate_scene() -> dict:
    """Flat (zero-thickness) Gaussians face-on and edge-on, behind the camera, at the near plane, at the
    camera centre, huge, off to the side near the near plane, plus ordinary ones."""
    flat_xy = torch.diag(torch.tensor([0.01, 0.004, 0.0], dtype=F64))  # zero thickness along z: face-on
    flat_yz = torch.diag(torch.tensor([0.0, 0.01, 0.004], dtype=F64))  # normal along x
    edge_on = torch.diag(torch.tensor([0.0, 0.0, 0.01], dtype=F64))  # a needle along the view ray
    iso = 0.002 * torch.eye(3, dtype=F64)
    rows = [
        ([0.0, 0.0, 2.0], flat_xy),
        ([0.1, 0.05, 2.5], flat_yz),
        ([0.0, 0.1, 1.5], edge_on),
        ([0.0, 0.0, -1.0], iso),  # behind the camera
        ([0.0, 0.0, 0.01], iso),  # exactly on the near plane
        ([0.0, 0.0, 0.0], iso),  # at the camera centre
        ([0.0, 0.0, 3.0], 1e8 * torch.eye(3, dtype=F64)),  # huge: covers the whole image
        ([5.0, -3.0, 0.0101], iso),  # just in front of the near plane, far outside the field of view
        ([-0.2, 0.1, 2.0], torch.zeros(3, 3, dtype=F64)),  # a point: only the 0.3 px dilation remains
    ]
    G = len(rows)
    g = torch.Generator().manual_seed(0)
    return {
        "means": torch.tensor([r[0] for r in rows], dtype=F64),
        "covars": torch.stack([r[1] for r in rows]),
        "opacities": torch.full((G,), 0.7, dtype=F64).index_fill(0, torch.tensor([6]), 0.05),
        "colors": torch.rand(G, 3, generator=g, dtype=F64),
    }


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_degenerate_gaussians_give_finite_images_and_gradients(backend: str, dtype: torch.dtype) -> None:
    scene = {k: v.to(dtype).requires_grad_(True) for k, v in _degenerate_scene().items()}
    cams = [head_on_camera(32, 24, 60.0), Camera(np.diag([60.0, 60.0, 1.0]) + np.array([[0, 0, 16], [0, 0, 12], [0, 0, 0]]),
                                                 np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]]), np.array([0.0, 0, 2.0]), 32, 24)]  # fmt: skip
    out = render_gaussians(scene["means"], scene["covars"], scene["opacities"], scene["colors"], cams, backend=backend)
    for name in ("rgb", "alpha", "depth"):
        assert torch.isfinite(getattr(out, name)).all(), name
    radii = out.radii[0]
    assert radii[3] == 0 and radii[4] == 0 and radii[5] == 0  # behind, on the near plane, at the centre: culled
    assert radii[0] > 0 and radii[2] > 0 and radii[6] > 0 and radii[8] > 0
    assert float(out.alpha[0].detach().min()) >= 0.05 - 1e-6  # the huge faint Gaussian covers every pixel
    (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
    for k, v in scene.items():
        assert v.grad is not None and torch.isfinite(v.grad).all(), k
    assert float(scene["means"].grad[0].abs().sum()) > 0  # a flat Gaussian still gets a position gradient


@pytest.mark.parametrize(
    "field, index",
    [("means", 4), ("covars", 2), ("opacities", 7), ("colors", 1)],
)
def test_nan_input_names_argument_and_index(field: str, index: int) -> None:
    scene = random_scene(10)
    scene[field] = scene[field].clone()
    scene[field][index] = float("nan")
    with pytest.raises(ClodsError, match=rf"{field}\[{index}\].*non-finite"):
        render_gaussians(scene["means"], scene["covars"], scene["opacities"], scene["colors"], [head_on_camera()])


def test_invalid_inputs_raise_clods_error() -> None:
    s = random_scene(5)
    args = (s["means"], s["covars"], s["opacities"], s["colors"])
    bad_K = head_on_camera()
    bad_K = Camera(np.diag([0.0, 100.0, 1.0]), bad_K.R, bad_K.t, bad_K.width, bad_K.height)
    with pytest.raises(ClodsError, match=r"cameras\[1\]\.K.*focal"):
        render_gaussians(*args, [head_on_camera(), bad_K])
    skew = head_on_camera()
    skew = Camera(skew.K + np.array([[0.0, 0.5, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), skew.R, skew.t, skew.width, skew.height)
    with pytest.raises(ClodsError, match=r"cameras\[0\]\.K.*pinhole"):
        render_gaussians(*args, [skew])
    with pytest.raises(ClodsError, match=r"cameras\[1\].*image size"):
        render_gaussians(*args, [head_on_camera(40, 24), head_on_camera(32, 24)])
    with pytest.raises(ClodsError, match=r"covars.*shape"):
        render_gaussians(s["means"], s["covars"][:, :2], s["opacities"], s["colors"], [head_on_camera()])
    with pytest.raises(ClodsError, match=r"opacities\[0\].*\[0, 1\]"):
        render_gaussians(s["means"], s["covars"], s["opacities"] + 1.0, s["colors"], [head_on_camera()])
    with pytest.raises(ClodsError, match=r"backend.*known: cpu, reference, gsplat"):
        render_gaussians(*args, [head_on_camera()], backend="cuda")  # type: ignore[arg-type]
    with pytest.raises(ClodsError, match=r"colors.*K=5"):
        render_gaussians(s["means"], s["covars"], s["opacities"], torch.zeros(5, 5, 3, dtype=F64), [head_on_camera()])
    with pytest.raises(ClodsError, match=r"covars.*not both"):
        render_gaussians(*args, [head_on_camera()], quats=torch.ones(5, 4, dtype=F64), scales=torch.ones(5, 3, dtype=F64))
    with pytest.raises(ClodsError, match=r"covars.*both quats and scales"):
        render_gaussians(s["means"], None, s["opacities"], s["colors"], [head_on_camera()], quats=torch.ones(5, 4, dtype=F64))
    with pytest.raises(ClodsError, match=r"scales\[2\].*non-finite"):
        bad = torch.ones(5, 3, dtype=F64).index_fill(0, torch.tensor([2]), float("nan"))
        render_gaussians(s["means"], None, s["opacities"], s["colors"], [head_on_camera()], quats=torch.ones(5, 4, dtype=F64), scales=bad)
    with pytest.raises(ClodsError, match=r"cameras.*at least one"):
        render_gaussians(*args, [])
    with pytest.raises(ClodsError, match=r"background"):
        render_gaussians(*args, [head_on_camera()], background=(1.0, 1.0))


def test_gsplat_backend_without_gsplat_or_cuda_raises_install_hint() -> None:
    from clods_bench.splatting.gsplat_backend import gsplat_available

    if gsplat_available()[0]:
        pytest.skip("gsplat and CUDA are available here; the error path cannot be exercised")
    s = random_scene(3)
    with pytest.raises(ClodsError, match="backend gsplat needs gsplat and a CUDA GPU: pip install gsplat"):
        render_gaussians(s["means"], s["covars"], s["opacities"], s["colors"], [head_on_camera()], backend="gsplat")


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("G", [0, 3])
def test_nothing_visible_renders_background_with_zero_gradients(backend: str, G: int) -> None:
    means = torch.tensor([[0.0, 0.0, -1.0]] * G, dtype=F64).reshape(G, 3).requires_grad_(True)  # all behind
    covars = (0.01 * torch.eye(3, dtype=F64)).expand(G, 3, 3)
    out = render_gaussians(means, covars, torch.full((G,), 0.5, dtype=F64), torch.ones(G, 3, dtype=F64), [head_on_camera()],
                           background=(0.2, 0.4, 0.6), backend=backend)  # fmt: skip
    torch.testing.assert_close(out.rgb[0, 3, 5], torch.tensor([0.2, 0.4, 0.6], dtype=F64))
    assert (out.alpha == 0).all() and (out.depth == 0).all() and out.radii.shape == (1, G)
    out.rgb.sum().backward()
    assert means.grad is not None and (means.grad == 0).all()
