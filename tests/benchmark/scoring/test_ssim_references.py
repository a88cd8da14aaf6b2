"""`image_metrics.ssim` against two independent references on non-trivial pairs (noise, shift, brightness, contrast).

The definition under test (Wang et al. 2004): per colour channel, an 11x11 Gaussian window (sigma 1.5, the 1-D
kernel exp(-k^2 / 2 sigma^2), k = -5..5, normalised) at every position where it lies wholly inside the image;
weighted means, population variances and covariance; SSIM = (2 mx my + C1)(2 sxy + C2) / ((mx^2 + my^2 + C1)
(sx^2 + sy^2 + C2)) with C1 = (0.01 L)^2, C2 = (0.03 L)^2, data range L = 1; the mean over those positions, then
over the three channels; float64 throughout.

References: (a) scikit-image's `structural_similarity` called per channel as a grayscale image with every parameter
spelled out, its full SSIM map cropped here by the window radius; (b) a brute-force loop over window positions.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from clods_bench.benchmark.scoring import image_metrics as im
from clods_bench.errors import ClodsError

WIN, SIGMA, K1, K2, L = 11, 1.5, 0.01, 0.03, 1.0
RADIUS = (WIN - 1) // 2

TOL = 1e-12
"""Both references and the implementation compute in float64 (eps 2.2e-16). The implementation (and reference a)
form variances as E[x^2] - E[x]^2, reference b as E[(x - mean)^2]: the cancellation costs at most a factor
E[x^2] / (variance + C2) <= 1 / C2 ~ 1.1e3 on sums of 121 terms, so ~1e-13 per window; 1e-12 leaves room (measured:
1.2e-15). A misconfigured SSIM differs far more: sample covariance by >= 1.7e-5 on these pairs, sigma 1.4 by 1.2e-4,
averaging the uncropped map by 8e-5, a 7x7 uniform window by 7e-4."""


def gaussian_window() -> np.ndarray:
    """The 11x11 weights: the outer product of the normalised 1-D Gaussian, sigma 1.5 (sums to 1)."""
    k = np.arange(-RADIUS, RADIUS + 1, dtype=np.float64)
    g = np.exp(-(k**2) / (2.0 * SIGMA**2))
    g /= g.sum()
    return np.outer(g, g)


def ssim_brute_force(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM of two (H,W,C) images: an explicit loop over every window position inside the image (float64)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    w = gaussian_window()[:, :, None]
    c1, c2 = (K1 * L) ** 2, (K2 * L) ** 2
    h, wd, _ = a.shape
    total, count = np.zeros(a.shape[2]), 0
    for i in range(h - WIN + 1):
        for j in range(wd - WIN + 1):
            x, y = a[i : i + WIN, j : j + WIN], b[i : i + WIN, j : j + WIN]
            mx, my = (w * x).sum(axis=(0, 1)), (w * y).sum(axis=(0, 1))
            vx, vy = (w * (x - mx) ** 2).sum(axis=(0, 1)), (w * (y - my) ** 2).sum(axis=(0, 1))
            cxy = (w * (x - mx) * (y - my)).sum(axis=(0, 1))
            total += (2 * mx * my + c1) * (2 * cxy + c2) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
            count += 1
    return float((total / count).mean())  # each channel's mean over positions, then the channels' mean


def ssim_skimage(a: np.ndarray, b: np.ndarray) -> float:
    """scikit-image's SSIM map of each channel (all parameters explicit), cropped by the window radius, averaged."""
    means = []
    for c in range(a.shape[2]):
        _, smap = structural_similarity(
            np.asarray(a[..., c], dtype=np.float64), np.asarray(b[..., c], dtype=np.float64), win_size=WIN,
            gaussian_weights=True, sigma=SIGMA, use_sample_covariance=False, data_range=L, K1=K1, K2=K2,
            channel_axis=None, full=True,
        )  # fmt: skip
        assert smap.shape == a.shape[:2]
        means.append(smap[RADIUS:-RADIUS, RADIUS:-RADIUS].mean())  # only the windows wholly inside the image
    return float(np.mean(means))


