"""Image metrics of the novel-view-synthesis table: PSNR, SSIM and LPIPS (AlexNet, v0.1).

Images are float arrays (H,W,3) in [0,1]. LPIPS is the network of Zhang et al. 2018 written
out here in torch (the `lpips` package needs torchvision, which is not a dependency): the
AlexNet `features` of torchvision (same layer layout and state-dict keys), taps after its
five ReLUs, lpips' input scaling, channel-unit-normalised squared feature differences,
lpips' learned 1x1 linear layers, spatial mean, sum over layers. Weights are never
downloaded: the linear layers come from the installed `lpips` package (located without
importing it), the backbone from the torch hub cache; if either is absent, `load_lpips`
says why instead of computing a number with random weights.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from skimage.metrics import structural_similarity
from torch import nn

from clods_bench.errors import ClodsError

ALEXNET_FILE = "alexnet-owt-7be5be79.pth"
"""torchvision's ImageNet AlexNet checkpoint name in the torch hub cache."""
GET_ALEXNET = "python -c \"import torchvision; torchvision.models.alexnet(weights='DEFAULT')\""
CHANNELS = (64, 192, 384, 256, 256)
"""Channels of the five AlexNet taps relu1..relu5 (= input widths of lpips' lin0..lin4)."""
CONV_LAYERS = {0: (3, 64, 11), 3: (64, 192, 5), 6: (192, 384, 3), 8: (384, 256, 3), 10: (256, 256, 3)}
"""torchvision AlexNet `features` index -> (in channels, out channels, kernel size)."""
LPIPS_SHIFT = (-0.030, -0.088, -0.188)
LPIPS_SCALE = (0.458, 0.448, 0.450)
MIN_LPIPS_SIDE = 31
"""Smallest image side AlexNet's strides and poolings accept (the 2nd max-pool needs a 3x3 input)."""
PSNR_MAX_DB = 100.0
"""PSNR cap: identical images score this (MSE floor 1e-10) instead of inf, so means stay finite."""


# ------------------------------------------------------------------ PSNR / SSIM


def _pair(pred: Any, gt: Any, where: str) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(pred, dtype=np.float64), np.asarray(gt, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 3 or a.shape[-1] != 3:
        raise ClodsError(f"expected two (H,W,3) images of equal shape, got {a.shape} and {b.shape}", where=where)
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ClodsError("image has NaN/Inf values", where=where)
    return a, b


def psnr(pred: Any, gt: Any) -> float:
    """PSNR in dB of one (H,W,3) image against the truth, data range 1 (capped at PSNR_MAX_DB)."""
    a, b = _pair(pred, gt, "psnr")
    mse = max(float(np.mean((a - b) ** 2)), 10.0 ** (-PSNR_MAX_DB / 10.0))
    return float(-10.0 * np.log10(mse))


def ssim(pred: Any, gt: Any) -> float:
    """SSIM of Wang et al. 2004 (11x11 Gaussian window, sigma 1.5, data range 1), mean over pixels and channels."""
    a, b = _pair(pred, gt, "ssim")
    if min(a.shape[:2]) < 11:
        raise ClodsError(f"image {a.shape[0]}x{a.shape[1]} is smaller than SSIM's 11x11 window", where="ssim")
    return float(
        structural_similarity(a, b, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False)
    )


# ------------------------------------------------------------------ LPIPS


def alexnet_features() -> nn.Sequential:
    """torchvision's AlexNet `features` (same indices, so its state-dict keys load unchanged)."""
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.Conv2d(384, 256, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.Conv2d(256, 256, kernel_size=3, padding=1),
        nn.ReLU(),
        nn.MaxPool2d(kernel_size=3, stride=2),
    )


TAPS = (1, 4, 7, 9, 11)
"""`features` indices of the ReLUs whose outputs LPIPS compares (relu1..relu5)."""


def default_backbone_path() -> Path:
    """Where torchvision caches the AlexNet weights: torch.hub.get_dir()/checkpoints (honours TORCH_HOME)."""
    return Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_FILE


def default_linear_path() -> Path | None:
    """lpips' weights/v0.1/alex.pth inside the installed package (found without importing it), or None."""
    try:
        spec = importlib.util.find_spec("lpips")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0]) / "weights" / "v0.1" / "alex.pth"


