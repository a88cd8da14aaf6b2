"""`bench threads`: the speed-up against the first count, the families whose bits move, and a noisy timing left out."""

from __future__ import annotations

import math

import pytest
from rich.console import Console

from clods_bench.benchmark.speed import thread_bench


def test_speedup_bits_and_noise(monkeypatch: pytest.MonkeyPatch) -> None:
    runs = iter([
        {"train_s_per_step": 0.20, "digests": {"graph net": "a", "renderer fit": "r"}},   # 1 thread, round 1
        {"train_s_per_step": -0.30, "digests": {"graph net": "b", "renderer fit": "r"}},  # 2 threads: a load burst
        {"train_s_per_step": 0.21, "digests": {"graph net": "a", "renderer fit": "r"}},
        {"train_s_per_step": 0.10, "digests": {"graph net": "b", "renderer fit": "r"}},
    ])  # fmt: skip
    monkeypatch.setattr(thread_bench, "_measure", lambda n, frames: next(runs))
    out = thread_bench.bench_threads(Console(quiet=True), counts=(1, 2), rounds=2)
    assert out[1]["train_s_per_step"] == 0.20 and out[2]["train_s_per_step"] == 0.10  # the negative one never counts
    assert math.isclose(out[2]["speedup"], 2.0)
    assert out[2]["same_bits"] == {"graph net": False, "renderer fit": True}


def test_bad_counts_are_refused() -> None:
    from clods_bench.errors import ClodsError

    with pytest.raises(ClodsError, match="thread counts must be >= 1"):
        thread_bench.bench_threads(Console(quiet=True), counts=(0, 2))
