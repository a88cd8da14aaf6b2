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

from clods_bench.numerics import aten_rules
from clods_bench.numerics.aten_rules import cpp_type, scalar_type

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
    """`beta * self + alpha * product` as ATen's addmm defines it (`self` ignored when beta is 0), in `dtype`; an
    empty result is laid out contiguously, as ATen's is (numpy gives empty arrays zero strides)."""
    import numpy as np
    import torch

    if product.size == 0:
        return torch.empty(product.shape, dtype=dtype)
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


_SUPPORTED = ("float16", "bfloat16", "float32", "float64", "complex64", "complex128", "uint8", "int8", "int16", "int32", "int64")
"""The dtypes ATen's CPU products take (bool and complex-half raise NotImplementedError)."""
_ATEN_KERNEL = {"mm": "addmm_impl_cpu_", "addmm": "addmm_impl_cpu_", "bmm": "bmm", "baddbmm": "baddbmm"}


def _check(name: str, a: Any, b: Any, dims: int) -> None:
    """ATen's checks of the two factors, with its messages and error types, before numpy sees them."""
    batched = dims == 3
    first, second = ("batch1", "batch2") if batched else ("self" if name == "mm" else "mat1", "mat2")
    for label, t in ((first, a), (second, b)):
        if t.dim() != dims:
            raise RuntimeError(f"{label} must be a 3D tensor" if batched else
                               f"{label} must be a matrix" + ("" if name == "mm" else f", got {t.dim()}-D tensor"))  # fmt: skip
    if batched and (a.shape[0] != b.shape[0] or a.shape[2] != b.shape[1]):
        raise RuntimeError(f"Expected size for first two dimensions of batch2 tensor to be: [{a.shape[0]}, {a.shape[2]}] "
                           f"but got: [{b.shape[0]}, {b.shape[1]}].")  # fmt: skip
    if not batched and a.shape[1] != b.shape[0]:
        raise RuntimeError(f"mat1 and mat2 shapes cannot be multiplied ({a.shape[0]}x{a.shape[1]} and {b.shape[0]}x{b.shape[1]})")
    if a.dtype != b.dtype:
        if name == "mm":
            raise RuntimeError(f"expected m1 and m2 to have the same dtype, but got: {cpp_type(a.dtype)} != {cpp_type(b.dtype)}")
        if name == "addmm":
            raise RuntimeError(f"mat1 and mat2 must have the same dtype, but got {scalar_type(a.dtype)} and {scalar_type(b.dtype)}")
        raise RuntimeError(f"expected scalar type {scalar_type(a.dtype)} but found {scalar_type(b.dtype)}")


def _check_out_and_dtype(name: str, dtype: Any, out: Any) -> None:
    """After the shapes, as ATen: an `out=` tensor of another dtype refused, then a dtype its products do not take."""
    if out is not None:
        aten_rules.check_out_dtype(out, dtype)
    if str(dtype).removeprefix("torch.") not in _SUPPORTED:
        raise NotImplementedError(f'"{_ATEN_KERNEL[name]}" not implemented for \'{scalar_type(dtype)}\'')


def _check_self(name: str, self: Any, a: Any, b: Any, beta: Any, alpha: Any) -> None:
    """ATen's checks of addmm's and baddbmm's `self` term and scalars: `self` of the factors' dtype, broadcastable to
    the product's shape (`expand`'s own error where not), no complex scalar for real tensors."""
    if self.dtype != a.dtype:
        if name == "addmm":
            raise RuntimeError(f"self and mat2 must have the same dtype, but got {scalar_type(self.dtype)} and {scalar_type(b.dtype)}")
        raise RuntimeError(f"Input dtypes must be the same, got: input {cpp_type(self.dtype)}, batch1: {cpp_type(a.dtype)}, "
                           f"batch2: {cpp_type(b.dtype)}")  # fmt: skip
    self.expand(_shape(a, b))  # a view, computing nothing: raises ATen's error where `self` does not broadcast
    if not a.dtype.is_complex and any(isinstance(s, complex) for s in (beta, alpha)):
        kind = "float" if a.dtype.is_floating_point else "int64_t"
        raise RuntimeError(f"value cannot be converted to type {kind} without overflow")


