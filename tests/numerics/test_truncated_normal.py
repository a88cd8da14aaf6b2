"""The truncated-normal initialisation that keeps initial weights the same under every torch version."""

from __future__ import annotations

import hashlib
import math

import pytest
import torch

from clods_bench.numerics.truncated_normal import truncated_normal_

TORCH_2_13 = tuple(int(x) for x in torch.__version__.split("+")[0].split(".")[:2]) >= (2, 13)


# sha256 (first 16 hex digits) of torch 2.13.0's own `nn.init.trunc_normal_` on each case (Intel Xeon, 2026-11-29):
# what `truncated_normal_` must give under every torch version, the GPU machines' 2.11 included.
TORCH_2_13_DIGESTS = {
    ("sonnet", "global"): "6c9fe53cf545e93d", ("sonnet", "generator"): "b26cb121ffbc22ba",
    ("openstl", "global"): "ab4e4e914a73b055", ("openstl", "generator"): "038684e8eb28f665",
    ("redraws", "global"): "a3eff554fe289a00", ("redraws", "generator"): "b1980b5dd0404f07",
    ("float64", "global"): "d27c0fa5e4335ed8", ("float64", "generator"): "8d279f8010bbdce0",
}  # fmt: skip
CASES = {
    "sonnet": ((128, 384), 0.0, 1 / math.sqrt(384), -2 / math.sqrt(384), 2 / math.sqrt(384), torch.float32),
    "openstl": ((16, 8, 3, 3), 0.0, 0.02, -2.0, 2.0, torch.float32),
    "redraws": ((5000,), 0.3, 1.0, -0.5, 0.6, torch.float32),  # mass 0.34: most values are redrawn, several rounds
    "float64": ((7, 11), -1.0, 2.0, -3.0, 4.0, torch.float64),
}


def _draw(fill, case: str, seeded_by: str) -> tuple[torch.Tensor, torch.Tensor | None]:
    """`fill` on the case's tensor, seeded globally (then the next three global draws) or by its own generator."""
    shape, mean, std, a, b, dtype = CASES[case]
    out = torch.empty(shape, dtype=dtype)
    if seeded_by == "global":
        torch.manual_seed(7)
        fill(out, mean, std, a, b)
        return out, torch.rand(3)
    fill(out, mean, std, a, b, generator=torch.Generator().manual_seed(11))
    return out, None


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("seeded_by", ["global", "generator"])
def test_gives_torch_2_13s_draws_under_this_torch(case: str, seeded_by: str) -> None:
    ours, after = _draw(truncated_normal_, case, seeded_by)
    assert hashlib.sha256(ours.numpy().tobytes()).hexdigest()[:16] == TORCH_2_13_DIGESTS[(case, seeded_by)]
    if TORCH_2_13:  # the reference itself is here: equal bits, and the generator advanced by as many draws
        theirs, after_theirs = _draw(torch.nn.init.trunc_normal_, case, seeded_by)
        assert torch.equal(ours, theirs)
        assert after is None or torch.equal(after, after_theirs)


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

    package = Path(__file__).resolve().parents[2] / "clods_bench"
    assert (package / "numerics").is_dir()  # the scan below must see the package
    callers = [
        str(p.relative_to(package))
        for p in package.rglob("*.py")
        if p.name != "truncated_normal.py" and "trunc_normal_(" in p.read_text().replace("truncated_normal_(", "")
    ]
    assert callers == []
