"""The elementwise functions deterministic mode takes away from MKL's vector math and computes with numpy instead.

ATen hands torch's CPU `sqrt`, `log`, `tan`, `asin`, `acos` and `atan` (among others) to MKL's vector-math library
(VML). Even under `MKL_CBWR=COMPATIBLE` these six give other bits under QEMU's models of an Intel Haswell, an AMD EPYC
Rome and an Intel Skylake Server than on a real Intel Xeon (`sqrt` on every input range; the others on some), while
MKL's `exp`, `erf`, `sin`, `cos`, `tanh`, ... and every other torch kernel used here give the same bits: so these six
depend on how the CPU computes something beyond IEEE arithmetic (an approximate instruction, as `rsqrtps` is), which
differs between CPU vendors as it does between QEMU and the hardware. In deterministic mode their CPU kernels are
replaced, for every dtype and for the out-of-place, in-place and `out=` forms, by numpy's, which numpy computes with
IEEE arithmetic only under the pins (`sqrt` correctly rounded). Autograd's formulas are unchanged (they sit above the
CPU kernels); `torch.optim`'s `_foreach_sqrt` reaches the replacement through `sqrt`. `x ** 0.5` does not: ATen's
`pow` calls MKL's `sqrt` directly, so clods-bench writes `torch.sqrt`.
"""

from __future__ import annotations

import warnings
from typing import Any, Callable

from clods_bench.numerics import aten_rules

REPLACED = ("sqrt", "log", "tan", "asin", "acos", "atan")
"""The ATen functions whose CPU kernels deterministic mode replaces (names of `torch` functions and numpy ufuncs'
torch names)."""

_NUMPY_NAME = {"sqrt": "sqrt", "log": "log", "tan": "tan", "asin": "arcsin", "acos": "arccos", "atan": "arctan"}
_state: dict[str, Any] = {"library": None}


def installed() -> bool:
    """Whether the replacement kernels are registered in this process."""
    return _state["library"] is not None


def evaluate(ufunc: Callable[[Any], Any], values: Any) -> Any:
    """numpy's `ufunc` on a contiguous array: where every replaced kernel makes its values (a test can spy on it)."""
    return ufunc(values)


def _result_dtype(x: Any) -> Any:
    """The dtype ATen gives these functions' result: the input's if floating or complex, else the default float."""
    import torch

    return x.dtype if (x.dtype.is_floating_point or x.dtype.is_complex) else torch.get_default_dtype()


def _kernel(ufunc: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """An out-of-place CPU kernel computing `ufunc` with numpy: integers and bool promote to torch's default float
    dtype, as ATen does; half, bfloat16 and complex-half go through float32 / complex64 and back. The result is laid
    out as ATen's elementwise kernels lay it out: contiguous for a contiguous or empty input, else following the
    input's strides (`torch.empty_like`: channels-last stays channels-last, a transposed input gives a transposed
    result). The values are the ufunc's on a contiguous copy whatever the layout."""
    import numpy as np
    import torch

    wide = {torch.float16: torch.float32, torch.bfloat16: torch.float32, torch.complex32: torch.complex64}

    def kernel(x: torch.Tensor) -> torch.Tensor:
        dtype = _result_dtype(x)
        if x.numel() == 0:  # nothing to compute; laid out contiguously, as ATen's empty results are
            return torch.empty(x.shape, dtype=dtype)
        target = wide.get(dtype, dtype)
        work = x if x.dtype == target else x.to(target)
        with np.errstate(all="ignore"):  # a 0-d input gives a numpy scalar: asarray keeps it 0-d
            out = torch.from_numpy(np.asarray(evaluate(ufunc, work.detach().resolve_conj().resolve_neg().contiguous().numpy())))
        out = out if out.dtype == dtype else out.to(dtype)
        if x.is_contiguous():
            return out
        laid_out = torch.empty_like(x, dtype=dtype)  # ATen's output follows the input's layout (channels-last, ...)
        return laid_out.copy_(out)

    return kernel


def _inplace(compute: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """The in-place form: ATen's error where the result's dtype cannot be stored in `x` (an integer or bool tensor)."""

    def inplace(x: Any) -> Any:
        aten_rules.check_cast(_result_dtype(x), x.dtype)
        return x.copy_(compute(x))

    return inplace


def _out_form(compute: Callable[[Any], Any]) -> Callable[..., Any]:
    """The `out=` form: ATen's error for an `out` of a dtype the result cannot be cast to; an `out` of another shape
    resized and laid out as the out-of-place result; one of the right shape keeps its strides."""

    def out_form(x: Any, *, out: Any) -> Any:
        aten_rules.check_cast(_result_dtype(x), out.dtype)
        value = compute(x)
        aten_rules.resize_out(out, value.shape, value.stride())
        return out.copy_(value)

    return out_form


def install() -> None:
    """Register the kernels for `REPLACED` on torch's CPU dispatch key (a no-op when installed; imports torch).
    Called by `numerics.exact()`, which removes them again with `uninstall()`."""
    if installed():
        return
    import numpy as np
    import torch

    library = torch.library.Library("aten", "IMPL")
    with warnings.catch_warnings():  # "Overriding a previously registered kernel": that is the point
        warnings.simplefilter("ignore")
        for name in REPLACED:
            compute = _kernel(getattr(np, _NUMPY_NAME[name]))
            library.impl(name, compute, "CPU")
            library.impl(f"{name}_", _inplace(compute), "CPU")
            library.impl(f"{name}.out", _out_form(compute), "CPU")
    _state["library"] = library


def uninstall() -> None:
    """Remove the replacement kernels: torch's own CPU kernels for `REPLACED` are back (a no-op when not installed)."""
    library = _state["library"]
    if library is not None:
        library._destroy()
        _state["library"] = None
