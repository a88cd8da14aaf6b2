"""MAU: attention weights over the window sum to one and follow the spatial similarity; shapes; scheduled sampling."""

from __future__ import annotations

import torch

from clods_bench.plugins.video.mau_model import MAU, MAUCell


def test_attention_weights_sum_to_one_over_the_window() -> None:
    torch.manual_seed(0)
    cell = MAUCell(channels=4, kernel=3, tau=5)
    weights = cell.attention(torch.randn(3, 4, 6, 6), torch.randn(5, 3, 4, 6, 6))
    assert weights.shape == (5, 3)
    torch.testing.assert_close(weights.sum(dim=0), torch.ones(3))
    assert (weights > 0).all()


def test_attention_prefers_the_previous_state_most_like_the_current_one() -> None:
    torch.manual_seed(0)
    cell = MAUCell(channels=4, kernel=3, tau=3)
    s_now = torch.randn(1, 4, 6, 6)
    query = cell.conv_s_next(s_now).detach()
    s_prev = torch.stack([-query, torch.zeros_like(query), 3 * query])  # anti-aligned, orthogonal, aligned
    weights = cell.attention(s_now, s_prev)[:, 0]
    assert weights[2] > 0.99 and weights[0] < weights[1] < weights[2]


def test_cell_and_model_shapes() -> None:
    torch.manual_seed(0)
    cell = MAUCell(channels=4, kernel=3, tau=2)
    t_new, s_new = cell(torch.randn(2, 4, 5, 5), torch.randn(2, 4, 5, 5), torch.randn(2, 2, 4, 5, 5), torch.randn(2, 2, 4, 5, 5))
    assert t_new.shape == s_new.shape == (2, 4, 5, 5)
    model = MAU(hidden=4, num_layers=2, kernel=3, tau=2, downsamples=2)
    assert model(torch.rand(2, 3, 3, 16, 8), future=4).shape == (2, 6, 3, 16, 8)  # frames 1..6


def test_scheduled_sampling_feeds_the_true_frames_where_asked() -> None:
    torch.manual_seed(0)
    model = MAU(hidden=4, num_layers=1, kernel=3, tau=2, downsamples=1).eval()
    video = torch.rand(1, 6, 3, 8, 8)
    teacher = model(video[:, :3], 3, truth=video[:, 3:], use_truth=torch.ones(1, 2, dtype=torch.bool))
    forced = model(video[:, :5], 1)  # reading all five true frames: the same computation
    torch.testing.assert_close(teacher, forced)
    free = model(video[:, :3], 3, truth=video[:, 3:], use_truth=torch.zeros(1, 2, dtype=torch.bool))
    torch.testing.assert_close(free, model(video[:, :3], 3))
    assert not torch.allclose(free[:, 3:], teacher[:, 3:])
