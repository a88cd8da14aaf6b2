"""The initial_mesh task (CloDS stage 0 scored across topologies) on the tiny dataset: metrics against a longhand
computation from the record's own per-trajectory values, the mesh picture, options and errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.builders import data_splits
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.outputs.mesh_pictures import load_mesh_sample
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
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


def test_the_pipeline_reuses_the_tables_stage0_meshes(tiny_root: Path, tmp_path: Path) -> None:
    """The initial-mesh table and a row learned from a reconstructed mesh share stage 0 (same images, cameras and
    options): the second finds every mesh in the cache, its cost carried over, the mesh the same."""
    from rich.console import Console

    from clods_bench.benchmark.clods.config import clods_config
    from clods_bench.benchmark.clods.reconstructed import stage0_config, stage0_mesh
    from clods_bench.benchmark.core.descriptors import TaskContext
    from clods_bench.datasets.store import DatasetStore

    cfg = tiny_config(tiny_root, *FAST, f"runs_dir={tmp_path / 'runs'}", task="initial_mesh")
    rec = json.loads((run_task(cfg, default_registry(), Console(quiet=True)) / RECORD_FILE).read_text())
    assert len(list((tmp_path / "runs" / "clods_cache").glob("stage0-*.npz"))) == 2
    stage0 = {k.removeprefix("task_config.initial_mesh."): v for k, v in (o.split("=") for o in FAST)}
    pipe = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", "task_config.clods.extraction_seed=0",
                       *(f"task_config.clods.stage0.{k}={v}" for k, v in stage0.items()), sim="mgn", renderer="smgs")  # fmt: skip
    opts = clods_config(pipe)
    store = DatasetStore.open(pipe.data.dataset_dir())
    views = list(data_splits(pipe.data).train_views)
    ctx = TaskContext(config=pipe, seed=0, work_dir=tmp_path, registry=default_registry())
    mesh, stats = stage0_mesh(ctx, opts, stage0_config(opts, 0), 0, store.frames(0).read([0], views)[0], [store.cameras()[v] for v in views], 12)
    assert stats["stage0_seconds"] == 0.0 and stats["stage0_cost_seconds"] > 0
    assert mesh.num_nodes == rec["per_seed"]["0"]["extra"]["per_trajectory"]["0"]["nodes"]


def test_initial_mesh_options_are_checked(tiny_root: Path, tmp_path: Path) -> None:
    from rich.console import Console

    cfg = tiny_config(tiny_root, "task_config.initial_mesh.hull_resolution=2", f"runs_dir={tmp_path / 'runs'}", task="initial_mesh")
    with pytest.raises(ClodsError, match="task_config.initial_mesh.hull_resolution"):
        run_task(cfg, default_registry(), Console(quiet=True))
