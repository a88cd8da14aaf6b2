"""TAU: the statical attention against a hand computation, the dynamical attention's gates, the differential
divergence against a brute-force numpy computation, output shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from clods_bench.plugins.video.tau_model import TAU, TemporalAttentionModule, differential_divergence, lka_kernels


def test_kernel_decomposition_follows_the_tau_rule() -> None:
    assert lka_kernels(21, 3) == (5, 7)  # 5x5 depthwise, then 7x7 with dilation 3: a 23 px receptive field
    assert lka_kernels(9, 3) == (5, 3)


def test_static_attention_is_box_sum_shifted_by_the_dilated_tap_then_scaled() -> None:
    unit = TemporalAttentionModule(dim=1, kernel_size=21)
    with torch.no_grad():
        unit.conv0.weight.fill_(1.0)  # 5x5 box sum, zero padding 2
        unit.conv0.bias.zero_()
        unit.conv_spatial.weight.zero_()
        unit.conv_spatial.weight[0, 0, 0, 0] = 1.0  # top-left tap of a 7x7 kernel with dilation 3 and padding 9
        unit.conv_spatial.bias.zero_()
        unit.conv1.weight.fill_(2.0)
        unit.conv1.bias.fill_(1.0)
    x = np.arange(144, dtype=np.float32).reshape(12, 12) / 100.0
    # By hand: box[y, x] = sum of x over the 5x5 window centred at (y, x) (zeros outside); the tap at (0, 0)
    # of the dilated kernel reads box[y - 9, x - 9]; then 2 * that + 1.
    padded = np.pad(x, 2)
    box = np.array([[padded[i : i + 5, j : j + 5].sum() for j in range(12)] for i in range(12)])
    want = np.ones((12, 12))
    want[9:, 9:] += 2.0 * box[:3, :3]
    got = unit.static(torch.from_numpy(x)[None, None])[0, 0].detach().numpy()
    np.testing.assert_allclose(got, want, rtol=1e-5)


def test_dynamical_attention_gates_channels_from_their_means_and_the_unit_multiplies_three_terms() -> None:
    torch.manual_seed(0)
    unit = TemporalAttentionModule(dim=8)
    x = torch.rand(2, 8, 6, 6)
    gates = unit.dynamical(x)
    assert gates.shape == (2, 8, 1, 1)
    lin1, lin2 = unit.fc[0].weight.detach(), unit.fc[2].weight.detach()
    mean = x.mean(dim=(2, 3))
    want = torch.sigmoid(torch.relu(mean @ lin1.T) @ lin2.T)
    torch.testing.assert_close(gates[:, :, 0, 0], want)
    torch.testing.assert_close(unit(x), unit.static(x) * gates * x)


def brute_force_divergence(pred: np.ndarray, truth: np.ndarray, temperature: float) -> float:
    """Loops over every (batch, channel, pixel): KL of the softmax over the T-1 frame differences, mean over all terms."""
    b, t = pred.shape[:2]
    rest = pred.shape[2:]
    total, count = 0.0, 0
    for i in range(b):
        for idx in np.ndindex(*rest):
            dp = [(pred[(i, k + 1) + idx] - pred[(i, k) + idx]) / temperature for k in range(t - 1)]
            dq = [(truth[(i, k + 1) + idx] - truth[(i, k) + idx]) / temperature for k in range(t - 1)]
            zp, zq = sum(math.exp(v) for v in dp), sum(math.exp(v) for v in dq)
            for k in range(t - 1):
                p, q = math.exp(dp[k]) / zp, math.exp(dq[k]) / zq
                total += p * math.log(p / q)
                count += 1
    return total / count


def test_differential_divergence_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    pred, truth = rng.random((2, 4, 3, 2, 3)), rng.random((2, 4, 3, 2, 3))
    got = differential_divergence(torch.from_numpy(pred), torch.from_numpy(truth), temperature=0.1).item()
    assert got == pytest.approx(brute_force_divergence(pred, truth, 0.1), rel=1e-9)
    assert got > 0.0
    assert differential_divergence(torch.from_numpy(truth), torch.from_numpy(truth)).item() == pytest.approx(0.0, abs=1e-12)
    assert differential_divergence(torch.from_numpy(pred[:, :2]), torch.from_numpy(truth[:, :2])).item() == 0.0  # one difference: nothing to compare


def test_tau_maps_t_frames_to_t_frames() -> None:
    torch.manual_seed(0)
    model = TAU(frames=3, hid_s=8, hid_t=16, enc_layers=4, trans_layers=3, kernel_size=21, mlp_ratio=2.0)
    assert model(torch.rand(2, 3, 3, 16, 12)).shape == (2, 3, 3, 16, 12)
