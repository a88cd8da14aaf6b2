"""TAU: the attention against hand computations, the differential divergence (value against a brute-force evaluation of
the authors' formula, gradient by torch.autograd.gradcheck), stochastic depth, OpenSTL's initialisation, parameter
count at the ci widths and one float64 output pinned against committed values (both equal to OpenSTL's with the same
weights: examples/studies/video_same_weights.py, results/studies/video_same_weights/)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import torch_threads
from clods_bench.plugins.video.tau import TauConfig, TauPredictor
from clods_bench.plugins.video.tau_blocks import DropPath, TemporalAttentionModule, drop_path_rates, lka_kernels
from clods_bench.plugins.video.tau_model import TAU, differential_divergence
from tests.plugins.video.fingerprint import assert_summary, fixed_input, set_weights, summary

CI = TauConfig(context_frames=5, hid_s=16, hid_t=52, enc_layers=4, trans_layers=4)
"""The ci preset's TAU widths (clods_bench/benchmark/core/presets/ci.yaml)."""


def test_kernel_decomposition_follows_the_tau_rule() -> None:
    assert lka_kernels(21, 3) == (5, 7)  # 5x5 depthwise, then 7x7 with dilation 3: a 23 px receptive field
    assert lka_kernels(9, 3) == (5, 3)


def test_static_attention_is_box_sum_shifted_by_the_dilated_tap_then_scaled() -> None:
    unit = TemporalAttentionModule(dim=4, kernel_size=21)
    with torch.no_grad():
        unit.conv0.weight.fill_(1.0)  # 5x5 box sum, zero padding 2
        unit.conv0.bias.zero_()
        unit.conv_spatial.weight.zero_()
        unit.conv_spatial.weight[:, 0, 0, 0] = 1.0  # top-left tap of a 7x7 kernel with dilation 3 and padding 9
        unit.conv_spatial.bias.zero_()
        unit.conv1.weight.zero_()
        unit.conv1.weight[0, 0] = 2.0
        unit.conv1.bias.fill_(1.0)
    x = np.arange(144, dtype=np.float32).reshape(12, 12) / 100.0
    # By hand: box[y, x] = sum of x over the 5x5 window centred at (y, x) (zeros outside); the tap at (0, 0)
    # of the dilated kernel reads box[y - 9, x - 9]; then 2 * that + 1.
    padded = np.pad(x, 2)
    box = np.array([[padded[i : i + 5, j : j + 5].sum() for j in range(12)] for i in range(12)])
    want = np.ones((12, 12))
    want[9:, 9:] += 2.0 * box[:3, :3]
    got = unit.static(torch.from_numpy(x)[None, None].repeat(1, 4, 1, 1))[0, 0].detach().numpy()
    np.testing.assert_allclose(got, want, rtol=1e-5)


def test_dynamical_attention_gates_channels_from_their_means_and_the_unit_multiplies_three_terms() -> None:
    torch.manual_seed(0)
    unit = TemporalAttentionModule(dim=64)
    assert unit.fc[0].out_features == 16  # OpenSTL's squeeze: dim // max(dim // 16, 4)
    x = torch.rand(2, 64, 6, 6)
    gates = unit.dynamical(x)
    assert gates.shape == (2, 64, 1, 1)
    lin1, lin2 = unit.fc[0].weight.detach(), unit.fc[2].weight.detach()
    want = torch.sigmoid(torch.relu(x.mean(dim=(2, 3)) @ lin1.T) @ lin2.T)
    torch.testing.assert_close(gates[:, :, 0, 0], want)
    torch.testing.assert_close(unit(x), unit.static(x) * gates * x)


def brute_force_divergence(pred: np.ndarray, truth: np.ndarray, temperature: float, eps: float = 1e-12) -> float:
    """The authors' formula term by term: for each video and frame difference, softmax over all C*H*W values of
    difference / temperature (p for the prediction, q for the truth), p * log(p / (q + eps) + eps); mean of all terms."""
    b, t = pred.shape[:2]
    total, count = 0.0, 0
    for i in range(b):
        for k in range(t - 1):
            dp = ((pred[i, k + 1] - pred[i, k]) / temperature).ravel().tolist()
            dq = ((truth[i, k + 1] - truth[i, k]) / temperature).ravel().tolist()
            zp, zq = sum(math.exp(v) for v in dp), sum(math.exp(v) for v in dq)
            for vp, vq in zip(dp, dq):
                p, q = math.exp(vp) / zp, math.exp(vq) / zq
                total += p * math.log(p / (q + eps) + eps)
                count += 1
    return total / count


