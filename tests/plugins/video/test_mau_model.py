"""MAU: attention weights over the window, shapes, scheduled sampling inside the network, the training schedule
against the authors' loop, parameter count at the ci widths and one float64 output pinned against committed values
(both equal to the authors' and OpenSTL's with the same weights: examples/studies/video_same_weights.py,
results/studies/video_same_weights/)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import torch_threads
from clods_bench.plugins.video.mau import MauConfig, MauPredictor
from clods_bench.plugins.video.mau_model import MAU, MAUCell
from tests.plugins.video.fingerprint import assert_summary, fixed_input, set_weights, summary

CI = MauConfig(context_frames=5, hidden=14, num_layers=4, kernel=3, downsamples=2, train_steps=250, batch_size=8, learning_rate=1e-3)
"""The ci preset's MAU widths (clods_bench/benchmark/core/presets/ci.yaml), trained 250 steps: a length whose schedule
the test below works out by hand."""


def test_attention_weights_sum_to_one_over_the_window() -> None:
    torch.manual_seed(0)
    cell = MAUCell(channels=4, kernel=3, tau=5, size=(6, 6))
    weights = cell.attention(torch.randn(3, 4, 6, 6), torch.randn(5, 3, 4, 6, 6))
    assert weights.shape == (5, 3)
    torch.testing.assert_close(weights.sum(dim=0), torch.ones(3))
    assert (weights > 0).all()


def test_attention_prefers_the_previous_state_most_like_the_current_one() -> None:
    torch.manual_seed(0)
    cell = MAUCell(channels=4, kernel=3, tau=3, size=(6, 6))
    s_now = torch.randn(1, 4, 6, 6)
    query = cell.conv_s_next(s_now).detach()
    s_prev = torch.stack([-query, torch.zeros_like(query), 3 * query])  # anti-aligned, orthogonal, aligned
    weights = cell.attention(s_now, s_prev)[:, 0]
    assert weights[2] > 0.99 and weights[0] < weights[1] < weights[2]


def test_cell_and_model_shapes_and_the_layer_norms_over_c_h_w() -> None:
    torch.manual_seed(0)
    cell = MAUCell(channels=4, kernel=3, tau=2, size=(5, 5))
    t_new, s_new = cell(torch.randn(2, 4, 5, 5), torch.randn(2, 4, 5, 5), torch.randn(2, 2, 4, 5, 5), torch.randn(2, 2, 4, 5, 5))
    assert t_new.shape == s_new.shape == (2, 4, 5, 5)
    assert cell.conv_t[1].normalized_shape == (12, 5, 5) and cell.conv_s_next[1].weight.shape == (4, 5, 5)
    model = MAU(hidden=4, num_layers=2, kernel=3, tau=2, downsamples=2, image_size=(16, 8))
    assert model(torch.rand(2, 3, 3, 16, 8), future=4).shape == (2, 6, 3, 16, 8)  # frames 1..6


def test_scheduled_sampling_feeds_the_true_frames_where_asked() -> None:
    torch.manual_seed(0)
    model = MAU(hidden=4, num_layers=1, kernel=3, tau=2, downsamples=1, image_size=(8, 8)).eval()
    video = torch.rand(1, 6, 3, 8, 8)
    teacher = model(video[:, :3], 3, truth=video[:, 3:], use_truth=torch.ones(1, 2, dtype=torch.bool))
    forced = model(video[:, :5], 1)  # reading all five true frames: the same computation
    torch.testing.assert_close(teacher, forced)
    free = model(video[:, :3], 3, truth=video[:, 3:], use_truth=torch.zeros(1, 2, dtype=torch.bool))
    torch.testing.assert_close(free, model(video[:, :3], 3))
    assert not torch.allclose(free[:, 3:], teacher[:, 3:])


def test_schedule_is_the_authors_at_their_length() -> None:
    """ZhengChang467/MAU: before iteration itr (from 0) eta -= 2e-5 while itr < 50000, else eta = 0; after the step of
    itr the learning rate is x0.9 when itr >= 50000 and itr % 2000 == 0; 80,000 iterations."""
    pred = MauPredictor(dataclasses.replace(CI, train_steps=80_000))
    eta, lr, worst_eta, worst_lr = 1.0, 1.0, 0.0, 0.0
    for itr in range(80_001):
        eta = eta - 0.00002 if itr < 50_000 else 0.0
        worst_eta = max(worst_eta, abs(pred.truth_probability(itr) - eta))
        worst_lr = max(worst_lr, abs(pred.lr_factor(itr) - lr) / lr)
        if itr >= 50_000 and itr % 2000 == 0:
            lr *= 0.9
    assert worst_eta < 1e-9 and worst_lr < 1e-12  # eta: the loop's own rounding (80,000 subtractions)


def test_schedule_at_250_steps_and_the_optimizer_follows_it() -> None:
    pred = MauPredictor(CI)  # S = 0.625 * 250 = 156.25, D = 0.025 * 250 = 6.25
    assert pred.truth_probability(0) == pytest.approx(1 - 1 / 156.25)
    assert pred.truth_probability(155) == pytest.approx(1 - 156 / 156.25) and pred.truth_probability(156) == 0.0
    assert [pred.lr_factor(k) for k in (0, 156, 157, 162, 163, 169, 249)] == pytest.approx([1, 1, 0.9, 0.9, 0.81, 0.729, 0.9**15])
    model = torch.nn.Linear(2, 2)
    opt, sched = pred.optimizer(model)
    assert isinstance(opt, torch.optim.Adam) and opt.defaults["weight_decay"] == 0
    seen = []
    for _ in range(250):
        seen.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    np.testing.assert_allclose(seen, [1e-3 * pred.lr_factor(k) for k in range(250)], rtol=1e-12)
    assert MauPredictor(dataclasses.replace(CI, scheduled_sampling=False)).truth_probability(0) == 0.0


def test_structure_and_parameter_count_at_ci_widths() -> None:
    pred = MauPredictor(CI)
    with pytest.raises(ClodsError, match="fit sets it"):
        pred.build_model()
    pred.size = (64, 64)
    # The authors' count at these widths is 293,912: 427 more, in two 1x1 convs their forward never calls.
    assert sum(p.numel() for p in pred.build_model().parameters()) == 293_485


def test_float64_output_is_the_committed_one() -> None:
    pred = MauPredictor(CI)
    pred.size = (32, 32)
    model = set_weights(pred.build_model())
    with torch_threads(1), torch.no_grad():
        out = model(fixed_input((1, 5, 3, 32, 32)), 5)
    assert out.shape == (1, 9, 3, 32, 32)
    assert_summary(summary(out), [-1981.5998882654874, 879.7271086030536, 24.24988911971938])
