"""The matrix products deterministic mode takes away from MKL and computes with `fma_gemm`.

Under `MKL_CBWR=COMPATIBLE` MKL's GEMMs give the same bits on every x86 CPU, but that branch is SSE2 code: torch's
`mm` of a 9000x384 by 384x128 float32 matrix took 28 ms on one core of an Intel Xeon (Sapphire Rapids) against 7 ms
on the host's own branch. MKL's AVX2 branch is fast but gave other bits under QEMU's AMD EPYC Rome than on the Xeon,
and no BLAS gives the same bits at AVX2 and AVX-512 width (OpenBLAS's Haswell and SkylakeX kernels do not). So
`fma_gemm` computes each element as one k-ordered chain of fused multiply-adds, which its AVX2 and AVX-512 kernels
both do: an AVX-512 CPU runs at AVX-512 speed and gives an AVX2 CPU's bits.

`mm`, `addmm`, `bmm` and `baddbmm` (out-of-place, in-place and `out=` forms) get CPU kernels that hand the product to
`fma_gemm.matmul` (float32 and float64; numpy's matmul for integers and complex numbers). `addmm` with a bias row
and beta = alpha = 1 (`nn.Linear`) has the kernel add the row as it stores the product, the same rounding as a
separate addition; other `beta * self` terms are added in numpy. `nn.Linear` reaches them through `addmm`/`mm`, and
autograd's backward formulas, which sit above the CPU kernels, call `mm` again. Convolutions stay on oneDNN (pinned
to AVX2) and the rarer products (`mv`, `dot`, `addbmm`, ...) on MKL's COMPATIBLE branch: those are the same bits
everywhere too, only slower.
"""

from __future__ import annotations

import warnings
from typing import Any

REPLACED = ("mm", "addmm", "bmm", "baddbmm")
"""The ATen matrix products whose CPU kernels deterministic mode replaces."""

_state: dict[str, Any] = {"library": None}


def installed() -> bool:
    """Whether the replacement kernels are registered in this process."""
    return _state["library"] is not None


def _operand(t: Any) -> Any:
    """`t` as a numpy array BLAS can take without a copy inside numpy: its last two axes row- or column-major
    (else a contiguous copy); half and bfloat16 widen to float32, as ATen accumulates them."""
    import torch

    t = t.detach().resolve_conj().resolve_neg()  # lazy conjugate / negative views made real
    if t.dtype in (torch.float16, torch.bfloat16):
        t = t.float()
    rows, cols = t.shape[-2], t.shape[-1]
    s_row, s_col = t.stride(-2), t.stride(-1)
    row_major = s_col == 1 and s_row >= max(cols, 1)
    col_major = s_row == 1 and s_col >= max(rows, 1)
    if not (row_major or col_major):
        t = t.contiguous()
    return t.numpy()


def _bias_row(self: Any, a: Any, b: Any, beta: Any, alpha: Any) -> Any:
    """`self` as one row (numpy) when addmm's `beta * self + alpha * a @ b` is `a @ b + row` (nn.Linear's bias):
    `fma_gemm` then adds it as it stores the product, which is the same addition without another pass; else None."""
    import torch

    if beta != 1 or alpha != 1 or a.dim() != 2 or not (self.dtype == a.dtype == b.dtype) or self.dtype not in (torch.float32, torch.float64):
        return None
    n = b.shape[-1]
    if self.dim() == 1 and self.shape[0] == n:
        return self.detach().resolve_neg().contiguous().numpy()
    if self.dim() == 2 and self.shape[-1] == n and (self.shape[0] == 1 or (self.shape[0] == a.shape[0] and self.stride(0) == 0)):
        return self.detach().resolve_neg()[0].contiguous().numpy()
    return None


def _product(a: Any, b: Any, row: Any = None) -> Any:
    """`a @ b (+ row)` for CPU tensors of two or three dimensions, as a numpy array: `fma_gemm`'s k-ordered chains of
    fused multiply-adds for float32 and float64, numpy for the other dtypes (integers are exact anyway)."""
    import numpy as np

    from clods_bench.numerics import fma_gemm

    import torch

    x, y = _operand(a), _operand(b)
    if x.dtype == y.dtype and x.dtype.type in fma_gemm.DTYPES:
        return fma_gemm.matmul(x, y, row, threads=torch.get_num_threads())
    out = np.matmul(x, y)
    return out if row is None else np.add(out, row, out=out)