def test_differential_divergence_is_the_authors_formula() -> None:
    rng = np.random.default_rng(0)
    pred, truth = rng.random((2, 4, 3, 2, 3)), rng.random((2, 4, 3, 2, 3))
    got = differential_divergence(torch.from_numpy(pred), torch.from_numpy(truth), temperature=0.1).item()
    assert got == pytest.approx(brute_force_divergence(pred, truth, 0.1), rel=1e-9)
    assert got > 0.0
    assert differential_divergence(torch.from_numpy(truth), torch.from_numpy(truth)).item() == pytest.approx(0.0, abs=1e-11)
    assert differential_divergence(torch.from_numpy(pred[:, :2]), torch.from_numpy(truth[:, :2])).item() == 0.0  # T <= 2: 0, as theirs
    # The softmax runs over each difference's pixels, not over time: shifting one whole difference by a constant
    # leaves it unchanged (a softmax over time would move).
    shifted = pred.copy()
    shifted[:, 2:] += 0.3
    assert differential_divergence(torch.from_numpy(shifted), torch.from_numpy(truth)).item() == pytest.approx(got, rel=1e-12)


def test_differential_divergence_gradient_matches_finite_differences() -> None:
    rng = np.random.default_rng(1)
    pred = torch.from_numpy(rng.random((2, 3, 2, 2, 2))).requires_grad_(True)
    truth = torch.from_numpy(rng.random((2, 3, 2, 2, 2)))
    assert torch.autograd.gradcheck(lambda p: differential_divergence(p, truth, 0.1), (pred,), eps=1e-6, atol=1e-9, rtol=1e-6)


def test_stochastic_depth_rates_and_masks() -> None:
    assert drop_path_rates(4, 0.0) == pytest.approx([0.01, 0.02 / 3, 0.01 / 3, 0.0], rel=1e-6)  # OpenSTL: linspace(0.01, 0), last = drop_path
    assert drop_path_rates(3, 0.2) == pytest.approx([0.01, 0.105, 0.2], rel=1e-6)
    drop = DropPath(0.25)
    x = torch.ones(4000, 2, 3, 3)
    assert torch.equal(drop.eval()(x), x)
    torch.manual_seed(0)
    y = drop.train()(x)
    kept = y[:, 0, 0, 0] > 0
    assert torch.all(y[kept] == 1 / 0.75) and torch.all(y[~kept] == 0)  # whole samples dropped, the rest scaled by 1/keep
    assert abs(kept.double().mean().item() - 0.75) < 0.03


def test_initialisation_is_openstls() -> None:
    torch.manual_seed(0)
    model = TAU(frames=5, hid_s=64, hid_t=256, enc_layers=4, trans_layers=2, kernel_size=21, mlp_ratio=8.0)
    enc = torch.cat([layer.conv.weight.flatten() for layer in model.enc])
    assert enc.std().item() == pytest.approx(0.02, rel=0.03) and enc.abs().max().item() < 0.15  # trunc normal, std 0.02
    assert all(float(layer.conv.bias.detach().abs().max()) == 0.0 for layer in model.enc)
    fc1 = model.translator[0].mlp.fc1  # VAN's rule: std sqrt(2 / fan_out), fan_out = 1 * 1 * 2560
    assert fc1.weight.std().item() == pytest.approx(math.sqrt(2 / 2560), rel=0.03)
    block = model.translator[0]
    assert torch.all(block.layer_scale_1 == 0.01) and torch.all(block.layer_scale_2 == 0.01)
    bound = 1 / math.sqrt(320)  # the attention's 1x1 convs keep PyTorch's default: U(-1/sqrt(fan_in), 1/sqrt(fan_in))
    assert block.attn.proj_1.weight.abs().max().item() <= bound and block.attn.proj_1.weight.std().item() == pytest.approx(bound / math.sqrt(3), rel=0.05)


def test_structure_and_parameter_count_at_ci_widths() -> None:
    model = TauPredictor(CI).build_model()
    assert [type(layer.act) for layer in model.enc] == [nn.SiLU] * 4
    assert [layer.conv.stride[0] for layer in model.enc] == [1, 2, 1, 2]
    assert [isinstance(layer.conv, nn.Sequential) for layer in model.dec] == [True, False, True, False]  # conv + PixelShuffle
    assert [b.drop_path.p for b in model.translator] == pytest.approx(drop_path_rates(4, 0.0))
    assert sum(p.numel() for p in model.parameters()) == 362_775  # OpenSTL's count at these widths


def test_float64_output_is_the_committed_one() -> None:
    model = set_weights(TauPredictor(CI).build_model())
    with torch_threads(1), torch.no_grad():
        out = model(fixed_input((1, 5, 3, 32, 32)))
    assert out.shape == (1, 5, 3, 32, 32)
    assert_summary(summary(out), [-2723.7910348846926, 4147.428375941969, -1.350370221987621])


def test_config_errors_name_the_field() -> None:
    with pytest.raises(ClodsError, match="must be even") as e:
        TauPredictor(TauConfig(enc_layers=3))
    assert e.value.where == "video_config.tau.enc_layers"
    with pytest.raises(ClodsError, match="drop_path in"):
        TauPredictor(TauConfig(drop_path=1.0))