@dataclass(frozen=True)
class LpipsUnavailable:
    """Why LPIPS cannot be computed here (a missing weights file), to be shown instead of a number."""

    reason: str


def _load_state(path: Path, what: str) -> dict[str, torch.Tensor]:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types (pickle, zip, runtime) for a bad file
        raise ClodsError(f"cannot read {what}: {type(exc).__name__}: {exc}", where=str(path)) from None
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ClodsError(f"{what} is not a state dict of tensors", where=str(path))
    return state


def _take(state: dict[str, torch.Tensor], key: str, shape: tuple[int, ...], path: Path, hint: str) -> torch.Tensor:
    if key not in state:
        raise ClodsError(f"missing weight '{key}'", where=str(path), hint=hint)
    value = state[key]
    if tuple(value.shape) != shape:
        raise ClodsError(f"weight '{key}' has shape {tuple(value.shape)}, expected {shape}", where=str(path), hint=hint)
    if not torch.isfinite(value).all():
        raise ClodsError(f"weight '{key}' has NaN/Inf values", where=str(path))
    return value.float()


class LpipsMetric:
    """LPIPS v0.1 with an AlexNet trunk: `metric(pred, gt)` -> (B,) distances of image pairs in [0,1]."""

    def __init__(self, backbone: dict[str, torch.Tensor], linear: dict[str, torch.Tensor], backbone_path: Path, linear_path: Path) -> None:
        """Build the network from already loaded state dicts (use `load_lpips` to find the files)."""
        self.backbone_path, self.linear_path = backbone_path, linear_path
        self.features = alexnet_features()
        hint = f"expected torchvision's {ALEXNET_FILE}"
        params = {}
        for idx, (cin, cout, k) in CONV_LAYERS.items():
            params[f"{idx}.weight"] = _take(backbone, f"features.{idx}.weight", (cout, cin, k, k), backbone_path, hint)
            params[f"{idx}.bias"] = _take(backbone, f"features.{idx}.bias", (cout,), backbone_path, hint)
        self.features.load_state_dict(params)
        self.lins = [
            _take(linear, f"lin{k}.model.1.weight", (1, c, 1, 1), linear_path, "expected lpips' weights/v0.1/alex.pth")
            for k, c in enumerate(CHANNELS)
        ]
        self.shift = torch.tensor(LPIPS_SHIFT).view(1, 3, 1, 1)
        self.scale = torch.tensor(LPIPS_SCALE).view(1, 3, 1, 1)
        self.features.eval().requires_grad_(False)

    def _taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in TAPS:
                out.append(x)
            if i == TAPS[-1]:
                break
        return out

    @torch.no_grad()
    def distance(self, pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
        """(B,) LPIPS of (B,3,H,W) tensors already in [-1,1] (lpips' own input convention)."""
        a = (pred - self.shift) / self.scale
        b = (gt - self.shift) / self.scale
        total = torch.zeros(pred.shape[0])
        for fa, fb, w in zip(self._taps(a), self._taps(b), self.lins):
            na = fa / (torch.sqrt((fa * fa).sum(dim=1, keepdim=True)) + 1e-10)
            nb = fb / (torch.sqrt((fb * fb).sum(dim=1, keepdim=True)) + 1e-10)
            total += torch.nn.functional.conv2d((na - nb) ** 2, w).mean(dim=(1, 2, 3))
        return total

    def __call__(self, pred: Any, gt: Any, batch: int = 16) -> np.ndarray:
        """(B,) LPIPS of (B,H,W,3) or (H,W,3) images in [0,1] (numpy or torch), computed in batches."""
        a = torch.from_numpy(np.array(pred, dtype=np.float32))  # a copy: inputs may be read-only views
        b = torch.from_numpy(np.array(gt, dtype=np.float32))
        if a.ndim == 3:
            a, b = a[None], b[None]
        if a.shape != b.shape or a.ndim != 4 or a.shape[-1] != 3:
            raise ClodsError(f"expected (B,H,W,3) images of equal shape, got {tuple(a.shape)} and {tuple(b.shape)}", where="lpips")
        if min(a.shape[1:3]) < MIN_LPIPS_SIDE:
            raise ClodsError(f"image {a.shape[1]}x{a.shape[2]} is smaller than AlexNet's minimum {MIN_LPIPS_SIDE} px", where="lpips")
        to_net = lambda x: (2.0 * x - 1.0).permute(0, 3, 1, 2).contiguous()  # noqa: E731  [0,1] HWC -> [-1,1] CHW
        out = [self.distance(to_net(a[i : i + batch]), to_net(b[i : i + batch])) for i in range(0, a.shape[0], batch)]
        return torch.cat(out).numpy().astype(np.float64)


def load_lpips(backbone_path: str | os.PathLike[str] | None = None, linear_path: str | os.PathLike[str] | None = None) -> LpipsMetric | LpipsUnavailable:
    """The LPIPS metric from local weight files, or LpipsUnavailable naming the missing file and how to get it.

    Defaults: the backbone from `default_backbone_path()`, the linear layers from the
    installed lpips package. A present but malformed file raises ClodsError naming it.
    """
    lin = Path(linear_path) if linear_path is not None else default_linear_path()
    if lin is None:
        return LpipsUnavailable(
            "LPIPS linear weights not found: the 'lpips' package is not installed (looked with importlib.util.find_spec('lpips')); "
            "install it with `pip install lpips --no-deps` (its weights/v0.1/alex.pth is used, lpips itself is not imported)"
        )
    if not lin.is_file():
        return LpipsUnavailable(f"LPIPS linear weights not found at {lin}; reinstall the 'lpips' package or copy weights/v0.1/alex.pth there")
    bb = Path(backbone_path) if backbone_path is not None else default_backbone_path()
    if not bb.is_file():
        return LpipsUnavailable(
            f"AlexNet backbone weights not found at {bb} (the torch hub cache; set TORCH_HOME to look elsewhere); "
            f"on a machine with network run `{GET_ALEXNET}` and copy {ALEXNET_FILE} from its torch hub checkpoints folder to {bb.parent}"
        )
    return LpipsMetric(_load_state(bb, "AlexNet backbone weights"), _load_state(lin, "LPIPS linear weights"), bb, lin)


def image_scores(pred: np.ndarray, gt: np.ndarray, lpips: LpipsMetric | None = None) -> dict[str, np.ndarray]:
    """Per-image 'psnr', 'ssim' (and 'lpips' if a metric is given) of (B,H,W,3) images in [0,1]."""
    pred, gt = np.asarray(pred), np.asarray(gt)
    if pred.shape != gt.shape or pred.ndim != 4:
        raise ClodsError(f"expected (B,H,W,3) images of equal shape, got {pred.shape} and {gt.shape}", where="image_scores")
    out = {
        "psnr": np.array([psnr(p, g) for p, g in zip(pred, gt)]),
        "ssim": np.array([ssim(p, g) for p, g in zip(pred, gt)]),
    }
    if lpips is not None:
        out["lpips"] = lpips(pred, gt)
    return out


def lpips_for(size: Sequence[int], lpips: LpipsMetric | LpipsUnavailable) -> LpipsMetric | LpipsUnavailable:
    """`lpips` itself, or LpipsUnavailable when (H,W) images are too small for AlexNet."""
    if isinstance(lpips, LpipsMetric) and min(size) < MIN_LPIPS_SIDE:
        return LpipsUnavailable(f"images are {size[0]}x{size[1]} px, smaller than AlexNet's minimum {MIN_LPIPS_SIDE} px")
    return lpips
