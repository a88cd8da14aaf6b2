"""The kernels `numerics.exact()` puts under torch's mm, addmm, bmm and baddbmm: `fma_gemm`'s k-ordered chains of
fused multiply-adds.

The test session runs inside `numerics.exact()` (`clods_bench.numerics.pytest_plugin`), so torch's products here are
the replacements. References: `fma_gemm.matmul` on the same values (the same bits, every form and layout; it is
checked against exact arithmetic in `test_fma_gemm.py`), torch's own products computed outside the scope in a fresh
interpreter (which round differently at k >= 1000, so a bypassed replacement fails here), a spy on `fma_gemm.matmul`,
`math.fsum` of the products (correctly rounded sums), autograd's gradients against finite differences, and fresh
interpreters for what the host's environment may not change (`test_aten_semantics.py` checks ATen's semantics).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from typing import Any

import numpy as np
import pytest
import torch

from clods_bench import numerics as dm
from clods_bench.numerics import exact_matmul, fma_gemm
from clods_bench.numerics.pinning import BEFORE_PINS_ENV
from tests.numerics import aten_reference

_G = torch.Generator().manual_seed(11)
K = 1031
"""An inner dimension where MKL's blocked sums and one k-ordered chain of fused multiply-adds round differently."""


def _randn(*shape: int, dtype: torch.dtype = torch.float32, generator: torch.Generator = _G) -> torch.Tensor:
    return torch.randn(*shape, generator=generator, dtype=dtype)


def test_installed_and_described() -> None:
    assert dm.active() and exact_matmul.installed()
    assert dm.describe()["exact_matmul"] == list(exact_matmul.REPLACED)


def _layouts(t: torch.Tensor) -> dict[str, torch.Tensor]:
    """The same values row-major, column-major, and as a strided slice."""
    out = {"row-major": t, "column-major": t.transpose(-1, -2).contiguous().transpose(-1, -2)}
    wide = torch.zeros(*t.shape[:-1], 2 * t.shape[-1], dtype=t.dtype)
    wide[..., ::2] = t
    out["every other column"] = wide[..., ::2]  # neither layout BLAS takes: copied first
    return out


@pytest.fixture(scope="module")
def host_products() -> dict[torch.dtype, dict[str, Any]]:
    """Per dtype: factors with k = K, and torch's own mm, bmm and addmm of them computed outside the exact scope (one
    fresh interpreter for all)."""
    g = torch.Generator().manual_seed(29)
    inputs = {dtype: {"mm": [_randn(37, K, dtype=dtype, generator=g), _randn(K, 18, dtype=dtype, generator=g)],
                      "bmm": [_randn(3, 9, K, dtype=dtype, generator=g), _randn(3, K, 4, dtype=dtype, generator=g)],
                      "addmm": [_randn(18, dtype=dtype, generator=g)]} for dtype in (torch.float32, torch.float64)}  # fmt: skip
    for case in inputs.values():
        case["addmm"] += case["mm"]
    cases = [{"kind": "call", "name": name, "form": "function", "args": args, "kwargs": {}}
             for case in inputs.values() for name, args in case.items()]  # fmt: skip
    records = iter(aten_reference.reference(cases))
    return {dtype: {name: (args, next(records)["result"]["value"]) for name, args in case.items()} for dtype, case in inputs.items()}


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_mm_and_bmm_give_fma_gemms_bits_in_every_layout(dtype: torch.dtype, host_products: dict[torch.dtype, Any]) -> None:
    """Bit for bit `fma_gemm`'s, and not the bits torch gives outside the scope: a bypassed kernel fails here."""
    (a, b), host = host_products[dtype]["mm"]
    want = torch.from_numpy(fma_gemm.matmul(a.numpy(), b.numpy()))
    assert not torch.equal(want, host)  # torch's own product rounds otherwise: the test can tell
    bound = 2 * K * torch.finfo(dtype).eps * (a.abs() @ b.abs())  # two sums each within K eps sum|terms| of exact
    assert bool(((want - host).abs() <= bound).all())  # ... by rounding only
    for name_a, la in _layouts(a).items():
        for name_b, lb in _layouts(b).items():
            assert torch.equal(torch.mm(la, lb), want), (name_a, name_b)
    (x, y), host3 = host_products[dtype]["bmm"]
    batched = torch.from_numpy(fma_gemm.matmul(x.numpy(), y.numpy()))
    assert not torch.equal(batched, host3)
    assert torch.equal(torch.bmm(x, y), batched)
    assert torch.equal(torch.bmm(x.transpose(1, 2).contiguous().transpose(1, 2), y), batched)
    assert torch.equal(torch.matmul(x, y), batched)
    assert torch.equal(torch.einsum("bij,bjk->bik", x, y), batched)
    (bias, a, b), host_linear = host_products[dtype]["addmm"]
    linear = torch.from_numpy(fma_gemm.matmul(a.numpy(), b.numpy(), bias.numpy()))
    assert not torch.equal(linear, host_linear)
    assert torch.equal(torch.nn.functional.linear(a, b.t(), bias), linear)  # nn.Linear's route: addmm with a bias row


