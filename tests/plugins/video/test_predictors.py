"""Video predictors: copy-last-frame against hand-computed PSNR, SimVP overfitting a moving square, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.interfaces import FitContext, VideoPredictor
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.scoring.image_metrics import psnr
from clods_bench.errors import ClodsError
from clods_bench.plugins.video.copylast import CopyLastPredictor
from clods_bench.plugins.video.simvp import CHECKPOINT_FILE, SimvpConfig, SimvpPredictor
from tests.plugins.video.toys import moving_square


def test_builtins_are_registered_as_video_predictors() -> None:
    reg = default_registry(refresh=True)
    assert {"copylast", "simvp", "tau", "mau", "mmvp"} <= set(reg.names("video_predictor"))
    assert reg.origins[("video_predictor", "simvp")] == "video_predictors"  # the entry-point name
    assert reg.get("video_predictor", "simvp").config_cls is SimvpConfig


def test_unknown_predictor_suggests_the_closest_name() -> None:
    with pytest.raises(ClodsError, match="did you mean 'simvp'"):
        default_registry().get("video_predictor", "simvpp")


def test_copylast_psnr_is_the_hand_computed_value(tmp_path: Path) -> None:
    # Grey level 0.25 everywhere, then 0.75 on one quarter of the image in the next frame:
    # MSE = 0.25 * 0.5^2 = 1/16, PSNR = -10 log10(1/16) = 12.0412 dB.
    video = np.full((3, 8, 8, 3), 0.25, np.float32)
    video[2, :4, :4] = 0.75
    pred = CopyLastPredictor()
    assert isinstance(pred, VideoPredictor)
    assert pred.fit([video], FitContext(tmp_path, 0, False)) == {}
    out = pred.predict(video[None, :2], num_frames=1)
    assert out.shape == (1, 1, 8, 8, 3)
    np.testing.assert_array_equal(out[0, 0], video[1])
    assert psnr(out[0, 0], video[2]) == pytest.approx(10 * np.log10(16), abs=1e-9)


def test_copylast_repeats_every_view_and_rejects_wrong_shapes() -> None:
    ctx = np.random.default_rng(0).random((2, 3, 5, 6, 3)).astype(np.float32)
    out = CopyLastPredictor().predict(ctx, num_frames=4)
    assert out.shape == (2, 4, 5, 6, 3)
    np.testing.assert_array_equal(out, np.repeat(ctx[:, 2:3], 4, axis=1))
    with pytest.raises(ClodsError, match=r"shape \(N,T,H,W,3\)"):
        CopyLastPredictor().predict(ctx[0], num_frames=2)  # one view without the view axis
    with pytest.raises(ClodsError, match="NaN"):
        CopyLastPredictor().predict(np.full((1, 2, 4, 4, 3), np.nan, np.float32), num_frames=1)


TINY_SIMVP = SimvpConfig(
    context_frames=2, hid_s=8, hid_t=32, enc_layers=2, trans_layers=2, kernels=[3, 5], groups=2,
    train_steps=120, batch_size=4, learning_rate=3e-3, checkpoint_every=0, num_threads=1,
)  # fmt: skip


def test_simvp_overfits_a_moving_square_and_predicts_its_shape(tmp_path: Path) -> None:
    video = moving_square()
    pred = SimvpPredictor(TINY_SIMVP, seed=0, progress=False)
    stats = pred.fit([video], FitContext(tmp_path, 0, False))
    assert stats["final_loss"] < stats["initial_loss"] / 20, stats
    assert (tmp_path / CHECKPOINT_FILE).is_file()
    # From frames 6,7 predict 8,9: the square must sit at columns 8..11 and 9..12, nowhere else.
    out = pred.predict(video[None, 6:8], num_frames=3)
    assert out.shape == (1, 3, 16, 16, 3)
    for k in range(2):
        truth = video[8 + k] > 0.5
        got = out[0, k] > 0.5
        iou = (truth & got).sum() / (truth | got).sum()
        assert iou > 0.8, (k, iou)
        assert psnr(out[0, k], video[8 + k]) > 18.0
    # The copy-last baseline misses the moved column on both sides: SimVP must beat it clearly.
    assert psnr(out[0, 0], video[8]) > psnr(video[7], video[8]) + 5.0


def test_simvp_resumes_from_its_checkpoint(tmp_path: Path) -> None:
    video = moving_square(frames=8)
    cfg = SimvpConfig(**{**TINY_SIMVP.__dict__, "train_steps": 6})
    first = SimvpPredictor(cfg, seed=0, progress=False)
    first.fit([video], FitContext(tmp_path, 0, False))
    again = SimvpPredictor(cfg, seed=0, progress=False)
    stats = again.fit([video], FitContext(tmp_path, 0, False))  # nothing left to train: the weights are the saved ones
    ctx = video[None, :2]
    np.testing.assert_allclose(again.predict(ctx, 2), first.predict(ctx, 2), atol=1e-6)
    assert stats["train_steps"] == 6
    other = SimvpPredictor(SimvpConfig(**{**cfg.__dict__, "hid_s": 4}), seed=0, progress=False)
    with pytest.raises(ClodsError, match="another config"):
        other.fit([video], FitContext(tmp_path, 0, False))


def test_simvp_bad_input_is_a_clear_error(tmp_path: Path) -> None:
    ctx = FitContext(tmp_path, 0, False)
    with pytest.raises(ClodsError, match="shorter than one training window"):
        SimvpPredictor(TINY_SIMVP, progress=False).fit([moving_square(frames=3)], ctx)
    with pytest.raises(ClodsError, match="different frame sizes"):
        SimvpPredictor(TINY_SIMVP, progress=False).fit([moving_square(size=16), moving_square(size=20)], ctx)
    with pytest.raises(ClodsError, match="cannot be downsampled"):
        SimvpPredictor(TINY_SIMVP, progress=False).fit([np.zeros((6, 15, 15, 3), np.float32)], ctx)
    with pytest.raises(ClodsError, match=r"expected a video of shape \(T,H,W,3\)"):
        SimvpPredictor(TINY_SIMVP, progress=False).fit([np.zeros((6, 16, 16), np.float32)], ctx)
    with pytest.raises(ClodsError, match="before fit"):
        SimvpPredictor(TINY_SIMVP, progress=False).predict(np.zeros((1, 2, 16, 16, 3), np.float32), 1)
    with pytest.raises(ClodsError, match="video_config.simvp.kernels"):
        SimvpPredictor(SimvpConfig(kernels=[4]))
