"""Seed every random number generator a task may use, so one config and seed give the same numbers twice."""

from __future__ import annotations

import os
import random
from typing import Any

import numpy as np

from clods_bench.numerics import exact_math, exact_matmul, fma_gemm

# The runner sets these before each seed; a seed's numbers then depend only on (config, seed, machine, thread count).
SEED_ENV = "CLODS_BENCH_SEED"


def seed_everything(seed: int, torch_threads: int | None = None) -> None:
    """Seed Python's `random`, NumPy's global RNG and torch (CPU and CUDA); optionally fix torch's CPU threads.

    Plugins should still draw from their own generators (`np.random.default_rng(seed)`,
    `torch.Generator().manual_seed(seed)`); this covers code that uses the global ones.
    cuDNN is switched to deterministic kernels (no autotuning), which matters on GPU machines only.
    """
    seed = int(seed)
    os.environ[SEED_ENV] = str(seed)
    random.seed(seed)
    np.random.seed(seed % 2**32)
    try:
        import torch
    except ImportError:  # torch is a dependency, but a plugin-only environment may lack it
        return
    torch.manual_seed(seed)
    if torch_threads is not None:
        torch.set_num_threads(int(torch_threads))
    if torch.backends.cudnn.is_available():
        torch.backends.cudnn.deterministic = True
        torch.backends.cudnn.benchmark = False


def openblas_core() -> str:
    """The kernel numpy's OpenBLAS runs (its `get_corename`, e.g. 'Haswell'), or 'unknown' where it cannot be asked
    (not Linux, or a numpy built on another BLAS)."""
    import ctypes
    import re

    import numpy  # noqa: F401  (loads the library)

    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = sorted(set(re.findall(r"(/\S*openblas\S*\.so\S*)", fh.read())))
    except OSError:
        return "unknown"
    for path in paths:
        lib = ctypes.CDLL(path)
        for name in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename64_", "openblas_get_corename"):
            fn = getattr(lib, name, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                return fn().decode().strip()
    return "unknown"


def effective_paths() -> dict[str, Any]:
    """The code paths the numeric libraries actually use in this process (imports numpy, torch and numba)."""
    import numba
    import torch

    try:
        from numpy._core import _multiarray_umath as umath  # numpy >= 2
    except ImportError:  # pragma: no cover - numpy 1.26
        from numpy.core import _multiarray_umath as umath
    features, targets = umath.__cpu_features__, umath.__cpu_dispatch__
    above_avx2 = [t for t in targets if t.startswith(("X86_V4", "AVX512"))]
    return {
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "torch_threads": torch.get_num_threads(),
        "numpy_dispatch_above_avx2": sorted(t for t in above_avx2 if features.get(t)),
        "numba_cpu_name": numba.config.CPU_NAME or "host",
        "numba_threads": numba.get_num_threads(),
        "mkl_cbwr": os.environ.get("MKL_CBWR", "host"),
        "onednn_max_isa": os.environ.get("ONEDNN_MAX_CPU_ISA", "host"),
        "torch_functions_on_numpy": list(exact_math.REPLACED) if exact_math.installed() else [],
        "torch_products_on_fma_gemm": list(exact_matmul.REPLACED) if exact_matmul.installed() else [],
        "fma_gemm_isa": fma_gemm.host_isa() if exact_matmul.installed() else "not used",
        "openblas_core": openblas_core(),
    }
