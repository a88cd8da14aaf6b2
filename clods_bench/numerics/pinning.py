"""The environment that pins every numeric library's floating-point path, set before those libraries load.

Every numeric library below picks a floating-point code path by the CPU it runs on (instruction set, vendor) and
by its thread count, and reads an environment variable that pins it once, when it loads. Nothing sets them on
import: the `clods-bench` console script calls `pin_environment()` before it imports numpy, torch or numba (worker
processes inherit them), and a library user does the same at the top of a script or notebook, or exports
`clods-bench numerics --export` before Python starts. `numerics.exact()` refuses to start without them.

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

This module imports nothing numeric: it must be usable before those libraries load.
"""

from __future__ import annotations

import json
import os
import sys

from clods_bench.numerics.cpu import missing_cpu_features

SWITCH_ENV = "CLODS_BENCH_DETERMINISTIC"
"""0/false/no/off: the CLI and the runner stay on the host's own (fastest) paths and enter no exact scope."""
THREADS_ENV = "CLODS_BENCH_THREADS"
BEFORE_PINS_ENV = "CLODS_BENCH_ENV_BEFORE_PINS"
"""Set by `pin_environment()`: the pinned variables' values before the pins (JSON), for `host_environ()`."""
PINS_VERSION = 4
"""Bumped whenever the pins change: numbers made under other pins are not comparable bit for bit."""

NUMERIC_MODULES = ("numpy", "torch", "numba", "scipy")
_FALSE = ("0", "false", "no", "off")

# numpy's dispatch targets above AVX2: numpy 2.4 groups them as X86_V4 and its successors; earlier releases name each
# AVX-512 set (a name numpy does not dispatch to costs an ImportWarning, so only the installed release's are given).
_NUMPY_ABOVE_AVX2 = {"new": "X86_V4 AVX512_ICL AVX512_SPR",
                     "old": "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"}  # fmt: skip
_PINNED_BY = {"numpy": ("NPY_DISABLE_CPU_FEATURES",), "torch": ("MKL_CBWR", "ONEDNN_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY"),
              "numba": ("NUMBA_CPU_NAME",), "scipy": ("OPENBLAS_CORETYPE",)}  # fmt: skip
_state: dict[str, list[str]] = {"late": []}


def _numpy_above_avx2() -> str:
    """NPY_DISABLE_CPU_FEATURES for the installed numpy, read from its metadata (numpy itself must not load yet)."""
    try:
        from importlib.metadata import version

        major, minor = (int(x) for x in version("numpy").split(".")[:2])
    except Exception:  # noqa: BLE001 - no numpy metadata: the newer names
        return _NUMPY_ABOVE_AVX2["new"]
    return _NUMPY_ABOVE_AVX2["new" if (major, minor) >= (2, 4) else "old"]


def requested() -> bool:
    """Whether exact numerics are asked for: unless $CLODS_BENCH_DETERMINISTIC says 0/false/no/off."""
    return os.environ.get(SWITCH_ENV, "1").strip().lower() not in _FALSE


def threads() -> int:
    """Threads per job in the exact scope: $CLODS_BENCH_THREADS (default 1; a bad value counts as 1)."""
    try:
        n = int(os.environ.get(THREADS_ENV, "1"))
    except ValueError:
        return 1
    return n if n >= 1 else 1


def pins(n_threads: int | None = None) -> dict[str, str]:
    """The environment the pins set (on a CPU without AVX2 OPENBLAS_CORETYPE is left alone: Haswell's kernel would
    stop numpy's import with an illegal instruction before anything can name the missing feature)."""
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
        env["OPENBLAS_CORETYPE"] = "Haswell"  # numpy's and scipy's products: a kernel every AVX2 CPU runs
    return env


def pin_environment() -> list[str]:
    """Set the pins in `os.environ`, to be called before numpy, torch or numba load (the console script does; a
    library user calls it first thing). Returns the numeric libraries already loaded without them (they stay on the
    host's paths; `numerics.exact()` then refuses to start and names them)."""
    wanted = pins()
    late = [m for m in NUMERIC_MODULES if m in sys.modules and any(k in wanted and os.environ.get(k) != wanted[k] for k in _PINNED_BY[m])]
    _state["late"] = sorted(set(_state["late"]) | set(late))
    before: dict[str, str | None] = {}
    inherited = os.environ.get(BEFORE_PINS_ENV)  # a parent process pinned them already: its originals
    if inherited:
        try:
            before.update({str(k): (None if v is None else str(v)) for k, v in json.loads(inherited).items()})
        except (ValueError, AttributeError):
            pass
    for key, value in wanted.items():
        before.setdefault(key, os.environ.get(key))
        os.environ[key] = value
    os.environ[BEFORE_PINS_ENV] = json.dumps(before, sort_keys=True)
    return list(late)


def unpin_environment() -> None:
    """Put back the environment from before the pins (a parent clods-bench process's, or ones exported by hand), so
    that libraries loaded afterwards take the host's own paths: what `--no-deterministic` does in a fresh process."""
    host = host_environ()
    for key in [k for k in os.environ if k not in host]:
        del os.environ[key]
    os.environ.update(host)


def missing_pins() -> list[str]:
    """The pinned variables that the environment lacks or holds another value for (empty when all are set)."""
    return [f"{k}={v}" for k, v in pins().items() if os.environ.get(k) != v and k != "CLODS_BENCH_MAX_THREADS"]


def loaded_too_early() -> list[str]:
    """Numeric libraries that were loaded before `pin_environment()` with other values in the environment."""
    return list(_state["late"])


def host_environ() -> dict[str, str]:
    """`os.environ` as it was before the pins (this process's or a parent's), with the switch off: for running a
    command on the host's own paths in a child process. A pin set by hand (`numerics --export`) is removed."""
    env = dict(os.environ)
    try:
        before = json.loads(env.get(BEFORE_PINS_ENV, "{}"))
    except ValueError:
        before = {}
    for key, pinned in pins().items():
        old = before[key] if key in before else (None if env.get(key) == pinned else env.get(key))
        if old is None:
            env.pop(key, None)
        else:
            env[key] = old
    env.pop(BEFORE_PINS_ENV, None)
    env[SWITCH_ENV] = "0"
    return env
