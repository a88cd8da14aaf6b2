"""The fitting loss: SSIM against scikit-image, the D-SSIM convention, and eq. 5's weighting."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.losses import gaussian_window, render_loss, ssim, ssim_map


def _pair(seed: int = 0, h: int = 24, w: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """A smooth image and a noisy, shifted version of it, both in [0,1]."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / 8.0
    a = np.stack([0.5 + 0.4 * np.sin(xx + k) * np.cos(yy - k) for k in range(3)], -1)
    b = np.clip(0.9 * a + 0.05 + 0.08 * rng.standard_normal(a.shape), 0, 1)
    return a, b


def _skimage(a: np.ndarray, b: np.ndarray, full: bool = False):
    return structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                 data_range=1.0, channel_axis=-1, full=full)  # fmt: skip


def test_window_is_the_normalised_gaussian():
    w = gaussian_window(dtype=torch.float64).numpy()
    x = np.arange(11) - 5.0
    ref = np.exp(-(x**2) / (2 * 1.5**2))
    np.testing.assert_allclose(w, ref / ref.sum(), rtol=1e-12)


def test_valid_ssim_equals_skimage_mean():
    a, b = _pair()
    ours = float(ssim(torch.tensor(a), torch.tensor(b), padding="valid"))
    assert ours == pytest.approx(_skimage(a, b), abs=1e-10)


def test_zero_padded_map_matches_skimage_away_from_the_border():
    a, b = _pair(1)
    ours = ssim_map(torch.tensor(a), torch.tensor(b), padding="zero").numpy()
    _, ref = _skimage(a, b, full=True)
    assert ours.shape == a.shape
    np.testing.assert_allclose(ours[5:-5, 5:-5], ref[5:-5, 5:-5], atol=1e-10)


def test_batched_images_score_like_single_ones():
    a, b = _pair(2)
    batch_a = torch.tensor(np.stack([a, b]))
    batch_b = torch.tensor(np.stack([b, b]))
    m = ssim_map(batch_a, batch_b, padding="valid")
    assert float(m[0].mean()) == pytest.approx(_skimage(a, b), abs=1e-10)
    assert float(m[1].mean()) == pytest.approx(1.0, abs=1e-12)


def test_loss_is_l1_plus_lambda_dssim():
    a, b = _pair(3)
    ta, tb = torch.tensor(a), torch.tensor(b)
    l1 = np.abs(a - b).mean()
    s = float(ssim(ta, tb))
    assert float(render_loss(ta, tb, 0.0)) == pytest.approx(l1, rel=1e-12)
    assert float(render_loss(ta, tb, 0.2)) == pytest.approx(0.8 * l1 + 0.2 * (1.0 - s), rel=1e-12)
    assert float(render_loss(ta, ta, 0.2)) == pytest.approx(0.0, abs=1e-12)


def test_loss_gradient_matches_finite_differences():
    a, b = _pair(4, 16, 16)
    tb = torch.tensor(b)
    x = torch.tensor(a, requires_grad=True)
    render_loss(x, tb).backward()
    rng = np.random.default_rng(0)
    for _ in range(3):  # directional derivatives along random directions
        d = torch.tensor(rng.standard_normal(a.shape))
        h = 1e-6
        fd = (float(render_loss(x.detach() + h * d, tb)) - float(render_loss(x.detach() - h * d, tb))) / (2 * h)
        assert float((x.grad * d).sum()) == pytest.approx(fd, rel=1e-5, abs=1e-9)


def test_bad_shapes_raise():
    with pytest.raises(ClodsError, match="one shape"):
        ssim(torch.zeros(8, 8, 3), torch.zeros(8, 9, 3))
    with pytest.raises(ClodsError, match="at least 11x11"):
        ssim(torch.zeros(8, 8, 3), torch.zeros(8, 8, 3), padding="valid")