def textured(h: int, w: int, seed: int) -> np.ndarray:
    """An (H,W,3) image in [0,1] with structure at several scales: sinusoids, a checkerboard and fine noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    out = np.empty((h, w, 3))
    for c in range(3):
        fx, fy, phase = rng.uniform(0.05, 0.4, 2).tolist() + [rng.uniform(0, 2 * np.pi)]
        out[..., c] = 0.5 + 0.25 * np.sin(fx * xx + fy * yy + phase) + 0.1 * (((yy // 4) + (xx // 4)) % 2 - 0.5)
    return np.clip(out + 0.05 * rng.standard_normal(out.shape), 0.0, 1.0)


def _shifted(h: int, w: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    big = textured(h + 6, w + 6, seed)
    return big[3 : 3 + h, 3 : 3 + w], big[0:h, 5 : 5 + w]  # the same texture, 3 px down and 2 px right


PAIRS: dict[str, Callable[[int, int, int], tuple[np.ndarray, np.ndarray]]] = {
    "gaussian-noise": lambda h, w, s: (t := textured(h, w, s), np.clip(t + 0.08 * np.random.default_rng(s + 99).standard_normal(t.shape), 0, 1)),
    "shift": _shifted,
    "brightness-0.7": lambda h, w, s: (t := textured(h, w, s), 0.7 * t),
    "contrast": lambda h, w, s: (t := textured(h, w, s), np.clip(0.5 + 1.6 * (t - 0.5), 0, 1)),
    "other-image": lambda h, w, s: (textured(h, w, s), textured(h, w, s + 1)),
}  # fmt: skip
SIZES = [(24, 32), (64, 48), (11, 17)]  # (11, 17): one row of windows, the smallest height accepted


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("kind", list(PAIRS))
def test_ssim_matches_scikit_image_and_brute_force(kind: str, size: tuple[int, int]) -> None:
    pred, gt = PAIRS[kind](*size, sum(size))
    got = im.ssim(pred, gt)
    brute, ski = ssim_brute_force(pred, gt), ssim_skimage(pred, gt)
    assert abs(got - brute) <= TOL and abs(got - ski) <= TOL, (got, brute, ski)
    assert got == pytest.approx(im.ssim(gt, pred), abs=TOL)  # symmetric
    assert -1.0 < got < 0.999  # a non-trivial pair: not the identical-image 1


def test_reference_reproduces_hand_values() -> None:
    """The brute-force reference itself, on cases whose SSIM is known in closed form."""
    rng = np.random.default_rng(5)
    img = rng.random((13, 12, 3))
    assert ssim_brute_force(img, img) == pytest.approx(1.0, abs=1e-14)
    a, b, c1 = 0.3, 0.6, (K1 * L) ** 2  # constant images: only the luminance term
    assert ssim_brute_force(np.full((11, 11, 3), a), np.full((11, 11, 3), b)) == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1), rel=1e-14)
    x = img[:11, :11]  # one window: y = -x around the window mean gives covariance -var, SSIM (2m^2+C1)/(2m^2+C1) * (C2-2v)/(C2+2v)
    m = (gaussian_window()[:, :, None] * x).sum(axis=(0, 1))
    y = 2 * m - x
    v = (gaussian_window()[:, :, None] * (x - m) ** 2).sum(axis=(0, 1))
    c2 = (K2 * L) ** 2
    assert ssim_brute_force(x, y) == pytest.approx(float(((c2 - 2 * v) / (c2 + 2 * v)).mean()), abs=1e-14)


def test_batches_and_float32_inputs_match_the_references() -> None:
    """`image_scores` over a (B,H,W,3) float32 batch: each image's SSIM is that of its float32 values taken as float64."""
    pairs = [PAIRS[k](24, 32, i) for i, k in enumerate(PAIRS)]
    pred = np.stack([p for p, _ in pairs]).astype(np.float32)
    gt = np.stack([g for _, g in pairs]).astype(np.float32)
    got = im.image_scores(pred, gt)["ssim"]
    assert got.shape == (len(pairs),) and got.dtype == np.float64
    for k in range(len(pairs)):
        assert abs(got[k] - ssim_brute_force(pred[k], gt[k])) <= TOL and abs(got[k] - ssim_skimage(pred[k], gt[k])) <= TOL


def test_only_rgb_images_are_taken() -> None:
    """Grayscale (H,W) or other channel counts are refused, not averaged in some other way."""
    gray = textured(24, 32, 0)[..., 0]
    with pytest.raises(ClodsError, match=r"expected two \(H,W,3\) images"):
        im.ssim(gray, gray)
    with pytest.raises(ClodsError, match=r"expected two \(H,W,3\) images"):
        im.ssim(np.zeros((24, 32, 4)), np.zeros((24, 32, 4)))
    with pytest.raises(ClodsError, match="smaller than SSIM's 11x11 window"):
        im.ssim(np.zeros((10, 32, 3)), np.zeros((10, 32, 3)))
