"""ATen's rules for results that the replacement kernels (`exact_math`, `exact_matmul`) follow: which dtypes an `out=`
or in-place result may take, how an `out=` tensor is resized, and ATen's own error messages. Shapes, dtypes, strides
and errors only: nothing here computes a value."""

from __future__ import annotations

import warnings
from typing import Any

_SCALAR_TYPE = {"float32": "Float", "float64": "Double", "float16": "Half", "bfloat16": "BFloat16", "complex32": "ComplexHalf",
                "complex64": "ComplexFloat", "complex128": "ComplexDouble", "int64": "Long", "int32": "Int", "int16": "Short",
                "int8": "Char", "uint8": "Byte", "bool": "Bool"}  # fmt: skip
_CPP_TYPE = {"float32": "float", "float64": "double", "float16": "c10::Half", "bfloat16": "c10::BFloat16",
             "complex32": "c10::complex<c10::Half>", "complex64": "c10::complex<float>", "complex128": "c10::complex<double>",
             "int64": "long int", "int32": "int", "int16": "short int", "int8": "signed char", "uint8": "unsigned char", "bool": "bool"}  # fmt: skip


def _short(dtype: Any) -> str:
    return str(dtype).removeprefix("torch.")


def scalar_type(dtype: Any) -> str:
    """ATen's ScalarType name of a torch dtype ('Float' for torch.float32), as its messages write it."""
    return _SCALAR_TYPE.get(_short(dtype), _short(dtype))


def cpp_type(dtype: Any) -> str:
    """The C++ type name ATen's messages give a torch dtype ('float' for torch.float32)."""
    return _CPP_TYPE.get(_short(dtype), _short(dtype))


def check_cast(result: Any, target: Any) -> None:
    """Raise ATen's error where an elementwise result of dtype `result` cannot be stored into a `target` tensor (an
    integer `out=` or in-place tensor for a floating result, a real one for a complex result)."""
    import torch

    if not torch.can_cast(result, target):
        raise RuntimeError(f"result type {scalar_type(result)} can't be cast to the desired output type {scalar_type(target)}")


def check_out_dtype(out: Any, dtype: Any) -> None:
    """Raise ATen's error of its structured product kernels where `out` has another dtype than the result."""
    if out.dtype != dtype:
        raise RuntimeError(f"Expected out tensor to have dtype {cpp_type(dtype)}, but got {cpp_type(out.dtype)} instead")


def resize_out(out: Any, shape: Any, strides: Any = None) -> None:
    """Resize `out` to `shape` as ATen's `resize_output` does (a warning when it had elements), then lay it out with
    `strides` (the layout a fresh result would have) where given; an `out` of the right shape keeps its strides."""
    shape = tuple(shape)
    if tuple(out.shape) == shape:
        return
    if out.numel() != 0:
        warnings.warn(f"An output with one or more elements was resized since it had shape {list(out.shape)}, which does not "
                      f"match the required output shape {list(shape)}. This behavior is deprecated, and in a future PyTorch "
                      "release outputs will not be resized unless they have zero elements. You can explicitly reuse an out "
                      "tensor t by resizing it, inplace, to zero elements with t.resize_(0).", UserWarning, stacklevel=3)  # fmt: skip
    out.resize_(shape)
    if strides is not None and tuple(out.stride()) != tuple(strides):
        out.as_strided_(shape, tuple(strides))
