"""A record keeps every seed finished for its configuration: more seeds add to it, fewer remove none, concurrent
runs of different seeds all land (under the record lock), an empty seed list is refused before any work,
`reproduce` builds its tables from the plan's seeds only, and `tables` refuses a record that disagrees with itself."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from rich.console import Console

from clods_bench import integrity
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.core.resolve import resolve_plugins
from clods_bench.benchmark.reproduction.reproduce import reproduce
from clods_bench.benchmark.running import records
from clods_bench.benchmark.running.executors import LocalExecutor
from clods_bench.benchmark.running.records import RECORD_FILE, aggregate, read_record, record_dir, seed_result_path
from clods_bench.benchmark.running.runner import run_data_digests, run_task
from clods_bench.benchmark.running.seed_jobs import run_configs
from clods_bench.errors import ClodsError
from tests.conftest import TINY, tiny_config
from tests.reliability.integrity_helpers import cli, error_line, tiny_args

KEY = "viewed/interp/d_avg"
ROOT = Path(__file__).resolve().parents[2]


def _run(tiny_root: Path, runs: Path, seeds: str) -> dict:
    rdir = run_task(tiny_config(tiny_root, f"runs_dir={runs}", f"seeds={seeds}", sim="constvel"), default_registry(), Console(quiet=True))
    return read_record(rdir / RECORD_FILE)


def test_more_seeds_add_to_the_record_and_fewer_remove_none(tiny_root: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    assert _run(tiny_root, runs, "[0]")["seeds"] == [0]
    rec = _run(tiny_root, runs, "[1]")  # the user's case: seeds=[1] after seeds=[0]
    assert rec["seeds"] == [0, 1] and sorted(rec["per_seed"]) == ["0", "1"]
    values = [rec["per_seed"][s]["metrics"][KEY] for s in ("0", "1")]
    assert rec["metrics"][KEY]["mean"] == float(np.mean(values)) and rec["metrics"][KEY]["std"] == float(np.std(values))
    again = _run(tiny_root, runs, "[1]")  # fewer seeds than recorded: none removed, the numbers unchanged
    assert again["seeds"] == [0, 1] and again["metrics"] == rec["metrics"] and again["per_seed"] == rec["per_seed"]
    assert again["identity"]["version"] == records.IDENTITY_VERSION
    assert again["identity"]["data"] == run_data_digests(tiny_config(tiny_root, sim="constvel"), default_registry())


def test_tables_show_every_seed_of_a_record(tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    _run(tiny_root, runs, "[0]")
    _run(tiny_root, runs, "[2]")
    code, _ = cli(capsys, "tables", "--runs", str(runs), "--out", str(tmp_path / "tables"))
    assert code == 0
    frame = pd.read_csv(tmp_path / "tables" / "cdg_flag_ci.csv")
    assert frame["seeds"].tolist() == [2]


@pytest.mark.slow  # about 30 s: two interpreters loading torch and the plugins on a shared 2-core machine
def test_three_runs_two_of_them_concurrent_processes_all_land(tiny_root: Path, tmp_path: Path) -> None:
    """Seed 0 here, then seeds 1 and 2 as two `clods-bench run` processes started together on one runs folder."""
    runs = tmp_path / "runs"
    _run(tiny_root, runs, "[0]")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    base = [sys.executable, "-m", "clods_bench.cli", "run", "cdg", "--sim", "constvel", "--jobs", "1", "--no-progress",
            *tiny_args(tiny_root, runs)]  # fmt: skip
    procs = [subprocess.Popen([*base, "--set", f"seeds=[{k}]"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for k in (1, 2)]  # fmt: skip
    outs = [p.communicate(timeout=300)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    rdir = record_dir(resolve_plugins(tiny_config(tiny_root, f"runs_dir={runs}", sim="constvel"), default_registry()), default_registry())
    rec = read_record(rdir / RECORD_FILE)
    assert rec["seeds"] == [0, 1, 2]
    for seed in (0, 1, 2):
        assert rec["per_seed"][str(seed)]["metrics"] == json.loads(seed_result_path(rdir, seed).read_text())["metrics"]


def test_the_record_lock_keeps_a_concurrent_seed(tiny_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A writer that read the seed results waits on nobody, yet a second writer's seed still lands: the second one
    waits for the lock, re-reads, and writes last. Without the lock the first writer's stale record would win."""
    runs = tmp_path / "runs"
    cfg = tiny_config(tiny_root, f"runs_dir={runs}", "seeds=[0, 1]", sim="constvel")
    rdir = run_task(cfg, default_registry(), Console(quiet=True))
    late = json.loads(seed_result_path(rdir, 1).read_text())
    seed_result_path(rdir, 1).unlink()
    digests = run_data_digests(cfg, default_registry())
    a_read, b_done = threading.Event(), threading.Event()
    real = records.seed_results

    def slow_first_reader(*args, **kwargs):
        out = real(*args, **kwargs)
        if threading.current_thread().name == "a":
            a_read.set()
            b_done.wait(timeout=1.0)  # B cannot finish while A holds the lock: A goes on after the timeout
        return out

    monkeypatch.setattr(records, "seed_results", slow_first_reader)
    a = threading.Thread(target=aggregate, name="a", args=(cfg, "constvel", rdir, {}, digests))
    a.start()
    assert a_read.wait(timeout=30)
    seed_result_path(rdir, 1).parent.mkdir(exist_ok=True)
    seed_result_path(rdir, 1).write_text(json.dumps(late))  # seed 1 finishes while A is between reading and writing
    aggregate(cfg, "constvel", rdir, {}, digests)
    b_done.set()
    a.join(timeout=30)
    assert read_record(rdir / RECORD_FILE)["seeds"] == [0, 1]


