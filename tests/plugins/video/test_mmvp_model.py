"""The MMVP network keeps its structure: parameter count at the ci preset's widths, one fixed-seed float64 output
(proven equal to the authors' code with the same weights by examples/studies/mmvp_same_weights.py, which wrote
results/studies/mmvp_same_weights/), frames after the first P change nothing in eval mode, and bad options are
clear errors."""

from __future__ import annotations

import pytest
import torch

from clods_bench.benchmark.core.config import load_config
from clods_bench.errors import ClodsError
from clods_bench.plugins.video.mmvp import MmvpConfig, MmvpPredictor
from clods_bench.plugins.video.mmvp_model import MMVP
from clods_bench.plugins.video.mmvp_predictor import MatrixPredictor

CI_PARAMETERS = 151_381
"""Parameters of MMVP at the ci preset's widths (context 5, channels 8, predictor 4, one RRDB per place)."""
CI_OUTPUT = {"sum": 14994.323825416699, "sum_sq": 9175.218534068514, "probe": 0.6047341494767355}
"""Eval-mode prediction of the seed-0 ci-width network (float64) from the seed-1 frames below."""
CI_TRAIN_OUTPUT = {"sum": 14991.029439254646, "sum_sq": 9173.328650054726, "probe": 0.6042921706239193}
"""The same network in train mode (BatchNorm batch statistics) from the whole 10-frame window."""


def ci_network() -> MMVP:
    cfg = MmvpConfig(**load_config("ci").video_config["mmvp"])
    torch.manual_seed(0)
    return MmvpPredictor(cfg, seed=0, progress=False).build_model().double()


def summary(out: torch.Tensor) -> dict[str, float]:
    return {"sum": out.sum().item(), "sum_sq": out.square().sum().item(), "probe": out[0, -1, 1, 37, 20].item()}


def test_parameter_count_at_the_ci_widths() -> None:
    assert sum(p.numel() for p in ci_network().parameters()) == CI_PARAMETERS


def test_fixed_seed_output_at_the_ci_widths() -> None:
    """Float64 on a fixed input: x86 CPUs of other instruction sets differ by ~1e-15, a real change far more."""
    model = ci_network()
    window = torch.rand(1, 10, 3, 64, 64, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    with torch.no_grad():
        got = summary(model.eval()(window[:, :5]))
        got_train = summary(model.train()(window))
    assert got == pytest.approx(CI_OUTPUT, rel=1e-9)
    assert got_train == pytest.approx(CI_TRAIN_OUTPUT, rel=1e-9)


def test_frames_after_the_context_change_nothing_in_eval_mode() -> None:
    torch.manual_seed(0)
    model = MMVP(3, channels=4, predictor_channels=2, encoder_blocks=1, decoder_blocks=1, enhancer_blocks=1).double().eval()
    x = torch.rand(2, 6, 3, 32, 32, dtype=torch.float64)
    with torch.no_grad():
        a, b = model(x[:, :3]), model(x)
        model.train()
        c, d = model(x[:, :3]), model(x)
    assert a.shape == (2, 3, 3, 32, 32) and torch.equal(a, b)
    assert (c - d).abs().max() > 1e-6  # in train mode they enter the filter blocks' batch statistics


def test_matrix_predictor_maps_past_matrices_to_future_ones() -> None:
    torch.manual_seed(0)
    pred = MatrixPredictor(past=4, future=3, channels=2)
    out = pred(torch.rand(2, 4, 48, 48), (6, 8))
    assert out.shape == (2, 3, 48, 48)
    rows = torch.rand(1, 4, 48, 48)
    single = pred.eval()(rows, (6, 8))
    moved = rows.clone()
    moved[:, :, 5] = 0.0  # one source position's rows: each row is predicted on its own
    changed = (pred(moved, (6, 8)) - single).abs().amax(dim=(0, 1, 3))
    assert changed[5] > 0 and changed[torch.arange(48) != 5].max() == 0


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [("context_frames", 1, "a motion matrix needs two frames"), ("channels", 2, "must be >= 4"),
     ("downsample", [2, 2], "three factors"), ("downsample", [2, 3, 2], "three factors"), ("encoder_blocks", 0, "must be >= 1"),
     ("weight_decay", -0.1, "must be >= 0")],  # fmt: skip
)
def test_bad_options_are_errors_naming_the_field(field: str, value: object, match: str) -> None:
    with pytest.raises(ClodsError, match=match) as e:
        MmvpPredictor(MmvpConfig(**{field: value}))
    assert e.value.where == f"video_config.mmvp.{field}"
