"""The truncated-normal initialisation that keeps initial weights the same under every torch version."""

from __future__ import annotations

import math

import pytest
import torch

from clods_bench.truncated_normal import truncated_normal_

TORCH_2_13 = tuple(int(x) for x in torch.__version__.split("+")[0].split(".")[:2]) >= (2, 13)


@pytest.mark.skipif(not TORCH_2_13, reason="torch 2.13's trunc_normal_ is the reference; this torch draws otherwise")
@pytest.mark.parametrize(
    ("shape", "mean", "std", "a", "b", "dtype"),
    [
        ((128, 384), 0.0, 1 / math.sqrt(384), -2 / math.sqrt(384), 2 / math.sqrt(384), torch.float32),  # Sonnet's rule
        ((16, 8, 3, 3), 0.0, 0.02, -2.0, 2.0, torch.float32),  # OpenSTL's rule
        ((5000,), 0.3, 1.0, -0.5, 0.6, torch.float32),  # mass 0.34: most values are redrawn, several rounds
        ((7, 11), -1.0, 2.0, -3.0, 4.0, torch.float64),
    ],
)
@pytest.mark.parametrize("seeded_by", ["global", "generator"])
def test_equals_torch_2_13_bit_for_bit(shape, mean, std, a, b, dtype, seeded_by) -> None:
    ours, theirs = torch.empty(shape, dtype=dtype), torch.empty(shape, dtype=dtype)
    if seeded_by == "global":
        torch.manual_seed(7)
        truncated_normal_(ours, mean, std, a, b)
        after_ours = torch.rand(3)
        torch.manual_seed(7)
        torch.nn.init.trunc_normal_(theirs, mean, std, a, b)
        after_theirs = torch.rand(3)
        assert torch.equal(after_ours, after_theirs)  # the generator advanced by as many draws
    else:
        truncated_normal_(ours, mean, std, a, b, generator=torch.Generator().manual_seed(11))
        torch.nn.init.trunc_normal_(theirs, mean, std, a, b, generator=torch.Generator().manual_seed(11))
    assert torch.equal(ours, theirs)


def test_values_inside_the_interval_are_the_first_draws_and_the_rest_redrawn() -> None:
    a, b = -0.4, 0.7
    first = torch.empty(20000).normal_(0.0, 1.0, generator=torch.Generator().manual_seed(3))
    out = truncated_normal_(torch.empty(20000), 0.0, 1.0, a, b, generator=torch.Generator().manual_seed(3))
    inside = (first >= a) & (first <= b)
    assert torch.equal(out[inside], first[inside])
    assert bool(((out >= a) & (out <= b)).all())
    assert not bool((out[~inside] == first[~inside]).any())


def test_moments_match_the_truncated_normal_formulas() -> None:
    mean, std, a, b = 0.5, 2.0, -1.0, 3.0
    out = truncated_normal_(torch.empty(400_000, dtype=torch.float64), mean, std, a, b, generator=torch.Generator().manual_seed(0))
    alpha, beta = (a - mean) / std, (b - mean) / std
    pdf = lambda x: math.exp(-0.5 * x * x) / math.sqrt(2 * math.pi)  # noqa: E731
    cdf = lambda x: 0.5 * (1 + math.erf(x / math.sqrt(2)))  # noqa: E731
    z = cdf(beta) - cdf(alpha)
    want_mean = mean + std * (pdf(alpha) - pdf(beta)) / z
    want_var = std**2 * (1 + (alpha * pdf(alpha) - beta * pdf(beta)) / z - ((pdf(alpha) - pdf(beta)) / z) ** 2)
    assert abs(out.mean().item() - want_mean) < 5 * math.sqrt(want_var / out.numel())
    assert abs(out.var().item() / want_var - 1) < 0.01


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="std must be positive"):
        truncated_normal_(torch.empty(3), std=0.0)
    with pytest.raises(ValueError, match=r"\[1.0, -1.0\] is empty"):
        truncated_normal_(torch.empty(3), a=1.0, b=-1.0)
    with pytest.raises(ValueError, match=r"\[5.0, 6.0\] holds 2.86e-07 of normal"):
        truncated_normal_(torch.empty(3), mean=0.0, std=1.0, a=5.0, b=6.0)
    assert truncated_normal_(torch.empty(0)).numel() == 0


def test_no_model_draws_through_torchs_own_trunc_normal() -> None:
    """A model calling `nn.init.trunc_normal_` would start from other weights under torch < 2.13 (other bits)."""
    from pathlib import Path

    package = Path(__file__).resolve().parents[1] / "clods_bench"
    callers = [
        str(p.relative_to(package))
        for p in package.rglob("*.py")
        if p.name != "truncated_normal.py" and "trunc_normal_(" in p.read_text().replace("truncated_normal_(", "")
    ]
    assert callers == []
