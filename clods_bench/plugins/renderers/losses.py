"""The photometric fitting loss of 3DGS, GaMeS and SMGS (paper eq. 5): (1 - lambda) L1 + lambda D-SSIM.

SSIM follows Wang et al. 2004 as 3DGS computes it: an 11x11 Gaussian window with sigma 1.5, local
statistics with population (biased) variances, C1 = (0.01 L)^2, C2 = (0.03 L)^2 for data range L = 1,
per colour channel, averaged. D-SSIM is 1 - SSIM, the convention of the 3DGS training code
(`loss = (1 - lambda) * l1 + lambda * (1 - ssim(image, gt))`), so lambda = 0.2 matches its weighting.
With padding 'valid' only complete windows count (skimage's `structural_similarity` mean, which crops
a 5-pixel border); with 'zero' every pixel has a window, zero-padded at the border (3DGS's conv2d).
"""

from __future__ import annotations

from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from clods_bench.errors import ClodsError

WINDOW = 11
SIGMA = 1.5
K1, K2 = 0.01, 0.03
LAMBDA_DSSIM = 0.2
Padding = Literal["valid", "zero"]


def gaussian_window(size: int = WINDOW, sigma: float = SIGMA, dtype: torch.dtype = torch.float32) -> Tensor:
    """(size,) normalised 1D Gaussian weights centred on the middle tap (the SSIM window is its outer product)."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2.0
    w = torch.exp(-(x**2) / (2.0 * sigma**2))
    return (w / w.sum()).to(dtype)


def _blur(x: Tensor, w: Tensor, pad: int) -> Tensor:
    """Separable Gaussian filter of (B,C,H,W) images, depthwise, with `pad` zeros on each side."""
    C = x.shape[1]
    k = w.numel()
    x = F.conv2d(x, w.view(1, 1, k, 1).expand(C, 1, k, 1), padding=(pad, 0), groups=C)
    return F.conv2d(x, w.view(1, 1, 1, k).expand(C, 1, 1, k), padding=(0, pad), groups=C)


def ssim_map(a: Tensor, b: Tensor, padding: Padding = "zero", data_range: float = 1.0) -> Tensor:
    """(...,h,w,3) per-pixel SSIM of two (...,H,W,3) images; differentiable in both."""
    if a.shape != b.shape or a.dim() < 3 or a.shape[-1] != 3:
        raise ClodsError(f"need two (...,H,W,3) images of one shape, got {tuple(a.shape)} and {tuple(b.shape)}", where="ssim")
    H, W = a.shape[-3:-1]
    if padding == "valid" and min(H, W) < WINDOW:
        raise ClodsError(f"'valid' SSIM needs images of at least {WINDOW}x{WINDOW}, got {H}x{W}", where="ssim")
    if padding not in ("valid", "zero"):
        raise ClodsError(f"unknown padding '{padding}'; known: valid, zero", where="ssim")
    lead = a.shape[:-3]
    x = a.reshape(-1, H, W, 3).permute(0, 3, 1, 2)
    y = b.reshape(-1, H, W, 3).permute(0, 3, 1, 2)
    w = gaussian_window(dtype=a.dtype).to(a.device)
    pad = WINDOW // 2 if padding == "zero" else 0
    # one depthwise blur of the five stacked statistics (2 conv calls instead of 10: the fit loop's hot spot)
    mu_x, mu_y, exx, eyy, exy = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), w, pad).chunk(5, dim=1)
    sxx = exx - mu_x * mu_x
    syy = eyy - mu_y * mu_y
    sxy = exy - mu_x * mu_y
    c1, c2 = (K1 * data_range) ** 2, (K2 * data_range) ** 2
    s = ((2 * mu_x * mu_y + c1) * (2 * sxy + c2)) / ((mu_x**2 + mu_y**2 + c1) * (sxx + syy + c2))
    return s.permute(0, 2, 3, 1).reshape(*lead, s.shape[-2], s.shape[-1], 3)


def ssim(a: Tensor, b: Tensor, padding: Padding = "zero") -> Tensor:
    """Mean SSIM (scalar tensor) of two (...,H,W,3) images in [0,1]."""
    return ssim_map(a, b, padding).mean()


def render_loss(pred: Tensor, gt: Tensor, lambda_dssim: float = LAMBDA_DSSIM, padding: Padding = "zero") -> Tensor:
    """Paper eq. 5: (1 - lambda) mean |pred - gt| + lambda (1 - SSIM), for (...,H,W,3) images."""
    l1 = (pred - gt).abs().mean()
    if lambda_dssim == 0.0:
        return l1
    return (1.0 - lambda_dssim) * l1 + lambda_dssim * (1.0 - ssim(pred, gt, padding))