def test_mm_bmm_and_linear_forward_and_backward_reach_fma_gemm(monkeypatch: pytest.MonkeyPatch) -> None:
    """A spy on `fma_gemm.matmul`: torch.mm, nn.Linear's forward (addmm) and backward (mm for both gradients) and a
    bmm each call it, with the factors' shapes."""
    calls: list[tuple[tuple[int, ...], tuple[int, ...]]] = []
    real = fma_gemm.matmul

    def spy(a: np.ndarray, b: np.ndarray, *args: Any, **kwargs: Any) -> np.ndarray:
        calls.append((a.shape, b.shape))
        return real(a, b, *args, **kwargs)

    monkeypatch.setattr(fma_gemm, "matmul", spy)
    torch.mm(_randn(5, 7), _randn(7, 3))
    assert calls == [((5, 7), (7, 3))]
    layer = torch.nn.Linear(16, 8)
    x = _randn(4, 16).requires_grad_()
    calls.clear()
    y = layer(x)
    assert calls == [((4, 16), (16, 8))]
    calls.clear()
    (y * _randn(4, 8)).sum().backward()
    assert sorted(calls) == sorted([((4, 8), (8, 16)), ((8, 4), (4, 16))])  # grad of x, grad of the weight
    calls.clear()
    torch.bmm(_randn(2, 3, 5), _randn(2, 5, 4))
    assert calls == [((2, 3, 5), (2, 5, 4))]


def test_products_are_sums_of_products_to_a_few_ulps() -> None:
    """Against `math.fsum` of the float64 products (exact sum, rounded once): BLAS's own order may differ by ulps."""
    a, b = _randn(6, 300, dtype=torch.float64), _randn(300, 5, dtype=torch.float64)
    got = torch.mm(a, b).numpy()
    an, bn = a.numpy(), b.numpy()
    for i in range(6):
        for j in range(5):
            terms = [float(an[i, k] * bn[k, j]) for k in range(300)]
            scale = math.fsum(abs(t) for t in terms)
            assert abs(got[i, j] - math.fsum(terms)) <= 64 * np.finfo(np.float64).eps * scale


def test_addmm_and_baddbmm_forms_follow_atens_definition() -> None:
    """beta * self + alpha * (a @ b), `self` broadcast; with beta = 0 a NaN in `self` does not propagate."""
    a, b, bias = _randn(20, 33), _randn(33, 7), _randn(7)
    prod = fma_gemm.matmul(a.numpy(), b.numpy())
    assert torch.equal(torch.addmm(bias, a, b), torch.from_numpy(prod + bias.numpy()))
    want = prod * np.float32(0.5) + bias.numpy() * np.float32(2.0)
    assert torch.equal(torch.addmm(bias, a, b, beta=2.0, alpha=0.5), torch.from_numpy(want))
    assert torch.equal(torch.addmm(torch.full((7,), float("nan")), a, b, beta=0), torch.from_numpy(prod))
    inplace = torch.zeros(20, 7) + bias
    inplace.addmm_(a, b)
    assert torch.equal(inplace, torch.from_numpy(prod + bias.numpy()))
    out = torch.empty(0)
    torch.addmm(bias, a, b, out=out)
    assert out.shape == (20, 7) and torch.equal(out, inplace)
    lin = torch.nn.functional.linear(a, b.t().contiguous(), bias)  # nn.Linear's route
    assert torch.equal(lin, torch.from_numpy(prod + bias.numpy()))
    x, y, base = _randn(2, 4, 6), _randn(2, 6, 3), _randn(2, 4, 3)
    want3 = fma_gemm.matmul(x.numpy(), y.numpy()) * np.float32(3.0) + base.numpy()
    assert torch.equal(torch.baddbmm(base, x, y, alpha=3.0), torch.from_numpy(want3))
    assert torch.equal(base.clone().baddbmm_(x, y, alpha=3.0), torch.from_numpy(want3))
    out3 = torch.empty(1)
    with pytest.warns(UserWarning, match="An output with one or more elements was resized"):  # as ATen warns
        torch.bmm(x, y, out=out3)
    assert torch.equal(out3, torch.from_numpy(fma_gemm.matmul(x.numpy(), y.numpy())))


