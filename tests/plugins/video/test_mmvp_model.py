"""MMVP: the motion matrix of a feature map shifted by one pixel recovers the shift, and composing with it moves
the features; the matrix predictor and the model keep their shapes."""

from __future__ import annotations

import torch

from clods_bench.plugins.video.mmvp_model import MMVP, MatrixPredictor, compose, motion_matrix


def test_motion_matrix_of_a_one_pixel_shift_recovers_the_shift_and_composition_applies_it() -> None:
    torch.manual_seed(0)
    h, w = 5, 6
    feats = torch.randn(1, 16, h, w)
    shifted = torch.roll(feats, shifts=1, dims=3)  # every feature moves one pixel right (wrapping round)
    matrix = motion_matrix(feats, shifted)
    assert matrix.shape == (1, h * w, h * w)
    assert matrix.abs().max() <= 1.0 + 1e-5  # cosine similarities
    source = matrix[0].argmax(dim=0)  # for each target position, the most similar source position
    ys, xs = torch.div(torch.arange(h * w), w, rounding_mode="floor"), torch.arange(h * w) % w
    torch.testing.assert_close(source, ys * w + (xs - 1) % w)
    moved = compose(matrix, feats, temperature=0.01)
    torch.testing.assert_close(moved, shifted, atol=1e-3, rtol=0)
    assert not torch.allclose(moved, feats, atol=0.5)


def test_composition_weights_are_a_softmax_over_sources() -> None:
    feats = torch.tensor([[[[1.0, 3.0]]]])  # (1,1,1,2): two source positions
    logits = torch.tensor([[[0.0, 2.0], [0.0, 0.0]]])  # target 0: equal weights; target 1: e^2 : 1 towards source 0
    out = compose(logits, feats)
    e = torch.exp(torch.tensor(2.0))
    torch.testing.assert_close(out[0, 0, 0], torch.stack([torch.tensor(2.0), (e * 1.0 + 3.0) / (e + 1.0)]))


def test_predictor_and_model_shapes() -> None:
    torch.manual_seed(0)
    pred = MatrixPredictor(past=2, future=3, hidden=4)
    assert pred(torch.rand(2, 2, 12, 12), 3, 4).shape == (2, 3, 12, 12)
    model = MMVP(frames=3, hid_s=8, motion_channels=4, predictor_hidden=4, enc_layers=4)
    assert model(torch.rand(2, 3, 3, 16, 12)).shape == (2, 3, 3, 16, 12)
