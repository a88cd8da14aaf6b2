"""Exact numerics, the bottom layer: the same command gives the same bits on every x86-64 CPU with AVX2.

Two parts, neither applied on import:

- `pin_environment()` sets the variables that pin MKL, oneDNN, ATen, numba, numpy and OpenBLAS to code paths every
  AVX2 CPU runs alike (`pins`). They are read once, when each library loads, so the call comes first: the
  `clods-bench` console script makes it before importing anything numeric.
- `exact()`, a context manager, registers kernels for torch's `mm`, `addmm`, `bmm`, `baddbmm` (`fma_gemm`) and
  `sqrt`, `log`, `tan`, `asin`, `acos`, `atan` (numpy's) with ATen's semantics, and removes them on exit. The CLI,
  the runner and every executor worker enter it; in a notebook or a plugin's own tests::

      from clods_bench import numerics
      numerics.pin_environment()      # before numpy / torch are imported
      import torch
      with numerics.exact():
          ...                         # the benchmark's bits

Importing this package or any module of clods_bench changes nothing in the process.
"""

from __future__ import annotations

from clods_bench.numerics.cpu import cpu_flags, cpu_model, missing_cpu_features
from clods_bench.numerics.pinning import (
    PINS_VERSION,
    SWITCH_ENV,
    THREADS_ENV,
    host_environ,
    loaded_too_early,
    missing_pins,
    pin_environment,
    pins,
    requested,
    threads,
    unpin_environment,
)
from clods_bench.numerics.scope import ExactNumericsError, active, check, describe, exact, maybe_exact, numeric_mode

__all__ = [
    "PINS_VERSION",
    "SWITCH_ENV",
    "THREADS_ENV",
    "ExactNumericsError",
    "active",
    "check",
    "cpu_flags",
    "cpu_model",
    "describe",
    "exact",
    "host_environ",
    "loaded_too_early",
    "maybe_exact",
    "missing_cpu_features",
    "missing_pins",
    "numeric_mode",
    "pin_environment",
    "pins",
    "requested",
    "threads",
    "unpin_environment",
]
