"""The numpy kernels `numerics.exact()` puts under torch's sqrt, log, tan, asin, acos and atan.

The test session runs inside `numerics.exact()` (`clods_bench.numerics.pytest_plugin`), so the kernels here are the
replacements. References: numpy's ufuncs on the same values, exact rational arithmetic for sqrt, torch's own kernels
computed outside the scope in a fresh interpreter (which round differently on thousands of values, so a bypassed
replacement fails here), a spy on `exact_math.evaluate`, and fresh interpreters for how the scope installs and
removes the kernels. `test_aten_semantics.py` checks ATen's shapes, dtypes, strides and errors.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from fractions import Fraction
from typing import Any

import numpy as np
import pytest
import torch

from clods_bench import numerics as dm
from clods_bench.numerics import exact_math
from clods_bench.numerics.pinning import BEFORE_PINS_ENV
from tests.numerics import aten_reference

_NUMPY = {"sqrt": np.sqrt, "log": np.log, "tan": np.tan, "asin": np.arcsin, "acos": np.arccos, "atan": np.arctan}


def _is_correctly_rounded_sqrt(root: np.float32, v: np.float32) -> bool:
    """Whether `root` is the float32 nearest sqrt(v), in exact rational arithmetic: v lies strictly between the squares
    of the midpoints to root's neighbours (independent of any square-root routine)."""
    below, above = np.nextafter(root, np.float32(0)), np.nextafter(root, np.float32(np.inf))
    lo = (Fraction(float(below)) + Fraction(float(root))) / 2
    hi = (Fraction(float(root)) + Fraction(float(above))) / 2
    return lo * lo < Fraction(float(v)) < hi * hi


def test_installed_inside_the_scope() -> None:
    assert dm.active() and exact_math.installed()
    assert dm.describe()["exact_math"] == list(exact_math.REPLACED)


_SCOPE_PROBE = """
import hashlib, json
from clods_bench import numerics
numerics.pin_environment()
import numpy as np, torch
from clods_bench.numerics import exact_math, exact_matmul, fma_gemm
g = torch.Generator().manual_seed(5)
a, b, x = torch.randn(16, 1031, generator=g), torch.randn(1031, 8, generator=g), torch.rand(4000, generator=g) + 0.01

def state():
    mm, root, log = torch.mm(a, b).numpy(), torch.sqrt(x).numpy(), torch.log(x).numpy()
    return {"installed": [exact_math.installed(), exact_matmul.installed()], "0-d sqrt": list(torch.sqrt(torch.tensor(4.0)).shape),
            "mm is fma_gemm's": bool(np.array_equal(mm, fma_gemm.matmul(a.numpy(), b.numpy()))),
            "sqrt and log are numpy's": bool(np.array_equal(root, np.sqrt(x.numpy())) and np.array_equal(log, np.log(x.numpy()))),
            "digest": hashlib.sha256(mm.tobytes() + root.tobytes() + log.tobytes()).hexdigest()}

before = state()
with numerics.maybe_exact():
    inside = state()
print(json.dumps([before, inside, state()]))
"""


