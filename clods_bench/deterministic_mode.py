"""Deterministic mode: the same command gives the same bits on every x86-64 CPU with AVX2 (on by default).

Every numeric library below picks a floating-point code path by the CPU it runs on (instruction set, vendor) and
by its thread count, and reads an environment variable that pins it once, when it loads. `apply()` sets them
before clods-bench imports numpy, torch or numba (it runs when the `clods_bench` package is imported), and worker
processes inherit them:

| library (what it computes here)          | variable                 | pinned to                        |
| ---------------------------------------- | ------------------------ | -------------------------------- |
| MKL (torch's rarer products, exp, ...)   | MKL_CBWR                 | COMPATIBLE (the AVX2 branch is    |
|                                          |                          | not honoured on AMD CPUs)        |
| oneDNN (torch's convolutions)            | ONEDNN_MAX_CPU_ISA       | AVX2                             |
| ATen's vectorised kernels (torch)        | ATEN_CPU_CAPABILITY      | avx2                             |
| numba (splatting, rasterizer, solver)    | NUMBA_CPU_NAME           | haswell                          |
| numpy's SIMD dispatch                    | NPY_DISABLE_CPU_FEATURES | every target above AVX2          |
| OpenBLAS (numpy's and scipy's products)  | OPENBLAS_CORETYPE        | Haswell                          |
| threads (OpenMP, MKL, OpenBLAS, numba,   | OMP_NUM_THREADS, ...     | CLODS_BENCH_THREADS (default 1)  |
| torch)                                   |                          | per job                          |

Two more things are not environment variables. MKL's vector `sqrt`, `log`, `tan`, `asin`, `acos` and `atan` depend on
the CPU even under COMPATIBLE, so when torch is imported their CPU kernels are replaced by numpy's (`exact_math`). And
MKL's COMPATIBLE GEMMs are SSE2 code (its AVX2 branch depends on the CPU's vendor), so torch's `mm`, `addmm`, `bmm`
and `baddbmm` go to `fma_gemm`, whose kernels give the same bits at AVX2 and at AVX-512 width (`exact_matmul`).

`CLODS_BENCH_DETERMINISTIC=0` (or `clods-bench --no-deterministic`) leaves every library on the host's own
(fastest) paths; records and caches made that way are kept apart from deterministic ones.
This module imports nothing numeric: it must run before those libraries load.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import json
import os
import platform
import sys
from typing import Any

SWITCH_ENV = "CLODS_BENCH_DETERMINISTIC"
THREADS_ENV = "CLODS_BENCH_THREADS"
BEFORE_PINS_ENV = "CLODS_BENCH_ENV_BEFORE_PINS"
"""Set by `apply()`: the pinned variables' values before the pins (JSON), for child processes' `host_environ()`."""
PINS_VERSION = 4
"""Bumped whenever the pins change: numbers made under other pins are not comparable bit for bit."""

NUMERIC_MODULES = ("numpy", "torch", "numba", "scipy")
_FALSE = ("0", "false", "no", "off")

# numpy's dispatch targets above AVX2: numpy 2.4 groups them as X86_V4 and its successors; earlier releases name each
# AVX-512 set (a name numpy does not dispatch to costs an ImportWarning, so only the installed release's are given).
_NUMPY_ABOVE_AVX2 = {"new": "X86_V4 AVX512_ICL AVX512_SPR",
                     "old": "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"}  # fmt: skip


def _numpy_above_avx2() -> str:
    """NPY_DISABLE_CPU_FEATURES for the installed numpy, read from its metadata (numpy itself must not load yet)."""
    try:
        from importlib.metadata import version

        major, minor = (int(x) for x in version("numpy").split(".")[:2])
    except Exception:  # noqa: BLE001 - no numpy metadata: the newer names
        return _NUMPY_ABOVE_AVX2["new"]
    return _NUMPY_ABOVE_AVX2["new" if (major, minor) >= (2, 4) else "old"]

_original: dict[str, str | None] = {}
_state: dict[str, Any] = {"applied": False, "late": []}


_PINNED_BY = {"numpy": ("NPY_DISABLE_CPU_FEATURES",), "torch": ("MKL_CBWR", "ONEDNN_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY"),
              "numba": ("NUMBA_CPU_NAME",), "scipy": ("OPENBLAS_CORETYPE",)}


def enabled() -> bool:
    """Whether deterministic mode is on: unless $CLODS_BENCH_DETERMINISTIC says 0/false/no/off."""
    return os.environ.get(SWITCH_ENV, "1").strip().lower() not in _FALSE


def threads() -> int:
    """Threads per job in deterministic mode: $CLODS_BENCH_THREADS (default 1; a bad value counts as 1)."""
    try:
        n = int(os.environ.get(THREADS_ENV, "1"))
    except ValueError:
        return 1
    return n if n >= 1 else 1


def pins(n_threads: int | None = None) -> dict[str, str]:
    """The environment deterministic mode sets (on a CPU without AVX2 it leaves OPENBLAS_CORETYPE alone: Haswell's
    kernel would stop numpy's import with an illegal instruction before the run can name the missing feature)."""
    n = str(threads() if n_threads is None else int(n_threads))
    env = {
        "MKL_CBWR": "COMPATIBLE",
        "ONEDNN_MAX_CPU_ISA": "AVX2",
        "DNNL_MAX_CPU_ISA": "AVX2",
        "ATEN_CPU_CAPABILITY": "avx2",
        "NUMBA_CPU_NAME": "haswell",
        "NPY_DISABLE_CPU_FEATURES": _numpy_above_avx2(),
        "OMP_NUM_THREADS": n,
        "MKL_NUM_THREADS": n,
        "OPENBLAS_NUM_THREADS": n,
        "NUMBA_NUM_THREADS": n,
        "CLODS_BENCH_MAX_THREADS": n,
    }
    if not missing_cpu_features():
        env["OPENBLAS_CORETYPE"] = _openblas_core()
    return env


def _openblas_core() -> str:
    """OpenBLAS's kernel: Haswell's, which every AVX2 CPU runs, whatever the environment chose (numpy's and scipy's
    products go through it, so another kernel would give other bits)."""
    return "Haswell"


def apply() -> None:
    """Set the pins in `os.environ` (once; a no-op when the mode is off), noting any numeric library loaded before."""
    if _state["applied"] or not enabled():
        return
    wanted = pins()
    _state["late"] = [m for m in NUMERIC_MODULES if m in sys.modules and any(k in wanted and os.environ.get(k) != wanted[k] for k in _PINNED_BY[m])]
    inherited = os.environ.get(BEFORE_PINS_ENV)  # a parent clods-bench process pinned them already: its originals
    if inherited:
        try:
            _original.update({str(k): (None if v is None else str(v)) for k, v in json.loads(inherited).items()})
        except (ValueError, AttributeError):
            pass
    for key, value in wanted.items():
        _original.setdefault(key, os.environ.get(key))
        os.environ[key] = value
    os.environ[BEFORE_PINS_ENV] = json.dumps(_original, sort_keys=True)
    _state["applied"] = True
    if "torch" in sys.modules:
        install_kernels()
    elif not any(isinstance(f, _AfterTorchImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterTorchImport())


class _AfterTorchImport(importlib.abc.MetaPathFinder):
    """Finds `torch` as the other finders do and has `install_kernels()` run once torch has loaded. It stays on
    `sys.meta_path` until then: `importlib.util.find_spec("torch")` (a library asking whether torch is there) comes
    through here too without loading anything."""

    def __init__(self) -> None:
        self._searching = False

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != "torch" or self._searching:
            return None
        self._searching = True  # the search below passes through this finder again
        try:
            spec = importlib.util.find_spec(fullname)
        finally:
            self._searching = False
        if spec is not None and spec.loader is not None:
            spec.loader = _InstallAfterExec(spec.loader)
        return spec


class _InstallAfterExec(importlib.abc.Loader):
    """torch's own loader (every other attribute is passed through), then the replacement kernels."""

    def __init__(self, inner: Any) -> None:
        self._inner = inner

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def create_module(self, spec: Any) -> Any:
        return self._inner.create_module(spec)

    def exec_module(self, module: Any) -> None:
        self._inner.exec_module(module)
        sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _AfterTorchImport)]
        install_kernels()


