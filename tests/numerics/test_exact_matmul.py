"""The kernels deterministic mode puts under torch's mm, addmm, bmm and baddbmm: `fma_gemm`'s k-ordered chains of
fused multiply-adds.

The test session runs in deterministic mode (`tests/test_deterministic_mode.py` asserts it), so torch's products here
are the replacements. References: `fma_gemm.matmul` on the same values (the same bits, every form and layout; it is
checked against exact arithmetic in `tests/test_fma_gemm.py`), `math.fsum` of the products (correctly rounded sums),
autograd's gradients against finite differences, and fresh interpreters for what the host's environment may not
change.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from clods_bench import numerics as dm
from clods_bench.numerics import exact_matmul, fma_gemm

_G = torch.Generator().manual_seed(11)


def _randn(*shape: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    return torch.randn(*shape, generator=_G, dtype=dtype)


def test_installed_and_described() -> None:
    assert exact_matmul.installed()
    assert dm.describe()["exact_matmul"] == list(exact_matmul.REPLACED)


def _layouts(t: torch.Tensor) -> dict[str, torch.Tensor]:
    """The same values row-major, column-major, and as a strided slice."""
    out = {"row-major": t, "column-major": t.transpose(-1, -2).contiguous().transpose(-1, -2)}
    wide = torch.zeros(*t.shape[:-1], 2 * t.shape[-1], dtype=t.dtype)
    wide[..., ::2] = t
    out["every other column"] = wide[..., ::2]  # neither layout BLAS takes: copied first
    return out


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_mm_and_bmm_give_fma_gemms_bits_in_every_layout(dtype: torch.dtype) -> None:
    a, b = _randn(37, 129, dtype=dtype), _randn(129, 18, dtype=dtype)
    want = fma_gemm.matmul(a.numpy(), b.numpy())
    assert not np.array_equal(want, np.matmul(a.numpy(), b.numpy()))  # not a BLAS's bits: the test can tell
    for name_a, la in _layouts(a).items():
        for name_b, lb in _layouts(b).items():
            assert torch.equal(torch.mm(la, lb), torch.from_numpy(want)), (name_a, name_b)
    x, y = _randn(3, 9, 65, dtype=dtype), _randn(3, 65, 4, dtype=dtype)
    batched = torch.from_numpy(fma_gemm.matmul(x.numpy(), y.numpy()))
    assert torch.equal(torch.bmm(x, y), batched)
    assert torch.equal(torch.bmm(x.transpose(1, 2).contiguous().transpose(1, 2), y), batched)
    assert torch.equal(torch.matmul(x, y), batched)
    assert torch.equal(torch.einsum("bij,bjk->bik", x, y), batched)


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
    code = ("import clods_bench, torch, hashlib\ng = torch.Generator().manual_seed(0)\n"
            "a, b = torch.randn(300, 257, generator=g), torch.randn(257, 129, generator=g)\n"
            "print(hashlib.sha256(torch.nn.functional.linear(a, b.t(), b[0, :129]).numpy().tobytes()).hexdigest()[:16])")  # fmt: skip
    full = {k: v for k, v in os.environ.items() if k not in (dm.SWITCH_ENV, dm.BEFORE_PINS_ENV)} | env
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full, timeout=300)
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