def _combine(product: Any, self: Any, beta: Any, alpha: Any, dtype: Any) -> Any:
    """`beta * self + alpha * product` as ATen's addmm defines it (`self` ignored when beta is 0), in `dtype`."""
    import numpy as np
    import torch

    if alpha != 1:
        np.multiply(product, np.asarray(alpha, dtype=product.dtype), out=product)
    if beta != 0:
        base = self.detach().resolve_conj().resolve_neg()
        base = base.float() if base.dtype in (torch.float16, torch.bfloat16) else base
        base = base.numpy()
        if beta != 1:
            base = base * np.asarray(beta, dtype=product.dtype)
        np.add(product, base, out=product)  # `product` is numpy's fresh result: safe to overwrite
    out = torch.from_numpy(np.ascontiguousarray(product))
    return out if out.dtype == dtype else out.to(dtype)


def _check(name: str, a: Any, b: Any, dims: int) -> None:
    """ATen's shape checks, with its messages, before numpy sees the operands."""
    if a.dim() != dims or b.dim() != dims:
        raise RuntimeError(f"{name}: expected {dims}D tensors, but got {a.dim()}D and {b.dim()}D tensors")
    if a.shape[-1] != b.shape[-2] or (dims == 3 and a.shape[0] != b.shape[0]):
        raise RuntimeError(f"{name}: mat1 and mat2 shapes cannot be multiplied ({'x'.join(map(str, a.shape))} and "
                           f"{'x'.join(map(str, b.shape))})")
    if a.dtype != b.dtype:
        raise RuntimeError(f"{name}: expected mat1 and mat2 to have the same dtype, but got: {a.dtype} != {b.dtype}")


def _write(out: Any, value: Any) -> Any:
    """Copy `value` into the `out=` tensor, resizing it as ATen's out forms do."""
    if out.shape != value.shape:
        out.resize_(value.shape)
    return out.copy_(value)


def mm(a: Any, b: Any) -> Any:
    """`a @ b` for two matrices."""
    _check("mm", a, b, 2)
    return _combine(_product(a, b), None, 0, 1, a.dtype)


def bmm(a: Any, b: Any) -> Any:
    """`a @ b` for two batches of matrices."""
    _check("bmm", a, b, 3)
    return _combine(_product(a, b), None, 0, 1, a.dtype)


def addmm(self: Any, a: Any, b: Any, *, beta: Any = 1, alpha: Any = 1) -> Any:
    """`beta * self + alpha * (a @ b)`, `self` broadcast to the product's shape."""
    _check("addmm", a, b, 2)
    row = _bias_row(self, a, b, beta, alpha)
    if row is not None:
        return _combine(_product(a, b, row), None, 0, 1, a.dtype)
    return _combine(_product(a, b), self, beta, alpha, a.dtype)


def baddbmm(self: Any, a: Any, b: Any, *, beta: Any = 1, alpha: Any = 1) -> Any:
    """`beta * self + alpha * (a @ b)` for batches of matrices."""
    _check("baddbmm", a, b, 3)
    return _combine(_product(a, b), self, beta, alpha, a.dtype)


def install() -> None:
    """Register the kernels for `REPLACED` on torch's CPU dispatch key (a no-op when installed; imports torch).
    Called by `numerics.exact()`, which removes them again with `uninstall()`."""
    if installed():
        return
    import torch

    library = torch.library.Library("aten", "IMPL")
    forms = {
        "mm": mm,
        "mm.out": lambda a, b, *, out: _write(out, mm(a, b)),
        "bmm": bmm,
        "bmm.out": lambda a, b, *, out: _write(out, bmm(a, b)),
        "addmm": addmm,
        "addmm_": lambda s, a, b, *, beta=1, alpha=1: s.copy_(addmm(s, a, b, beta=beta, alpha=alpha)),
        "addmm.out": lambda s, a, b, *, beta=1, alpha=1, out: _write(out, addmm(s, a, b, beta=beta, alpha=alpha)),
        "baddbmm": baddbmm,
        "baddbmm_": lambda s, a, b, *, beta=1, alpha=1: s.copy_(baddbmm(s, a, b, beta=beta, alpha=alpha)),
        "baddbmm.out": lambda s, a, b, *, beta=1, alpha=1, out: _write(out, baddbmm(s, a, b, beta=beta, alpha=alpha)),
    }
    with warnings.catch_warnings():  # "Overriding a previously registered kernel": that is the point
        warnings.simplefilter("ignore")
        for name, kernel in forms.items():
            library.impl(name, kernel, "CPU")
    _state["library"] = library


def uninstall() -> None:
    """Remove the replacement kernels: torch's own CPU kernels for `REPLACED` are back (a no-op when not installed)."""
    library = _state["library"]
    if library is not None:
        library._destroy()
        _state["library"] = None
