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

REPLACED = ("sqrt", "log", "tan", "asin", "acos", "atan")
"""The ATen functions whose CPU kernels deterministic mode replaces (names of `torch` functions and numpy ufuncs'
torch names)."""

_NUMPY_NAME = {"sqrt": "sqrt", "log": "log", "tan": "tan", "asin": "arcsin", "acos": "arccos", "atan": "arctan"}
_state: dict[str, Any] = {"library": None}


def installed() -> bool:
    """Whether the replacement kernels are registered in this process."""
    return _state["library"] is not None


def _kernel(ufunc: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """An out-of-place CPU kernel computing `ufunc` with numpy: integers promote to torch's default float dtype, as
    ATen does; half, bfloat16 and complex-half go through float32 / complex64 and back."""
    import numpy as np
    import torch

    wide = {torch.float16: torch.float32, torch.bfloat16: torch.float32, torch.complex32: torch.complex64}

    def kernel(x: torch.Tensor) -> torch.Tensor:
        dtype = x.dtype if (x.dtype.is_floating_point or x.dtype.is_complex) else torch.get_default_dtype()
        target = wide.get(dtype, dtype)
        work = x if x.dtype == target else x.to(target)
        with np.errstate(all="ignore"):  # a 0-d input gives a numpy scalar: asarray keeps it 0-d
            out = torch.from_numpy(np.asarray(ufunc(work.detach().resolve_conj().contiguous().numpy())))
        out = out if out.dtype == dtype else out.to(dtype)
        if x.is_contiguous():
            return out
        laid_out = torch.empty_like(x, dtype=dtype)  # ATen's output follows the input's layout (channels-last, ...)
        return laid_out.copy_(out)

    return kernel


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

            def inplace(x: torch.Tensor, _compute: Callable[[Any], Any] = compute) -> torch.Tensor:
                return x.copy_(_compute(x))

            def out_form(x: torch.Tensor, *, out: torch.Tensor, _compute: Callable[[Any], Any] = compute) -> torch.Tensor:
                value = _compute(x)
                if out.shape != value.shape:
                    out.resize_(value.shape)
                return out.copy_(value)

            library.impl(name, compute, "CPU")
            library.impl(f"{name}_", inplace, "CPU")
            library.impl(f"{name}.out", out_form, "CPU")
    _state["library"] = library


def uninstall() -> None:
    """Remove the replacement kernels: torch's own CPU kernels for `REPLACED` are back (a no-op when not installed)."""
    library = _state["library"]
    if library is not None:
        library._destroy()
        _state["library"] = None
