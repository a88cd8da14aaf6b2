"""Executors: parallel local worker processes and Ray tasks run the (run, seed) jobs of a sweep with the sequential numbers."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from rich.console import Console

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.reproduction.reproduce import reproduce
from clods_bench.benchmark.running.executors import LocalExecutor, make_executor
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import MAX_THREADS_ENV, torch_threads
from tests.benchmark.reproduction.test_reproduce import _overrides, _plan

TIMING = ("infer_ms_per_step", "fit_seconds")


def test_unknown_executor_is_a_clear_error() -> None:
    with pytest.raises(ClodsError, match="unknown executor 'dask'"):
        make_executor("dask")
    assert isinstance(make_executor("local"), LocalExecutor)
    with pytest.raises(ClodsError, match="--jobs"):
        make_executor("local", jobs=0)


def _threads_seen(asked: int) -> tuple[int, str | None, int, int]:
    """(torch threads at start, the cap variable, threads inside a block that asks for `asked`, numba threads) in a worker."""
    import os

    import numba
    import torch

    with torch_threads(asked):
        inside = torch.get_num_threads()
    return torch.get_num_threads(), os.environ.get(MAX_THREADS_ENV), inside, numba.get_num_threads()


def test_parallel_workers_share_the_cores() -> None:
    import os
    import signal

    before = signal.getsignal(signal.SIGTERM)
    seen = LocalExecutor(jobs=2).map(_threads_seen, [8, 8, 1], progress=False)
    assert signal.getsignal(signal.SIGTERM) == before  # the driver's SIGTERM handling is put back after the jobs
    cap = max(1, (os.cpu_count() or 1) // 2)
    assert seen == [(cap, str(cap), cap, cap), (cap, str(cap), cap, cap), (cap, str(cap), 1, cap)]  # a config asking for 8 gets the cap


def test_parallel_sweep_matches_sequential(tmp_path: Path, tiny_root: Path) -> None:
    plan = _plan(tmp_path)
    one = reproduce("ci", tmp_path / "one", default_registry(), Console(quiet=True), "local", plan, _overrides(tiny_root, tmp_path / "runs_one"))
    two = reproduce("ci", tmp_path / "two", default_registry(), Console(quiet=True), "local", plan, _overrides(tiny_root, tmp_path / "runs_two"), jobs=2)
    assert one["jobs"] == 1 and two["jobs"] == 2
    for a, b in zip(one["runs"], two["runs"]):
        ra = json.loads((Path(a["record_dir"]) / RECORD_FILE).read_text())
        rb = json.loads((Path(b["record_dir"]) / RECORD_FILE).read_text())
        assert ra["per_seed"]["0"]["metrics"] == rb["per_seed"]["0"]["metrics"] and ra["seeds"] == rb["seeds"] == [0, 1]
    for stem in ("t_cdg", "t_damp"):
        ta = pd.read_csv(tmp_path / "one" / f"{stem}.csv").drop(columns=list(TIMING))
        tb = pd.read_csv(tmp_path / "two" / f"{stem}.csv").drop(columns=list(TIMING))
        pd.testing.assert_frame_equal(ta, tb, check_exact=True)


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


def test_a_complete_dataset_of_an_edited_scene_is_not_reused(tiny_root: Path) -> None:
    """A finished dataset is reused only while its scene definition (fingerprint) is unchanged; an edited scene of the
    same name gets the store's 'different config' error instead of the old trajectories (and nothing is deleted)."""
    import dataclasses

    from clods_bench.benchmark.running.run_data import ensure_complete_dataset
    from tests.conftest import tiny_config

    cfg = tiny_config(tiny_root)
    registry = default_registry()
    store = ensure_complete_dataset(cfg, registry, progress=False)
    before = store.completed_indices()
    flag = registry.get("scene", cfg.data.scene)
    edited = dataclasses.replace(flag, params=flag.params.scaled(2.0))

    class EditedRegistry:
        def get(self, kind: str, name: str) -> object:
            return edited if kind == "scene" else registry.get(kind, name)

    with pytest.raises(ClodsError, match="different config"):
        ensure_complete_dataset(cfg, EditedRegistry(), progress=False)
    assert ensure_complete_dataset(cfg, registry, progress=False).completed_indices() == before


def _gpu_ids(_item) -> list:
    import ray

    return list(ray.get_gpu_ids())


def test_ray_gives_a_gpu_share_only_to_jobs_that_use_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a cluster that declares a GPU, jobs with a CUDA renderer or a gsplat surfel fit get it (a share each), the
    others none; the share comes from $CLODS_BENCH_RAY_GPU_SHARE, which must lie in (0, 1]."""
    ray = pytest.importorskip("ray")
    from clods_bench.benchmark.running.executors import GPU_SHARE_ENV, RayExecutor, SeedJob, job_uses_gpu

    jobs = [
        SeedJob({"renderer": "smgs", "renderer_config": {"smgs": {"device": "cuda", "backend": "gsplat"}}}, 0, "smgs on cuda"),
        SeedJob({"renderer": "smgs", "renderer_config": {"smgs": {"backend": "cpu"}, "games": {"device": "cuda"}}}, 0, "smgs on cpu"),
        SeedJob({"task_config": {"clods": {"stage0": {"backend": "gsplat"}}}}, 0, "stage 0 on gsplat"),
        SeedJob({"task_config": {"initial_mesh": {"backend": "cpu"}}}, 0, "stage 0 on cpu"),
        SeedJob({"sim": "mgn", "sim_config": {"mgn": {"device": "cuda:0"}}}, 0, "mgn on cuda"),
        SeedJob({"sim": "constvel", "predictor": "tau", "video_config": {"tau": {"device": "cuda"}}, "sim_config": {"mgn": {"device": "cuda"}}}, 0, "tau on cuda"),
    ]
    assert [job_uses_gpu(j) for j in jobs] == [True, False, True, False, True, True]
    assert not job_uses_gpu(SeedJob({"sim": "constvel", "sim_config": {"mgn": {"device": "cuda"}}}, 0, "constvel"))  # mgn's option: not its plugin
    assert not job_uses_gpu("data generation item")
    monkeypatch.setenv(GPU_SHARE_ENV, "0.5")
    executor = RayExecutor()
    assert executor.gpu_share == 0.5
    ray.init(num_cpus=2, num_gpus=1, include_dashboard=False, log_to_driver=False)  # a declared GPU: Ray schedules, nothing runs on it
    try:
        seen = executor.map(_gpu_ids, jobs, progress=False)
    finally:
        ray.shutdown()
    assert [len(ids) for ids in seen] == [1, 0, 1, 0, 1, 1]
    for bad in ("0", "1.5", "half"):
        monkeypatch.setenv(GPU_SHARE_ENV, bad)
        with pytest.raises(ClodsError, match=GPU_SHARE_ENV.replace("$", "")):
            RayExecutor()


_SLEEPER = """
import os, sys, time
from pathlib import Path
from clods_bench.benchmark.running.executors import LocalExecutor

