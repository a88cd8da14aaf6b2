"""`run` uses the machine by default: one worker per core, at most one per seed, with the bits of one worker."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from clods_bench.benchmark.running import executors
from clods_bench.cli import main
from tests.conftest import TINY


def _run(tmp: Path, *extra: str) -> dict:
    sets = [a for s in [*TINY, "seeds=[0,1]", f"runs_dir={tmp / 'runs'}", f"data.root={tmp / 'data'}"] for a in ("--set", s)]
    assert main(["run", "cdg", "--sim", "constvel", "--preset", "ci", "--no-progress", *sets, *extra]) == 0
    (record,) = list((tmp / "runs").rglob("record.json"))
    return json.loads(record.read_text())


def test_run_uses_one_worker_per_core_by_default_with_the_same_bits(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    made: list[int] = []
    real = executors.make_executor

    def spy(name: str, address: str | None = None, jobs: int = 1):  # type: ignore[no-untyped-def]
        made.append(jobs)
        return real(name, address, jobs)

    monkeypatch.setattr(executors, "make_executor", spy)
    monkeypatch.setattr(executors, "default_jobs", lambda: 4)  # a 4-core machine, a 2-seed run: 2 workers
    parallel = _run(tmp_path / "parallel")
    assert made == [2]
    serial = _run(tmp_path / "serial", "--jobs", "1")
    assert made == [2]  # --jobs 1 runs in the command's own process
    assert parallel["seeds"] == serial["seeds"] == [0, 1]
    for seed in ("0", "1"):  # every metric and stage digest equal (timings differ)
        assert parallel["per_seed"][seed]["metrics"] == serial["per_seed"][seed]["metrics"]
        assert parallel["per_seed"][seed]["extra"]["stage_digests"] == serial["per_seed"][seed]["extra"]["stage_digests"]
