"""The Ray executor runs the (run, seed) jobs of a sweep as Ray tasks and gives the local executor's numbers."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from rich.console import Console

from clods_bench.benchmark.executors import LocalExecutor, make_executor
from clods_bench.benchmark.records import RECORD_FILE
from clods_bench.benchmark.registry import default_registry
from clods_bench.benchmark.reproduce import reproduce
from clods_bench.errors import ClodsError
from tests.benchmark.test_reproduce import _overrides, _plan

TIMING = ("infer_ms_per_step", "fit_seconds")


def test_unknown_executor_is_a_clear_error() -> None:
    with pytest.raises(ClodsError, match="unknown executor 'dask'"):
        make_executor("dask")
    assert isinstance(make_executor("local"), LocalExecutor)


@pytest.mark.slow  # ~30 s on 2 shared cores: Ray's start (~15 s) and its workers' first imports (~15 s)
def test_ray_sweep_matches_local(tmp_path: Path, tiny_root: Path) -> None:
    ray = pytest.importorskip("ray")
    plan = _plan(tmp_path)
    local = reproduce("ci", tmp_path / "local", default_registry(), Console(quiet=True), "local", plan, _overrides(tiny_root, tmp_path / "runs_local"))
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        remote = reproduce("ci", tmp_path / "ray", default_registry(), Console(quiet=True), "ray", plan, _overrides(tiny_root, tmp_path / "runs_ray"))
    finally:
        ray.shutdown()
    assert remote["executor"] == "ray"
    ran = [r for r in remote["runs"] if r["same_as"] is None]
    assert len(ran) == 2 and all(r["seeds_run"] == [0, 1] for r in ran)  # 4 seed jobs went through Ray
    for a, b in zip(local["runs"], remote["runs"]):
        ra = json.loads((Path(a["record_dir"]) / RECORD_FILE).read_text())
        rb = json.loads((Path(b["record_dir"]) / RECORD_FILE).read_text())
        assert "runs_ray" in b["record_dir"]
        for seed in ("0", "1"):
            assert ra["per_seed"][seed]["metrics"] == rb["per_seed"][seed]["metrics"]
    for stem in ("t_cdg", "t_damp"):
        ta = pd.read_csv(tmp_path / "local" / f"{stem}.csv").drop(columns=list(TIMING))
        tb = pd.read_csv(tmp_path / "ray" / f"{stem}.csv").drop(columns=list(TIMING))
        pd.testing.assert_frame_equal(ta, tb, check_exact=True)


def test_ray_executor_without_ray_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    import builtins

    real_import = builtins.__import__

    def no_ray(name: str, *args, **kwargs):
        if name == "ray":
            raise ImportError("no ray")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(ClodsError, match=r"clods-bench\[ray\]"):
        make_executor("ray").map(len, ["x"])