def install_kernels() -> None:
    """Register deterministic mode's replacements for torch's CPU kernels (`exact_math`, `exact_matmul`)."""
    from clods_bench import exact_math, exact_matmul

    exact_math.install()
    exact_matmul.install()


def host_environ() -> dict[str, str]:
    """`os.environ` as it was before the pins (this process's or a parent's), with the mode switched off: for
    re-running a command on host paths. A pin set by hand (`numerics --export`) is removed."""
    env = dict(os.environ)
    for key, pinned in pins().items():
        before = _original[key] if key in _original else (None if env.get(key) == pinned else env.get(key))
        if before is None:
            env.pop(key, None)
        else:
            env[key] = before
    env.pop(BEFORE_PINS_ENV, None)
    env[SWITCH_ENV] = "0"
    return env


def loaded_too_early() -> list[str]:
    """Numeric libraries imported before `apply()` whose pins were not in the environment already (`clods-bench
    numerics --export`): they run on the host's paths."""
    return list(_state["late"])


def _first_processor(cpuinfo: str | None = None) -> dict[str, str] | None:
    """The fields of the first processor in /proc/cpuinfo (Linux) or in the text given; None where unreadable."""
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
                cpuinfo = fh.read()
        except OSError:
            return None
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            break
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields


def cpu_flags() -> set[str] | None:
    """The CPU's feature flags from /proc/cpuinfo (Linux), or None where they cannot be read."""
    fields = _first_processor()
    return set(fields["flags"].split()) if fields and "flags" in fields else None


