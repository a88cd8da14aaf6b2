"""The shared window trainer, for every learned predictor: output shapes, one step lowers the loss, an interrupted
run resumed from its checkpoint ends with the uninterrupted run's weights, too many context frames is one clear error."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from clods_bench.benchmark.core.interfaces import FitContext, VideoPredictor
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.errors import ClodsError
from clods_bench.plugins.video.mau import MauConfig, MauPredictor
from clods_bench.plugins.video.mmvp import MmvpConfig, MmvpPredictor
from clods_bench.plugins.video.simvp import SimvpConfig, SimvpPredictor
from clods_bench.plugins.video.tau import TauConfig, TauPredictor
from clods_bench.plugins.video.trainer import WindowPredictor
from tests.plugins.video.toys import moving_square

COMMON: dict[str, Any] = {"context_frames": 3, "batch_size": 4, "learning_rate": 3e-3, "checkpoint_every": 0, "num_threads": 1, "train_steps": 6}
TINY: dict[str, Any] = {
    "simvp": SimvpConfig(hid_s=8, hid_t=16, enc_layers=2, trans_layers=2, kernels=[3], groups=2, **COMMON),
    "tau": TauConfig(hid_s=8, hid_t=16, enc_layers=2, trans_layers=2, kernel_size=9, mlp_ratio=2.0, **COMMON),
    "mau": MauConfig(hidden=8, num_layers=2, kernel=3, tau=2, downsamples=1, **COMMON),
    "mmvp": MmvpConfig(channels=4, predictor_channels=2, encoder_blocks=1, decoder_blocks=1, enhancer_blocks=1, **COMMON),
}
CLASSES: dict[str, type[WindowPredictor[Any]]] = {"simvp": SimvpPredictor, "tau": TauPredictor, "mau": MauPredictor, "mmvp": MmvpPredictor}
NAMES = sorted(TINY)


def make(name: str, **changes: Any) -> WindowPredictor[Any]:
    """A tiny predictor of this kind, with config fields changed."""
    return CLASSES[name](dataclasses.replace(TINY[name], **changes), seed=0, progress=False)


@pytest.mark.parametrize("name", ["tau", "mau", "mmvp"])
def test_registered_with_their_config(name: str) -> None:
    spec = default_registry().get("video_predictor", name)
    assert spec.config_cls is type(TINY[name]) and spec.learned


@pytest.mark.parametrize("name", NAMES)
def test_fit_and_predict_shapes(name: str, tmp_path: Path) -> None:
    pred = make(name, train_steps=2)
    assert isinstance(pred, VideoPredictor)
    stats = pred.fit([moving_square(frames=8)], FitContext(tmp_path, 0, False))
    assert stats["train_windows"] == 3 and stats["parameters"] > 0
    context = np.random.default_rng(0).random((2, 4, 16, 16, 3)).astype(np.float32)
    for frames in (1, 3, 7):  # shorter than, equal to and longer than one block of context_frames
        out = pred.predict(context, frames)
        assert out.shape == (2, frames, 16, 16, 3) and out.dtype == np.float32
        assert np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0


@pytest.mark.parametrize("name", NAMES)
def test_one_training_step_lowers_the_loss_on_a_moving_square(name: str) -> None:
    pred = make(name)
    pred.size = (16, 16)  # set by fit (MAU's layer norms are built for one size)
    torch.manual_seed(0)
    model = pred.build_model().train()
    video = torch.from_numpy(moving_square().transpose(0, 3, 1, 2))
    window = torch.stack([video[s : s + 6] for s in (0, 3, 6, 8)])
    rng = np.random.default_rng(0)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    before = pred.loss(model, window, 0, rng)
    opt.zero_grad()
    before.backward()
    opt.step()
    after = pred.loss(model, window, 1, rng)
    assert after.item() < before.item(), (before.item(), after.item())


class Interrupt(Exception):
    """Raised by the patched checkpoint writer to stop a run after its first checkpoint."""


@pytest.mark.parametrize("name", NAMES)
def test_resumed_run_ends_with_the_uninterrupted_weights(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    videos = [moving_square(frames=9), moving_square(frames=8, y0=2)]
    whole = make(name, checkpoint_every=3)
    whole.fit(videos, FitContext(tmp_path / "whole", 0, False))

    save = WindowPredictor._save

    def save_then_stop(self: WindowPredictor[Any], path: Path, digest: str, step: int, *rest: Any) -> None:
        save(self, path, digest, step, *rest)
        raise Interrupt(step)

    with monkeypatch.context() as patch:
        patch.setattr(WindowPredictor, "_save", save_then_stop)
        with pytest.raises(Interrupt, match="3"):
            make(name, checkpoint_every=3).fit(videos, FitContext(tmp_path / "cut", 0, False))
    resumed = make(name, checkpoint_every=3)
    steps: list[int] = []
    loss = resumed.loss
    monkeypatch.setattr(resumed, "loss", lambda model, window, step, rng: steps.append(step) or loss(model, window, step, rng))
    resumed.fit(videos, FitContext(tmp_path / "cut", 0, False))
    assert steps == [3, 4, 5]  # only the steps after the checkpoint ran
    assert whole.model is not None and resumed.model is not None
    a, b = whole.model.state_dict(), resumed.model.state_dict()
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key


@pytest.mark.parametrize("name", NAMES)
def test_more_context_frames_than_the_observed_video_is_one_clear_error(name: str, tmp_path: Path) -> None:
    pred = make(name, context_frames=16)
    with pytest.raises(ClodsError, match=rf"video_config\.{name}\.context_frames: 16 context frames need training videos of 2 x 16 = 32 frames; the longest has 31"):
        pred.fit([moving_square(frames=31), moving_square(frames=20)], FitContext(tmp_path, 0, False))
    ok = make(name, train_steps=1)
    ok.fit([moving_square(frames=8)], FitContext(tmp_path / "ok", 0, False))
    with pytest.raises(ClodsError, match=rf"video_config\.{name}\.context_frames: needs 3 context frames, got 2"):
        ok.predict(np.zeros((1, 2, 16, 16, 3), np.float32), 1)


@pytest.mark.parametrize("name", NAMES)
def test_bad_sizes_and_checkpoints_are_clear_errors(name: str, tmp_path: Path) -> None:
    with pytest.raises(ClodsError, match="cannot be downsampled"):
        make(name).fit([np.zeros((8, 15, 15, 3), np.float32)], FitContext(tmp_path, 0, False))
    (tmp_path / f"{name}.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ClodsError, match=f"unreadable {CLASSES[name].label} checkpoint"):
        make(name).fit([moving_square(frames=8)], FitContext(tmp_path, 0, False))


@pytest.mark.parametrize("name", NAMES)
def test_device_option_is_checked_and_not_part_of_the_checkpoint_identity(name: str, tmp_path: Path) -> None:
    from clods_bench.plugins.video.trainer import config_digest

    video = [moving_square(frames=8)]
    assert config_digest(name, dataclasses.replace(TINY[name], device="cuda"), video) == config_digest(name, TINY[name], video)
    for bad in ("gpu", "cuda:x"):
        with pytest.raises(ClodsError) as e:
            make(name, device=bad)
        assert e.value.where == f"video_config.{name}.device"
    if not torch.cuda.is_available():
        with pytest.raises(ClodsError, match="torch sees no CUDA GPU"):
            make(name, device="cuda").fit(video, FitContext(tmp_path, 0, False))
        assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("name", NAMES)
def test_training_and_prediction_on_a_gpu_match_the_cpu(name: str, tmp_path: Path, monkeypatch) -> None:
    """Same seed and windows on the CPU and on CUDA: losses agree to 1e-3 and 5-step predictions to 1e-3. TF32 is
    switched off for the comparison: with PyTorch's default (cuDNN convolutions in TF32) SimVP, TAU and MMVP
    predicted up to 3.3e-3 apart after 20 steps on an H200; with it off TAU, MAU and MMVP agreed within 1e-4 and
    SimVP within 3.1e-4 (float32 summation order of cuDNN's convolutions, compounded over 5 autoregressive steps)."""
    if not torch.cuda.is_available():
        pytest.skip("the CPU/GPU agreement of a predictor needs a CUDA GPU (torch.cuda.is_available() is False); ran on an H200, README 'On a GPU'")
    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", False)
    monkeypatch.setattr(torch.backends.cuda.matmul, "allow_tf32", False)
    video = [moving_square(frames=8)]
    cpu, gpu = make(name), make(name, device="cuda")
    s_cpu = cpu.fit(video, FitContext(tmp_path / "cpu", 0, False))
    s_gpu = gpu.fit(video, FitContext(tmp_path / "gpu", 0, False))
    assert s_gpu["final_loss"] == pytest.approx(s_cpu["final_loss"], rel=1e-3)
    context = np.random.default_rng(0).random((2, 4, 16, 16, 3)).astype(np.float32)
    np.testing.assert_allclose(gpu.predict(context, 5), cpu.predict(context, 5), atol=1e-3)