def _scope_states(**env: str) -> list[dict[str, Any]]:
    """The kernels' state before, inside and after `numerics.maybe_exact()` in a fresh interpreter that pins the
    environment and imports torch first (nothing inherited from this session's pins)."""
    drop = set(dm.pins()) | {dm.SWITCH_ENV, BEFORE_PINS_ENV}
    full = {k: v for k, v in os.environ.items() if k not in drop} | env
    out = subprocess.run([sys.executable, "-c", _SCOPE_PROBE], capture_output=True, text=True, env=full, timeout=300, cwd=aten_reference.ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_fresh_process_has_the_kernels_only_inside_the_scope() -> None:
    """Importing torch installs nothing; `exact()` installs both replacements (numpy's bits, fma_gemm's products) and
    removes them on exit, torch's own results coming back bit for bit; with the switch off the scope does nothing."""
    before, inside, after = _scope_states()
    assert before["installed"] == after["installed"] == [False, False] and inside["installed"] == [True, True]
    assert not before["mm is fma_gemm's"] and inside["mm is fma_gemm's"] and inside["sqrt and log are numpy's"]
    assert after == before and inside["digest"] != before["digest"]
    assert before["0-d sqrt"] == inside["0-d sqrt"] == after["0-d sqrt"] == []
    host = _scope_states(**{dm.SWITCH_ENV: "0"})
    assert all(s["installed"] == [False, False] and s["digest"] == before["digest"] for s in host)


@pytest.fixture(scope="module")
def host_values() -> dict[torch.dtype, dict[str, tuple[torch.Tensor, torch.Tensor]]]:
    """Per dtype and function: 20,000 values inside its domain, and torch's own results on them computed outside the
    exact scope (one fresh interpreter for all)."""
    g = torch.Generator().manual_seed(3)
    inputs = {dtype: {name: (torch.rand(20000, generator=g, dtype=dtype) * (0.98 if name in ("asin", "acos") else 10) + 0.01)
                      for name in exact_math.REPLACED} for dtype in (torch.float32, torch.float64)}  # fmt: skip
    cases = [{"kind": "call", "name": name, "form": "function", "args": [x], "kwargs": {}}
             for per in inputs.values() for name, x in per.items()]  # fmt: skip
    records = iter(aten_reference.reference(cases))
    return {dtype: {name: (x, next(records)["result"]["value"]) for name, x in per.items()} for dtype, per in inputs.items()}


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_thousands_of_values_give_numpys_bits_not_the_hosts(dtype: torch.dtype, host_values: dict[torch.dtype, Any]) -> None:
    """Each function gives numpy's bits on 20,000 values; torch's own kernels (MKL's vector math) give other bits on
    some of them, so a bypassed replacement fails here."""
    differ = 0
    for name, (x, host) in host_values[dtype].items():
        want = _NUMPY[name](x.numpy())
        assert np.array_equal(getattr(torch, name)(x).numpy(), want), name
        differ += int((host.numpy() != want).sum())
        np.testing.assert_allclose(host.numpy(), want, rtol=4 * torch.finfo(dtype).eps)  # ... by rounding only
    assert differ > 0


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


def test_adams_foreach_sqrt_goes_through_the_replacement(host_values: dict[torch.dtype, Any]) -> None:
    """`torch._foreach_sqrt` and `_foreach_log` (Adam's route) give numpy's bits on 20,000 values per tensor, where
    torch's own kernels differ on some."""
    (xs, host_sqrt), (_, host_log) = host_values[torch.float32]["sqrt"], host_values[torch.float32]["log"]
    parts = [xs[:7], xs[7:4007], xs[4007:]]
    for fn, ufunc, host in ((torch._foreach_sqrt, np.sqrt, host_sqrt), (torch._foreach_log, np.log, host_log)):
        got = torch.cat(fn(parts)).numpy()
        assert np.array_equal(got, ufunc(xs.numpy()))
    assert not (np.array_equal(host_sqrt.numpy(), np.sqrt(xs.numpy())) and np.array_equal(host_log.numpy(), np.log(xs.numpy())))


@pytest.mark.parametrize("foreach", [False, True])
def test_torch_sqrt_log_and_adam_steps_reach_the_numpy_kernels(foreach: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """A spy on `exact_math.evaluate`, where every replaced kernel makes its values: torch.sqrt, torch.log and an Adam
    step (single-tensor and foreach) on 0-d, 1-d and 2-d parameters call it with numpy's ufuncs."""
    seen: list[tuple[str, tuple[int, ...]]] = []
    real = exact_math.evaluate

    def spy(ufunc: Any, values: np.ndarray) -> Any:
        seen.append((ufunc.__name__, values.shape))
        return real(ufunc, values)

    monkeypatch.setattr(exact_math, "evaluate", spy)
    torch.sqrt(torch.rand(5))
    torch.log(torch.rand(2, 3))
    assert seen == [("sqrt", (5,)), ("log", (2, 3))]
    params = [torch.nn.Parameter(torch.tensor(0.5)), torch.nn.Parameter(torch.rand(4)), torch.nn.Parameter(torch.rand(2, 3))]
    opt = torch.optim.Adam(params, lr=0.01, foreach=foreach)
    for p in params:
        p.grad = torch.rand(p.shape)
    seen.clear()
    opt.step()
    assert sorted(shape for name, shape in seen if name == "sqrt") == [(), (2, 3), (4,)]  # Adam's denominators
    assert [p.shape for p in params] == [torch.Size([]), torch.Size([4]), torch.Size([2, 3])]
