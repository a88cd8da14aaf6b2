"""The exact scope: inside `with exact():` torch's CPU products and six elementwise functions run on kernels that
give the same bits on every x86-64 CPU with AVX2; on leaving it, torch is as it was.

The CLI, the runner and every executor worker enter it; a library user can too (after `pin_environment()`, see
`clods_bench.numerics`). Every entry checks what the scope cannot fix by itself: a CPU without AVX2/FMA/F16C, pins
missing from the environment, or a numeric library loaded before them. The scope is
process-wide (torch's dispatch table is), re-entrant, and counts its entries: the kernels leave with the last exit.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Any, Iterator

from clods_bench.errors import ClodsError
import clods_bench.numerics.cpu as cpu
import clods_bench.numerics.pinning as pins

_lock = threading.RLock()
_state: dict[str, Any] = {"depth": 0, "restore": None}
_HINT = "or run with --no-deterministic (CLODS_BENCH_DETERMINISTIC=0): the host's own paths, not the committed tables' bits"


class ExactNumericsError(ClodsError):
    """The exact scope cannot hold in this process: what is missing and what to do."""


def _loaded_on_host_paths() -> list[str]:
    """Numeric libraries already loaded whose own report shows a path the pins forbid (AVX-512 dispatch)."""
    import sys

    wrong = []
    if "numpy" in sys.modules:
        try:
            from numpy._core import _multiarray_umath as umath  # numpy >= 2
        except ImportError:  # pragma: no cover - numpy 1.26
            from numpy.core import _multiarray_umath as umath
        if any(on for name, on in umath.__cpu_features__.items() if name.startswith(("X86_V4", "AVX512")) and name in umath.__cpu_dispatch__):
            wrong.append("numpy")
    if "torch" in sys.modules:
        import torch

        if torch.backends.cpu.get_cpu_capability().upper().startswith("AVX512"):
            wrong.append("torch")
    return wrong


def check() -> None:
    """Raise `ExactNumericsError` (one line: what is wrong, what to do) when the exact scope cannot hold here."""
    missing = cpu.missing_cpu_features()
    if missing:
        raise ExactNumericsError(f"exact numerics pin AVX2 code paths, and this CPU ({cpu.cpu_model()}) lacks {', '.join(missing)}",
                                 where="CPU", hint=_HINT[3:])  # fmt: skip
    unset = pins.missing_pins()
    if unset:
        raise ExactNumericsError(
            f"the numeric libraries' pins are not in the environment ({', '.join(unset[:3])}{', ...' if len(unset) > 3 else ''})",
            where="exact numerics",
            hint=f"call clods_bench.numerics.pin_environment() before importing numpy or torch, or export the output of `clods-bench numerics --export` before Python starts, {_HINT}",
        )  # fmt: skip
    late = sorted(set(pins.loaded_too_early()) | set(_loaded_on_host_paths()))
    if late:
        raise ExactNumericsError(
            f"{', '.join(late)} loaded before the pins were set, so {'its' if len(late) == 1 else 'their'} floating-point paths are the host's",
            where="exact numerics",
            hint=f"call clods_bench.numerics.pin_environment() before importing {late[0]}, or export the output of `clods-bench numerics --export` before Python starts, {_HINT}",
        )  # fmt: skip


def active() -> bool:
    """Whether this process is inside an exact scope now."""
    return _state["depth"] > 0


def _set_mkldnn_deterministic(value: bool) -> None:
    """Set oneDNN's deterministic flag, also after `torch.backends.disable_global_flags()` (which importing torch's
    test utilities calls, and which makes a bare assignment raise): the same flag either way."""
    import torch

    setter = getattr(torch._C, "_set_mkldnn_deterministic", None)
    if setter is None:  # pragma: no cover - a torch without the binding
        torch.backends.mkldnn.deterministic = value
    else:
        setter(value)


def _enter() -> None:
    with _lock:
        check()  # at every entry: a nested scope in a process that lost its footing says so too
        if _state["depth"] == 0:
            import torch

            from clods_bench.numerics import exact_math, exact_matmul

            restore = {"threads": torch.get_num_threads(), "mkldnn": getattr(torch.backends.mkldnn, "deterministic", None)}
            exact_math.install()
            exact_matmul.install()
            torch.set_num_threads(pins.threads())
            if restore["mkldnn"] is not None:
                _set_mkldnn_deterministic(True)  # oneDNN's reductions in a fixed order whatever the threads
            _state["restore"] = restore
        _state["depth"] += 1


def _exit() -> None:
    with _lock:
        if _state["depth"] <= 0:
            return
        _state["depth"] -= 1
        if _state["depth"] == 0:
            import torch

            from clods_bench.numerics import exact_math, exact_matmul

            exact_matmul.uninstall()
            exact_math.uninstall()
            restore = _state["restore"] or {}
            if restore.get("threads"):
                torch.set_num_threads(restore["threads"])
            if restore.get("mkldnn") is not None:
                _set_mkldnn_deterministic(restore["mkldnn"])
            _state["restore"] = None


@contextlib.contextmanager
def exact() -> Iterator[None]:
    """Run the block with exact numerics: the replacement kernels registered, torch at the pinned thread count and
    oneDNN deterministic; all undone when the outermost block exits. Raises `ExactNumericsError` where it cannot hold."""
    _enter()
    try:
        yield
    finally:
        _exit()


def maybe_exact() -> contextlib.AbstractContextManager[None]:
    """`exact()` where exact numerics are requested ($CLODS_BENCH_DETERMINISTIC not 0), else a no-op: what the runner
    and the workers enter."""
    return exact() if pins.requested() else contextlib.nullcontext()


def numeric_mode() -> str:
    """'deterministic' inside the exact scope, else 'host': joins the identity of records and caches, so the two never mix."""
    return "deterministic" if active() else "host"


def _product_kernels() -> str:
    """The instruction set of `fma_gemm`'s kernels in use (informative: both give the same bits)."""
    try:
        from clods_bench.numerics import fma_gemm

        return fma_gemm.host_isa()
    except (ImportError, ValueError) as exc:
        return f"unknown ({exc})"


def describe() -> dict[str, Any]:
    """What a record says of the numeric paths it was made with (inside the scope this loads llvmlite, to name the
    product kernels' instruction set)."""
    import os

    out: dict[str, Any] = {"mode": numeric_mode(), "cpu": cpu.cpu_model()}
    if active():
        from clods_bench.numerics import exact_math, exact_matmul

        out.update({"pins_version": pins.PINS_VERSION, "threads": pins.threads(), "exact_math": list(exact_math.REPLACED),
                    "exact_matmul": list(exact_matmul.REPLACED), "product_kernels": _product_kernels(),
                    "pins": {k: os.environ.get(k) for k in sorted(pins.pins())}})  # fmt: skip
    return out
