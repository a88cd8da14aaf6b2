"""`bench determinism`: the two modes alternate in child processes at one thread count; ratios of the best runs."""

from __future__ import annotations

import itertools

import pytest
from rich.console import Console

from clods_bench import numerics as dm
from clods_bench.benchmark.speed import determinism_bench


def test_modes_alternate_and_the_best_of_each_is_compared(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []
    times = itertools.cycle([{"x": 3.0}, {"x": 2.0}, {"x": 2.5}, {"x": 4.0}])  # det, host, det, host

    def fake(deterministic: bool, frames: int, repeats: int) -> dict[str, float]:
        calls.append(deterministic)
        return dict(next(times))

    monkeypatch.setattr(determinism_bench, "_measure", fake)
    result = determinism_bench.bench_determinism(Console(quiet=True), rounds=2)
    assert calls == [True, False, True, False]
    assert result == {"x": {"host": 2.0, "deterministic": 2.5, "ratio": 1.25}}


def test_both_children_run_at_deterministic_modes_thread_count_and_only_one_is_pinned() -> None:
    det, host = determinism_bench._child_env(True), determinism_bench._child_env(False)
    n = str(dm.threads())
    assert det["OMP_NUM_THREADS"] == host["OMP_NUM_THREADS"] == n and det["NUMBA_NUM_THREADS"] == host["NUMBA_NUM_THREADS"] == n
    assert det[dm.SWITCH_ENV] == "1" and host[dm.SWITCH_ENV] == "0"
    assert det["MKL_CBWR"] == "COMPATIBLE" and host.get("MKL_CBWR") != "COMPATIBLE"
