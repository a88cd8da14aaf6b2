"""What the CPU is and whether it runs the pinned paths: read from /proc/cpuinfo, without loading any numeric library."""

from __future__ import annotations

import functools
import platform

REQUIRED_FEATURES = ("avx2", "fma", "f16c")
"""The instruction sets every pinned path uses (the AVX2 branches of ATen, oneDNN, numba, numpy and OpenBLAS)."""


@functools.lru_cache(maxsize=1)
def _cpuinfo() -> str | None:
    """/proc/cpuinfo's text, read once (None where there is none)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            return fh.read()
    except OSError:
        return None


def _first_processor(cpuinfo: str | None = None) -> dict[str, str] | None:
    """The fields of the first processor in /proc/cpuinfo (Linux) or in the text given; None where unreadable."""
    if cpuinfo is None:
        cpuinfo = _cpuinfo()
        if cpuinfo is None:
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
    return [f for f in REQUIRED_FEATURES if f not in flags]


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
