"""The initial_mesh task (CloDS stage 0 scored across topologies) on the tiny dataset: metrics against a longhand
computation from the record's own per-trajectory values, the mesh picture, options and errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.builders import data_splits
from clods_bench.benchmark.mesh_pictures import load_mesh_sample
from clods_bench.benchmark.records import RECORD_FILE
from clods_bench.benchmark.registry import default_registry
from clods_bench.benchmark.runner import run_task
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config

FAST = ["task_config.initial_mesh.iterations=20", "task_config.initial_mesh.num_surfels=200", "task_config.initial_mesh.num_nodes=12"]


def test_initial_mesh_task_scores_each_training_video(tiny_root: Path, tmp_path: Path) -> None:
    from rich.console import Console

    cfg = tiny_config(tiny_root, *FAST, f"runs_dir={tmp_path / 'runs'}", task="initial_mesh")
    rdir = run_task(cfg, default_registry(), Console(quiet=True))
    rec = json.loads((rdir / RECORD_FILE).read_text())
    seed = rec["per_seed"]["0"]
    per = seed["extra"]["per_trajectory"]
    assert sorted(per) == ["0", "1"] and seed["extra"]["views"] == list(data_splits(cfg.data).train_views) == [0, 1]  # camera 2 held out
    assert seed["metrics"]["attached_rmse"] == pytest.approx(np.mean([v["attached_rmse"] for v in per.values()]))
    assert seed["metrics"]["chamfer"] == pytest.approx(np.mean([v["chamfer"] for v in per.values()]))
    assert seed["metrics"]["attached_rmse_rel"] == pytest.approx(seed["metrics"]["attached_rmse"] / seed["extra"]["cloth_size"])
    assert all(abs(v["nodes"] - 12) <= 4 for v in per.values())
    cells, meshes, truth, _, title = load_mesh_sample(rdir / "seed_0" / "initial_mesh.npz")
    assert truth is None and "reconstructed (stage 0)" in meshes and "trajectory 0" in title


def test_initial_mesh_options_are_checked(tiny_root: Path, tmp_path: Path) -> None:
    from rich.console import Console

    cfg = tiny_config(tiny_root, "task_config.initial_mesh.hull_resolution=2", f"runs_dir={tmp_path / 'runs'}", task="initial_mesh")
    with pytest.raises(ClodsError, match="task_config.initial_mesh.hull_resolution"):
        run_task(cfg, default_registry(), Console(quiet=True))
