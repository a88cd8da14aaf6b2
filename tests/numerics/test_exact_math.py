"""The numpy kernels deterministic mode puts under torch's sqrt, log, tan, asin, acos and atan.

The test session runs in deterministic mode (`tests/test_deterministic_mode.py` asserts it), so the kernels here are
the replacements; how each import order and the mode switch install them or not is checked in fresh interpreters.
"""

from __future__ import annotations

import os
import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest
import torch

from clods_bench import numerics as dm
from clods_bench.numerics import exact_math



def _is_correctly_rounded_sqrt(root: np.float32, v: np.float32) -> bool:
    """Whether `root` is the float32 nearest sqrt(v), in exact rational arithmetic: v lies strictly between the squares
    of the midpoints to root's neighbours (independent of any square-root routine)."""
    below, above = np.nextafter(root, np.float32(0)), np.nextafter(root, np.float32(np.inf))
    lo = (Fraction(float(below)) + Fraction(float(root))) / 2
    hi = (Fraction(float(root)) + Fraction(float(above))) / 2
    return lo * lo < Fraction(float(v)) < hi * hi


def test_installed_when_torch_loads_in_deterministic_mode() -> None:
    assert exact_math.installed()
    assert dm.describe()["exact_math"] == list(exact_math.REPLACED)


def _installed_in_fresh_python(code: str, **env: str) -> str:
    full = {k: v for k, v in os.environ.items() if k not in (dm.SWITCH_ENV, dm.BEFORE_PINS_ENV)} | env
    probe = "\nfrom clods_bench.numerics import exact_math, exact_matmul; print(exact_math.installed() and exact_matmul.installed(), exact_math.installed() or exact_matmul.installed())"
    out = subprocess.run([sys.executable, "-c", code + probe],
                         capture_output=True, text=True, env=full, timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


def test_every_import_order_installs_them_and_host_mode_does_not() -> None:
    """Both replacements (these functions and `exact_matmul`'s products) are installed together, or neither."""
    # torch's presence looked up first (as libraries do), then imported: still installed once torch loads
    assert _installed_in_fresh_python("import clods_bench, importlib.util\nimportlib.util.find_spec('torch')\nimport torch") == "True True"
    # torch loaded before clods_bench, with the pins exported beforehand (`numerics --export`): installed at once
    assert _installed_in_fresh_python("import numpy, torch, clods_bench", **dm.pins()) == "True True"
    # the mode switched off: torch keeps MKL's kernels
    assert _installed_in_fresh_python("import clods_bench, torch", **{dm.SWITCH_ENV: "0"}) == "False False"


def test_sqrt_is_correctly_rounded() -> None:
    x = torch.rand(4000, generator=torch.Generator().manual_seed(3), dtype=torch.float32) * 10 + 1e-3
    got = torch.sqrt(x).numpy()
    assert all(_is_correctly_rounded_sqrt(r, v) for r, v in zip(got, x.numpy()))


@pytest.mark.parametrize("name", exact_math.REPLACED)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_every_form_gives_numpys_bits(name: str, dtype: torch.dtype) -> None:
    x = (torch.rand(257, generator=torch.Generator().manual_seed(1), dtype=dtype) * 0.9 + 0.05)
    want = getattr(np, {"asin": "arcsin", "acos": "arccos", "atan": "arctan"}.get(name, name))(x.numpy())
    fn = getattr(torch, name)
    assert fn(x).dtype == dtype and np.array_equal(fn(x).numpy(), want)
    assert np.array_equal(getattr(x, name)().numpy(), want)
    inplace = x.clone()
    getattr(inplace, name + "_")()
    assert np.array_equal(inplace.numpy(), want)
    out = torch.empty(0, dtype=dtype)
    fn(x, out=out)
    assert np.array_equal(out.numpy(), want)
    strided = x.view(1, 257).expand(3, 257).t()  # a non-contiguous view: values as numpy's on the same numbers
    assert np.array_equal(fn(strided).numpy(), np.broadcast_to(want[:, None], (257, 3)))


def test_gradients_follow_autograd_formulas() -> None:
    x = torch.tensor([0.25, 0.5, 2.0], dtype=torch.float64, requires_grad=True)
    (torch.sqrt(x).sum() + torch.log(x).sum() + torch.atan(x).sum()).backward()
    want = 0.5 / np.sqrt([0.25, 0.5, 2.0]) + 1 / np.array([0.25, 0.5, 2.0]) + 1 / (1 + np.array([0.25, 0.5, 2.0]) ** 2)
    np.testing.assert_allclose(x.grad.numpy(), want, rtol=1e-15)


def test_integers_promote_and_half_precision_round_trips() -> None:
    assert torch.sqrt(torch.tensor([4, 9])).dtype == torch.get_default_dtype()
    assert torch.sqrt(torch.tensor([4, 9])).tolist() == [2.0, 3.0]
    half = torch.tensor([2.0, 3.0], dtype=torch.bfloat16)
    assert torch.sqrt(half).dtype == torch.bfloat16
    assert torch.sqrt(half).tolist() == torch.tensor(np.sqrt([2.0, 3.0]), dtype=torch.float32).to(torch.bfloat16).tolist()


def test_adams_foreach_sqrt_goes_through_the_replacement() -> None:
    x = [torch.rand(33, generator=torch.Generator().manual_seed(5)) + 0.1, torch.rand(7) + 0.1]
    got = torch._foreach_sqrt(x)
    for g, v in zip(got, x):
        assert np.array_equal(g.numpy(), np.sqrt(v.numpy()))