def job(folder):
    (Path(folder) / f"{os.getpid()}.pid").write_text("")
    time.sleep(120)
    return 0

if __name__ == "__main__":
    try:
        LocalExecutor(jobs=2).map(job, [sys.argv[1]] * 4, progress=False)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(130)
"""


def _alive(pid: int) -> bool:
    """Whether `pid` runs (a zombie, dead but not yet reaped, counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _start_sleepers(tmp_path: Path) -> tuple["subprocess.Popen[str]", list[int]]:
    """A parent running LocalExecutor(jobs=2) over 120-s jobs, and its two workers' pids once both jobs have started."""
    import os
    import subprocess
    import sys
    import time

    script = tmp_path / "sleepers.py"
    script.write_text(_SLEEPER)
    pids = tmp_path / "pids"
    pids.mkdir()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[3]), os.environ.get("PYTHONPATH", "")]))
    parent = subprocess.Popen([sys.executable, str(script), str(pids)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    deadline = time.monotonic() + 120
    while len(list(pids.glob("*.pid"))) < 2:
        if parent.poll() is not None or time.monotonic() > deadline:
            parent.kill()
            pytest.fail(f"workers did not start: {parent.communicate()[0]}")
        time.sleep(0.2)
    return parent, [int(p.stem) for p in pids.glob("*.pid")]


def _gone_within(pids: list[int], seconds: float) -> bool:
    import time

    deadline = time.monotonic() + seconds
    while any(_alive(p) for p in pids):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)
    return True


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads worker states from /proc and relies on the Linux parent-death signal")
def test_sigterm_to_the_parent_stops_running_workers(tmp_path: Path) -> None:
    """`kill <reproduce pid>` used to leave the workers computing on alone, for hours (a per-frame 3DGS job)."""
    import signal
    import time

    parent, workers = _start_sleepers(tmp_path)
    t0 = time.monotonic()
    parent.send_signal(signal.SIGTERM)  # the parent alone, not its process group
    out, _ = parent.communicate(timeout=60)
    assert parent.returncode == 130 and "interrupted" in out, out
    assert time.monotonic() - t0 < 30  # not the 120 s of a running job
    assert _gone_within(workers, 10)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads worker states from /proc and relies on the Linux parent-death signal")
def test_workers_die_with_a_killed_parent(tmp_path: Path) -> None:
    """SIGKILL leaves the parent no cleanup: the workers' parent-death signal stops them."""
    parent, workers = _start_sleepers(tmp_path)
    parent.kill()
    parent.communicate(timeout=30)
    assert _gone_within(workers, 10)


def _fail_or_finish(arg: tuple[str, str]) -> str:
    """Job double: 'fail' raises at once; 'slow' sleeps 3 s, then leaves a file saying it finished."""
    import time

    kind, folder = arg
    if kind == "fail":
        raise ClodsError("job failed on purpose", where="test")
    time.sleep(3)
    (Path(folder) / "finished").write_text("")
    return kind


def test_a_failed_job_lets_the_running_ones_finish(tmp_path: Path) -> None:
    """Only an interrupt terminates running workers; a job's own error ends the map after the others saved their work."""
    with pytest.raises(ClodsError, match="failed on purpose"):
        LocalExecutor(jobs=2).map(_fail_or_finish, [("slow", str(tmp_path)), ("fail", str(tmp_path))], progress=False)
    assert (tmp_path / "finished").exists()


def _sleep_then(arg: tuple[float, int]) -> int:
    import time

    time.sleep(arg[0])
    return arg[1]


@pytest.mark.parametrize("jobs", [1, 2])
def test_no_job_starts_after_the_deadline_and_started_ones_finish(jobs: int) -> None:
    """A time-boxed map: jobs submitted before the deadline run to the end; the rest never start (result None)."""
    import time

    items = [(1.5, 0), (1.5, 1), (0.0, 2), (0.0, 3)]
    out = LocalExecutor(jobs=jobs).map(_sleep_then, items, progress=False, deadline=time.monotonic() + 0.5)
    assert out == ([0, None, None, None] if jobs == 1 else [0, 1, None, None])
    assert LocalExecutor(jobs=jobs).map(_sleep_then, items[2:], progress=False, deadline=time.monotonic() + 60) == [2, 3]
    assert LocalExecutor(jobs=jobs).map(_sleep_then, items[2:], progress=False, deadline=time.monotonic() - 1) == [None, None]
