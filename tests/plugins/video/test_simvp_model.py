"""SimVP (v1): the authors' structure (translator U-Net, concatenated skip, strides), parameter count at the ci
widths and one float64 output pinned against committed values (both equal to A4Bio/SimVP's with the same weights:
examples/studies/video_same_weights.py, results/studies/video_same_weights/)."""

from __future__ import annotations

import pytest
import torch

from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import torch_threads
from clods_bench.plugins.video.simvp import SimvpConfig, SimvpPredictor
from clods_bench.plugins.video.simvp_model import SimVP, Translator
from tests.plugins.video.fingerprint import assert_summary, fixed_input, set_weights, summary

CI = SimvpConfig(context_frames=5, hid_s=16, hid_t=64, enc_layers=4, trans_layers=4, kernels=[3, 5, 7], groups=4)
"""The ci preset's SimVP widths (clods_bench/benchmark/core/presets/ci.yaml)."""


def test_translator_is_simvp_v1s_unet() -> None:
    t = Translator(channels=40, hidden=32, num_layers=4, kernels=(3, 5), groups=4)
    assert [b.conv1.in_channels for b in t.enc] == [40, 32, 32, 32]
    assert [b.conv1.in_channels for b in t.dec] == [32, 64, 64, 64]  # the first decoder block takes the encoder's output alone
    assert [b.branches[0].conv.out_channels for b in t.dec] == [32, 32, 32, 40]
    assert all(b.conv1.out_channels == 16 for b in [*t.enc, *t.dec])  # Inception blocks work at hidden / 2
    assert t.enc[0].branches[1].conv.groups == 4 and t.enc[0].branches[1].conv.kernel_size == (5, 5)


def test_structure_and_parameter_count_at_ci_widths() -> None:
    model = SimvpPredictor(CI).build_model()
    assert isinstance(model, SimVP)
    assert [layer.conv.stride[0] for layer in model.enc] == [1, 2, 1, 2]
    assert [type(layer.conv).__name__ for layer in model.dec] == ["ConvTranspose2d", "Conv2d", "ConvTranspose2d", "Conv2d"]
    assert model.dec[-1].conv.in_channels == 32  # decoded features concatenated with the first encoder layer's
    assert sum(p.numel() for p in model.parameters()) == 397_939  # A4Bio/SimVP's count at these widths


def test_float64_output_is_the_committed_one() -> None:
    model = set_weights(SimvpPredictor(CI).build_model())
    with torch_threads(1), torch.no_grad():
        out = model(fixed_input((1, 5, 3, 32, 32)))
    assert out.shape == (1, 5, 3, 32, 32)
    assert_summary(summary(out), [-1425.8971301364957, 3755.7640220854555, -56.49110949966753])


def test_groups_must_divide_the_widths() -> None:
    with pytest.raises(ClodsError, match="not divisible by the 4 Inception groups") as e:
        SimvpPredictor(SimvpConfig(hid_s=6, hid_t=64, groups=4, context_frames=5))
    assert e.value.where == "video_config.simvp.groups"
    with pytest.raises(ClodsError, match="must be >= 2"):
        SimvpPredictor(SimvpConfig(trans_layers=1))
