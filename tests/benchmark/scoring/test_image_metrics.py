"""PSNR/SSIM against closed-form values; LPIPS loaded from local files, checked against the lpips package itself."""

from __future__ import annotations

import importlib.util
import sys
import types

import numpy as np
import pytest
import torch
from torch import nn

from clods_bench.benchmark.scoring import image_metrics as im, lpips_weights as lw
from clods_bench.errors import ClodsError

# ------------------------------------------------------------------ PSNR / SSIM


def test_psnr_known_values() -> None:
    rng = np.random.default_rng(0)
    gt = rng.uniform(0.2, 0.8, (16, 20, 3))
    assert im.psnr(gt + 0.1, gt) == pytest.approx(20.0, abs=1e-9)  # MSE 0.01
    half = np.zeros((4, 4, 3))
    half[:2] = 1.0
    assert im.psnr(half, np.zeros_like(half)) == pytest.approx(10 * np.log10(2.0), abs=1e-12)  # MSE 0.5
    assert im.psnr(gt, gt) == im.PSNR_MAX_DB


def test_ssim_known_values() -> None:
    rng = np.random.default_rng(1)
    img = rng.random((24, 24, 3))
    assert im.ssim(img, img) == pytest.approx(1.0, abs=1e-12)
    # two constant images: no variance, so SSIM is the luminance term (2ab + C1) / (a^2 + b^2 + C1), C1 = 0.01^2
    a, b, c1 = 0.3, 0.6, 0.01**2
    assert im.ssim(np.full((16, 16, 3), a), np.full((16, 16, 3), b)) == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1), rel=1e-9)
    assert im.ssim(np.clip(img + 0.2 * rng.standard_normal(img.shape), 0, 1), img) < 0.9


def test_metric_input_errors() -> None:
    with pytest.raises(ClodsError, match="smaller than SSIM"):
        im.ssim(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)))
    with pytest.raises(ClodsError, match="equal shape"):
        im.psnr(np.zeros((8, 8, 3)), np.zeros((8, 9, 3)))
    with pytest.raises(ClodsError, match="NaN"):
        im.psnr(np.full((8, 8, 3), np.nan), np.zeros((8, 8, 3)))


# ------------------------------------------------------------------ LPIPS


def torchvision_alexnet_features() -> nn.Sequential:
    """torchvision's AlexNet `features`, written out independently of the module under test."""
    return nn.Sequential(
        nn.Conv2d(3, 64, 11, 4, 2), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
        nn.Conv2d(64, 192, 5, padding=2), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
        nn.Conv2d(192, 384, 3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(384, 256, 3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(256, 256, 3, padding=1), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
    )  # fmt: skip


def random_metric(seed: int) -> tuple[im.LpipsMetric, nn.Sequential, list[torch.Tensor]]:
    """The project's LPIPS on random AlexNet weights and random non-negative heads (and those weights)."""
    torch.manual_seed(seed)
    feats = torchvision_alexnet_features()
    heads = [torch.rand(1, c, 1, 1) for c in lw.CHANNELS]
    return im.LpipsMetric(lw.LpipsWeights(dict(feats.state_dict()), heads, "random", ())), feats, heads


def _pair(h: int = 40, w: int = 48, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.random((3, h, w, 3)).astype(np.float32)
    return a, np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1).astype(np.float32)


def test_lpips_behaves_like_a_distance() -> None:
    metric, _, _ = random_metric(0)
    a, b = _pair()
    np.testing.assert_array_equal(metric(a, a), 0.0)
    d = metric(a, b)
    assert d.shape == (3,) and (d > 0).all()
    np.testing.assert_allclose(metric(b, a), d, rtol=1e-6)
    assert not np.allclose(random_metric(1)[0](a, b), d, rtol=1e-3)  # other weights -> other distances


def test_lpips_matches_the_lpips_package(monkeypatch: pytest.MonkeyPatch) -> None:
    """The lpips package's own LPIPS(net='alex', v0.1) on the same random weights, torchvision faked in memory. The lpips
    package is not installed by the set-up command (it is not a weight source); install it without its dependencies
    to run this check (`pip install --no-deps lpips==0.1.4`)."""
    spec = importlib.util.find_spec("lpips")
    if spec is None:
        pytest.skip("the lpips package is not installed (`pip install --no-deps lpips==0.1.4` runs this comparison)")
    metric, feats, _ = random_metric(2)
    tv = types.ModuleType("torchvision")
    tv.models = types.ModuleType("torchvision.models")
    tv.models.alexnet = lambda pretrained=False, **_: types.SimpleNamespace(features=feats)
    monkeypatch.setitem(sys.modules, "torchvision", tv)
    monkeypatch.setitem(sys.modules, "torchvision.models", tv.models)
    try:
        import lpips

        reference = lpips.LPIPS(net="alex", version="0.1", verbose=False)  # loads its own v0.1 heads
        heads = [reference.lins[k].model[-1].weight.detach().clone() for k in range(len(lw.CHANNELS))]
        a, b = _pair(seed=3)
        with torch.no_grad():
            expected = reference(torch.tensor(a).permute(0, 3, 1, 2), torch.tensor(b).permute(0, 3, 1, 2), normalize=True).flatten().numpy()
    finally:
        for name in [m for m in sys.modules if m == "lpips" or m.startswith("lpips.")]:
            del sys.modules[name]
    ours = im.LpipsMetric(lw.LpipsWeights(dict(feats.state_dict()), heads, "lpips", ()))
    np.testing.assert_allclose(ours(a, b), expected, rtol=1e-4, atol=1e-7)


def test_lpips_rejects_images_alexnet_cannot_take() -> None:
    metric, _, _ = random_metric(0)
    a, b = _pair(h=30, w=40)
    with pytest.raises(ClodsError, match="minimum 31"):
        metric(a, b)
    assert metric(*_pair(h=31, w=31)).shape == (3,)  # the smallest size that works
    assert isinstance(im.lpips_for((30, 40), metric), im.LpipsUnavailable)
    assert im.lpips_for((31, 40), metric) is metric