def test_an_empty_seed_list_is_refused_before_any_work(tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    rec = _run(tiny_root, runs, "[0]")
    rdir = record_dir(resolve_plugins(tiny_config(tiny_root, f"runs_dir={runs}", sim="constvel"), default_registry()), default_registry())
    before = (rdir / RECORD_FILE).read_bytes()
    line = error_line(capsys, "run", "cdg", "--sim", "constvel", *tiny_args(tiny_root, runs, "seeds=[]"))
    assert line == "error: seeds: is empty: a run needs at least one seed (e.g. --set seeds=[0])"
    assert (rdir / RECORD_FILE).read_bytes() == before and rec["seeds"] == [0]
    # the library entry points refuse it too, before a record folder or a dataset is made
    empty = tiny_config(tmp_path / "fresh", sim="constvel")
    empty.seeds = []
    for call in (lambda: run_task(empty, default_registry(), Console(quiet=True)),
                 lambda: run_configs([("row", empty)], LocalExecutor(1), default_registry(), Console(quiet=True))):  # fmt: skip
        with pytest.raises(ClodsError, match="seeds: is empty"):
            call()
    assert not (tmp_path / "fresh").exists()


def test_tables_refuse_a_record_whose_mean_disagrees_with_its_seeds(tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Written that way by other code (its content hash matches): the per-seed values decide, and they disagree."""
    runs = tmp_path / "runs"
    _run(tiny_root, runs, "[0, 1]")
    path = next(runs.rglob(RECORD_FILE))
    doc = json.loads(path.read_text())
    doc["metrics"][KEY]["mean"] += 0.01
    path.write_text(json.dumps(integrity.seal_json(doc)))
    line = error_line(capsys, "tables", "--runs", str(runs), "--out", str(tmp_path / "tables"))
    want = doc["metrics"][KEY]["mean"]
    assert line.startswith(f"error: {path}: metric '{KEY}': mean {want} but its per-seed values give ")
    assert f"clods-bench run cdg --config {path.parent / 'config.yaml'}" in line
    doc["seeds"] = [0]  # per-seed values of a seed the record does not list
    path.write_text(json.dumps(integrity.seal_json(doc)))
    assert "lists seeds [0] but holds per-seed values of [0, 1]" in error_line(capsys, "tables", "--runs", str(runs), "--out", str(tmp_path / "t"))


def test_reproduce_tables_use_the_plans_seeds_only(tiny_root: Path, tmp_path: Path) -> None:
    """A runs folder holding more seeds of a run (records accumulate) gives the same tables, bit for bit."""
    plan = tmp_path / "plan.yaml"
    plan.write_text("version: 1\ndescription: tiny\ntables:\n  - {id: t, task: cdg, title: t}\n"
                    "runs:\n  - {table: t, task: cdg, label: CV, sim: constvel}\n  - {table: t, task: cdg, label: F, sim: frozen}\n")  # fmt: skip
    runs = tmp_path / "runs"

    def run(seeds: str, out: str) -> dict:
        overrides = [*TINY, f"data.root={tiny_root / 'data'}", f"runs_dir={runs}", f"seeds={seeds}"]
        return reproduce("ci", tmp_path / out, default_registry(), Console(quiet=True), plan_path=plan, overrides=overrides)

    run("[0, 1]", "first")
    run("[0, 1, 2]", "more")  # seed 2 added to both records
    manifest = run("[0, 1]", "again")
    for rdir in {r["record_dir"] for r in manifest["runs"]}:
        assert read_record(Path(rdir) / RECORD_FILE)["seeds"] == [0, 1, 2]
    assert [r["seeds"] for r in manifest["runs"]] == [[0, 1], [0, 1]]
    for suffix in (".csv", ".md", ".tex"):
        assert (tmp_path / "again" / f"t{suffix}").read_bytes() == (tmp_path / "first" / f"t{suffix}").read_bytes()
    assert (tmp_path / "more" / "t.csv").read_bytes() != (tmp_path / "first" / "t.csv").read_bytes()


def test_the_consistency_check_reads_what_a_record_holds() -> None:
    """Seeds 2 and 10 in numeric order; per-seed values without timings (a hand-written record) check the metrics only."""
    rec = {"seeds": [10, 2], "metrics": {"m": {"mean": 2.0, "std": 1.0}}, "timings": {"t": {"mean": 5.0, "std": 0.0}},
           "per_seed": {"2": {"metrics": {"m": 1.0}}, "10": {"metrics": {"m": 3.0}}}}  # fmt: skip
    records.check_consistent(rec, "r.json")
    rec["metrics"]["m"]["std"] = "x"
    with pytest.raises(ClodsError, match=r"r.json: metric 'm': std x but its per-seed values give 1.0"):
        records.check_consistent(rec, "r.json")
    rec["seeds"] = [2]
    with pytest.raises(ClodsError, match=r"lists seeds \[2\] but holds per-seed values of \[2, 10\]"):
        records.check_consistent(rec, "r.json")
