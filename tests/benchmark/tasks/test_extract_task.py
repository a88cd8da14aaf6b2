"""The extract task (CloDS stages 1-2 alone): E-GT against a longhand computation, seeds, tables."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.outputs.mesh_pictures import load_mesh_sample
from clods_bench.benchmark.outputs.tables import write_tables
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config

FAST = [
    "renderer_config.games.iterations=10",
    "renderer_config.games.gaussians_per_face=1",
    "task_config.clods.iterations=2",
    "task_config.clods.min_iterations=2",
    "task_config.clods.extraction_seed=0",  # ignored by the extract task: its seeds are extraction seeds
    "task_config.clods.init_noise=gaussian",  # makes the extraction depend on the seed
    "seeds=[0, 1]",
]


def test_egt_matches_the_cached_meshes_and_seeds_are_extraction_seeds(tiny_root: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    cfg = tiny_config(tiny_root, f"runs_dir={runs}", *FAST, "task_config.extract.num_trajectories=1", task="extract", renderer="games")
    rdir = run_task(cfg, default_registry())
    rec = json.loads((rdir / RECORD_FILE).read_text())
    store = DatasetStore.open(cfg.data.dataset_dir())
    truth = store.load_trajectory(0).world_pos[: cfg.data.interp_steps + 1].astype(np.float64)
    egts = []
    for seed in ("0", "1"):
        s = rec["per_seed"][seed]
        assert s["extra"]["trajectories"] == [0]
        with np.load(runs / "clods_cache" / s["extra"]["cache"] / "traj_0000.npz") as z:
            got = z["world_pos"].astype(np.float64)
        egt = np.sqrt(((got - truth) ** 2).mean(axis=(1, 2)))  # longhand E-GT per frame
        _, meshes, sample_truth, _, _ = load_mesh_sample(rdir / f"seed_{seed}" / "extraction_meshes.npz")  # the picture's sample
        np.testing.assert_allclose(meshes["extracted (stage 2)"], got, atol=1e-6)
        np.testing.assert_allclose(sample_truth, truth, atol=1e-6)
        assert s["metrics"]["egt_avg"] == pytest.approx(egt[1:].mean(), rel=1e-6)
        assert s["metrics"]["egt_end"] == pytest.approx(egt[-1], rel=1e-6)
        curves = json.loads((rdir / f"seed_{seed}" / "result.json").read_text())["curves"]
        np.testing.assert_allclose(curves["egt"], egt, rtol=1e-6)
        assert egt[0] > 0  # the noisy initial mesh differs from the truth
        assert s["timings"]["stage2_ms_per_frame"] > 0 and s["timings"]["fit_seconds"] >= s["timings"]["stage2_seconds"]
        egts.append(egt)
    assert rec["per_seed"]["0"]["extra"]["cache"] != rec["per_seed"]["1"]["extra"]["cache"]
    assert not np.allclose(egts[0], egts[1])  # two extraction seeds, two noise draws

    paths = write_tables(runs, tmp_path / "tables", task="extract")
    md = next(p for p in paths if p.suffix == ".md").read_text()
    assert "E-GT avg (m)" in md and "extraction seeds" in md
    csv = pd.read_csv(next(p for p in paths if p.suffix == ".csv"))
    assert csv["egt_avg/mean"].iloc[0] == pytest.approx(np.mean([e[1:].mean() for e in egts]), rel=1e-6)


def test_bad_options_are_clear_errors(tiny_root: Path, tmp_path: Path) -> None:
    base = [f"runs_dir={tmp_path}", *FAST]
    with pytest.raises(ClodsError, match="task_config.extract.num_trajectories"):
        run_task(tiny_config(tiny_root, *base, "task_config.extract.num_trajectories=0", task="extract", renderer="games"), default_registry())
    with pytest.raises(ClodsError, match="unknown config key"):
        run_task(tiny_config(tiny_root, *base, "task_config.extract.trajectories=1", task="extract", renderer="games"), default_registry())
    with pytest.raises(ClodsError, match="renderer"):
        run_task(tiny_config(tiny_root, *base, task="extract"), default_registry())
