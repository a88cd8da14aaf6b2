"""Fit cache: equal fits train once (CDG then stability), a changed config trains anew, timings stay honest."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.fit_cache import FIT_CACHE_DIR, fit_cost_seconds, fit_work_dir, sim_fit_identity
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from tests.conftest import tiny_config

MGN = ["sim_config.mgn.latent_size=8", "sim_config.mgn.message_passing_steps=1", "sim_config.mgn.train_steps=6", "sim_config.mgn.warmup_steps=2"]


def _record(root: Path, task: str, *extra: str) -> dict:
    cfg = tiny_config(root, *MGN, *extra, sim="mgn", task=task)
    return json.loads((run_task(cfg, default_registry()) / RECORD_FILE).read_text())


def _seed(rec: dict) -> dict:
    return rec["per_seed"]["0"]["timings"]


def test_stability_reuses_the_cdg_training_and_reports_its_cost(tiny_root: Path, tmp_path: Path) -> None:
    runs = f"runs_dir={tmp_path / 'runs'}"
    cdg = _seed(_record(tiny_root, "cdg", runs))
    assert cdg["fit/resumed_from_step"] == 0 and cdg["fit/train_steps"] == 6
    stab = _seed(_record(tiny_root, "stability", runs))
    assert stab["fit/resumed_from_step"] == 6  # loaded the finished checkpoint: no training step ran
    assert stab["fit/train_seconds"] == cdg["fit/train_seconds"]
    assert stab["fit_seconds"] >= cdg["fit/train_seconds"] > 0  # counted at the recorded cost, not the load time
    assert len(list((tmp_path / "runs" / FIT_CACHE_DIR).iterdir())) == 1
    other = _seed(_record(tiny_root, "stability", runs, "sim_config.mgn.learning_rate=0.002"))
    assert other["fit/resumed_from_step"] == 0  # another config is another fit
    assert len(list((tmp_path / "runs" / FIT_CACHE_DIR).iterdir())) == 2


def test_identity_resolves_defaults_and_separates_what_matters(tiny_root: Path, tmp_path: Path) -> None:
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path}", sim="mgn")
    ctx = TaskContext(config=cfg, seed=0, work_dir=tmp_path, registry=default_registry())
    base = sim_fit_identity(ctx, [0, 1], 9)
    assert base["sim_config"]["latent_size"] == cfg.sim_config["mgn"]["latent_size"] and "noise_std" in base["sim_config"]
    same = sim_fit_identity(ctx, [0, 1], 9, sim_config={**cfg.sim_config["mgn"]})
    assert fit_work_dir(ctx, base) == fit_work_dir(ctx, same)
    for changed in (sim_fit_identity(ctx, [0], 9), sim_fit_identity(ctx, [0, 1], 8), sim_fit_identity(ctx, [0, 1], 9, supervision="video")):
        assert fit_work_dir(ctx, changed) != fit_work_dir(ctx, base)
    assert json.loads((fit_work_dir(ctx, base) / "identity.json").read_text())["train_ids"] == [0, 1]
    # where and on how many threads it trains does not decide the model: one fit serves them all
    for same_model in ({"num_threads": 1}, {"num_threads": 2, "device": "cuda"}):
        other = sim_fit_identity(ctx, [0, 1], 9, sim_config={**cfg.sim_config["mgn"], **same_model})
        assert fit_work_dir(ctx, other) == fit_work_dir(ctx, base)


@pytest.mark.parametrize(("wall", "stats", "cost"), [(2.0, {"train_seconds": 5.0}, 5.0), (2.0, {"train_seconds": 1.0}, 2.0), (2.0, {}, 2.0), (2.0, None, 2.0)])
def test_cost_is_the_recorded_training_time_never_below_the_wall_time(wall: float, stats: dict | None, cost: float) -> None:
    assert fit_cost_seconds(wall, stats) == cost