def test_gradients_match_finite_differences() -> None:
    a = _randn(5, 4, dtype=torch.float64).requires_grad_()
    b = _randn(4, 3, dtype=torch.float64).requires_grad_()
    bias = _randn(3, dtype=torch.float64).requires_grad_()
    assert torch.autograd.gradcheck(lambda p, q, r: torch.addmm(r, p, q, alpha=0.7, beta=1.3), (a, b, bias))
    x = _randn(2, 3, 4, dtype=torch.float64).requires_grad_()
    y = _randn(2, 4, 2, dtype=torch.float64).requires_grad_()
    assert torch.autograd.gradcheck(torch.bmm, (x, y))


def test_other_dtypes_and_empty_products() -> None:
    """Half and bfloat16 are multiplied in float32 and rounded once, integers exactly, complex conjugate views
    resolved."""
    a, b = _randn(8, 16), _randn(16, 4)
    for low in (torch.float16, torch.bfloat16):
        got = torch.mm(a.to(low), b.to(low))
        want = fma_gemm.matmul(a.to(low).float().numpy(), b.to(low).float().numpy())
        assert got.dtype == low and torch.equal(got, torch.from_numpy(want).to(low))
        bias = _randn(4).to(low)  # nn.Linear's route in half precision: the bias is added in float32, then rounded
        lin = torch.nn.functional.linear(a.to(low), b.t().contiguous().to(low), bias)
        assert lin.dtype == low and torch.equal(lin, torch.from_numpy(want + bias.float().numpy()).to(low))
    ints = torch.arange(12).reshape(3, 4)
    assert torch.equal(torch.mm(ints, ints.t()), torch.from_numpy(ints.numpy() @ ints.numpy().T))
    assert torch.equal(torch.mm(torch.zeros(3, 0), torch.zeros(0, 2)), torch.zeros(3, 2))
    c = _randn(3, 4, dtype=torch.complex64)
    assert torch.equal(torch.mm(c.conj(), c.t()), torch.from_numpy(np.matmul(c.numpy().conj(), c.numpy().T)))  # a lazy conjugate


def test_bad_shapes_and_dtypes_raise_atens_error() -> None:
    """ATen's messages (`test_aten_semantics` compares every error's type with ATen's in a fresh interpreter)."""
    with pytest.raises(RuntimeError, match=r"cannot be multiplied \(3x4 and 5x6\)"):
        torch.mm(_randn(3, 4), _randn(5, 6))
    with pytest.raises(RuntimeError, match="expected m1 and m2 to have the same dtype, but got: float != double"):
        torch.mm(_randn(3, 4), _randn(4, 2, dtype=torch.float64))
    with pytest.raises(RuntimeError, match="batch1 must be a 3D tensor"):
        torch.bmm(_randn(3, 4), _randn(4, 2))
    with pytest.raises(RuntimeError, match="Expected out tensor to have dtype float, but got double instead"):
        torch.mm(_randn(3, 4), _randn(4, 2), out=torch.empty(0, dtype=torch.float64))
    with pytest.raises(NotImplementedError, match="not implemented for 'Bool'"):
        torch.mm(torch.ones(2, 2, dtype=torch.bool), torch.ones(2, 2, dtype=torch.bool))


def _product_digest(**env: str) -> str:
    """The digest of an nn.Linear product inside `numerics.exact()` in a fresh interpreter with `env` added."""
    code = ("from clods_bench import numerics\nnumerics.pin_environment()\nimport torch, hashlib\n"
            "g = torch.Generator().manual_seed(0)\na, b = torch.randn(300, 257, generator=g), torch.randn(257, 129, generator=g)\n"
            "with numerics.exact():\n"
            "    print(hashlib.sha256(torch.nn.functional.linear(a, b.t(), b[0, :129]).numpy().tobytes()).hexdigest()[:16])")  # fmt: skip
    full = {k: v for k, v in os.environ.items() if k not in (dm.SWITCH_ENV, BEFORE_PINS_ENV)} | env
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full, timeout=300, cwd=aten_reference.ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


@pytest.mark.skipif("avx2" not in (dm.cpu_flags() or set()), reason="the kernels need an AVX2 CPU")
def test_the_hosts_settings_do_not_reach_the_product() -> None:
    """Neither a host's own OPENBLAS_CORETYPE (Prescott's SSE kernel) nor the kernels' instruction set (AVX2 forced on
    an AVX-512 CPU) changes deterministic mode's products, nn.Linear's folded bias included."""
    pinned = _product_digest()
    assert _product_digest(OPENBLAS_CORETYPE="Prescott") == pinned
    assert _product_digest(**{fma_gemm.ISA_ENV: "avx2"}) == pinned
    if fma_gemm.host_isa() == "avx512":
        assert _product_digest(**{fma_gemm.ISA_ENV: "avx512"}) == pinned