def _shape(a: Any, b: Any) -> tuple[int, ...]:
    """The shape of `a @ b` for checked factors."""
    return (*a.shape[:-1], b.shape[-1])


def mm(a: Any, b: Any, *, out: Any = None) -> Any:
    """`a @ b` for two matrices (written into `out` where given)."""
    _check("mm", a, b, 2)
    _check_out_and_dtype("mm", a.dtype, out)
    return _write(out, _combine(_product(a, b), None, 0, 1, a.dtype))


def bmm(a: Any, b: Any, *, out: Any = None) -> Any:
    """`a @ b` for two batches of matrices (written into `out` where given)."""
    _check("bmm", a, b, 3)
    _check_out_and_dtype("bmm", a.dtype, out)
    return _write(out, _combine(_product(a, b), None, 0, 1, a.dtype))


def addmm(self: Any, a: Any, b: Any, *, beta: Any = 1, alpha: Any = 1, out: Any = None) -> Any:
    """`beta * self + alpha * (a @ b)`, `self` broadcast to the product's shape (written into `out` where given)."""
    _check("addmm", a, b, 2)
    _check_self("addmm", self, a, b, beta, alpha)
    _check_out_and_dtype("addmm", a.dtype, out)
    row = _bias_row(self, a, b, beta, alpha)
    if row is not None:
        return _write(out, _combine(_product(a, b, row), None, 0, 1, a.dtype))
    return _write(out, _combine(_product(a, b), self, beta, alpha, a.dtype))


def baddbmm(self: Any, a: Any, b: Any, *, beta: Any = 1, alpha: Any = 1, out: Any = None) -> Any:
    """`beta * self + alpha * (a @ b)` for batches of matrices (written into `out` where given)."""
    _check("baddbmm", a, b, 3)
    _check_self("baddbmm", self, a, b, beta, alpha)
    _check_out_and_dtype("baddbmm", a.dtype, out)
    return _write(out, _combine(_product(a, b), self, beta, alpha, a.dtype))


def _inplace(product: Any) -> Any:
    """The in-place form of addmm or baddbmm: ATen's error where `self` is not of the product's shape (it is not
    broadcast), else the product written into `self` with `self`'s strides."""

    def inplace(self: Any, a: Any, b: Any, *, beta: Any = 1, alpha: Any = 1) -> Any:
        value = product(self, a, b, beta=beta, alpha=alpha)
        if value.shape != self.shape:
            raise RuntimeError(f"Bad in-place call: input tensor size {list(self.shape)} and output tensor size "
                               f"{list(value.shape)} should match")  # fmt: skip
        return self.copy_(value)

    return inplace


def _write(out: Any, value: Any) -> Any:
    """`value`, or where an `out=` tensor is given (its dtype checked before the product), `value` copied into it as
    ATen's structured products do: an `out` of another shape resized (contiguous), one of the right shape keeping
    its strides."""
    if out is None:
        return value
    aten_rules.resize_out(out, value.shape)
    return out.copy_(value)


def install() -> None:
    """Register the kernels for `REPLACED` on torch's CPU dispatch key (a no-op when installed; imports torch).
    Called by `numerics.exact()`, which removes them again with `uninstall()`."""
    if installed():
        return
    import torch

    library = torch.library.Library("aten", "IMPL")
    forms = {
        "mm": mm,
        "mm.out": mm,
        "bmm": bmm,
        "bmm.out": bmm,
        "addmm": addmm,
        "addmm_": _inplace(addmm),
        "addmm.out": addmm,
        "baddbmm": baddbmm,
        "baddbmm_": _inplace(baddbmm),
        "baddbmm.out": baddbmm,
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