def missing_cpu_features() -> list[str]:
    """What this CPU lacks for the pinned paths: x86-64 itself, or AVX2/FMA/F16C (empty when all is there or unknown)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return [f"x86-64 (this CPU is {platform.machine() or 'unknown'})"]
    flags = cpu_flags()
    if flags is None:
        return []
    return [f for f in ("avx2", "fma", "f16c") if f not in flags]


def cpu_model(cpuinfo: str | None = None) -> str:
    """The CPU's model name with its family, model and widest vector set (Linux /proc/cpuinfo, or the text given),
    else `platform.processor()`: virtual machines often report only "AMD EPYC" or "Intel Xeon Processor"."""
    fields = _first_processor(cpuinfo) or {}
    name = fields.get("model name")
    if not name:
        return platform.processor() or platform.machine()
    flags = set(fields.get("flags", "").split())
    width = "AVX-512" if {"avx512f", "avx512dq", "avx512bw", "avx512vl"} <= flags else "AVX2" if "avx2" in flags else "no AVX2"
    family, model = fields.get("cpu family"), fields.get("model")
    where = f"family {family}, model {model}, " if family and model else ""
    return f"{name} ({where}{width})"


def numeric_mode() -> str:
    """'deterministic' or 'host': joins the identity of records and caches, so the two never mix."""
    return "deterministic" if enabled() else "host"


def _product_kernels() -> str:
    """The instruction set of `fma_gemm`'s kernels in use (informative: both give the same bits)."""
    try:
        from clods_bench import fma_gemm

        return fma_gemm.host_isa()
    except (ImportError, ValueError) as exc:
        return f"unknown ({exc})"


def describe() -> dict[str, Any]:
    """What a record says of the numeric paths it was made with (in deterministic mode this loads numpy and
    llvmlite, after the pins, to name the product kernels' instruction set)."""
    out: dict[str, Any] = {"mode": numeric_mode(), "cpu": cpu_model()}
    if enabled():
        from clods_bench import exact_math, exact_matmul

        out.update({"pins_version": PINS_VERSION, "threads": threads(), "exact_math": list(exact_math.REPLACED),
                    "exact_matmul": list(exact_matmul.REPLACED), "product_kernels": _product_kernels(),
                    "pins": {k: os.environ.get(k) for k in sorted(pins())}})  # fmt: skip
    return out
