"""CDG scored on another dataset (`task_config.cdg.eval_data`): parsing, one clear error per bad option, the same
numbers when the scored dataset is the training one reached another way, and the other scene's trajectories and rest
shape when it is another scene (checked against a longhand constant-velocity rollout and edge strain)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.eval_data import cdg_config, scored_data
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.datasets.meshes import make_cylinder_mesh
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError
from tests.benchmark.tasks.test_cdg import _independent_constvel, _independent_constvel_rmse
from tests.conftest import tiny_config

CYLINDER = ["task_config.cdg.eval_data.scene=cylinder", "task_config.cdg.eval_data.resolution=[5,4]",
            "task_config.cdg.eval_data.render_frames=false"]  # fmt: skip  # 20 nodes (the tiny flag has 24), meshes only


def _record(cfg) -> dict:
    return json.loads((run_task(cfg, default_registry()) / RECORD_FILE).read_text())


def test_eval_data_lays_its_fields_over_data(tiny_root: Path) -> None:
    plain = tiny_config(tiny_root)
    assert cdg_config(plain).eval_data == {} and scored_data(plain, default_registry()) is plain.data
    cfg = tiny_config(tiny_root, *CYLINDER)
    d = scored_data(cfg, default_registry())
    assert (d.scene, d.resolution, d.render_frames) == ("cylinder", [5, 4], False)
    assert dataclasses.replace(d, scene="flag", resolution=[6, 4], render_frames=True) == cfg.data  # nothing else moved
    assert d.dataset_dir().parent == cfg.data.dataset_dir().parent and d.dataset_dir() != cfg.data.dataset_dir()
    assert cfg.data.scene == "flag"  # training stays on `data`


@pytest.mark.parametrize(
    ("override", "where", "match"),
    [
        ("task_config.cdg.eval_data.scen=cylinder", "task_config.cdg.eval_data.scen", "did you mean 'scene'"),
        ("task_config.cdg.eval_data.num_train=many", "task_config.cdg.eval_data.num_train", "expected an integer"),
        ("task_config.cdg.eval_data.root=/elsewhere", "task_config.cdg.eval_data.root", "cannot differ"),
        ("task_config.cdg.eval_data.scene=cylindre", "task_config.cdg.eval_data.scene", "did you mean 'cylinder'"),
        ("task_config.cdg.eval_data.path=/no/such/dataset", "task_config.cdg.eval_data.path", "manifest.json missing"),
        ("task_config.cdg.eval_data=cylinder", "task_config.cdg", "expected a mapping"),
        ("task_config.cdg.eval_dat.scene=cylinder", "task_config.cdg", "did you mean 'cdg.eval_data'"),
    ],
)
def test_a_bad_eval_data_option_fails_before_anything_runs(tiny_root: Path, tmp_path: Path, override: str, where: str, match: str) -> None:
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", override, sim="constvel")
    with pytest.raises(ClodsError, match=match) as err:
        run_task(cfg, default_registry(), ensure_data=lambda *a: pytest.fail("data step reached"))
    assert err.value.where == where
    assert not (tmp_path / "runs").exists()  # refused by the plugin check, before the record directory


def test_an_eval_dataset_without_meshes_is_refused_naming_eval_data_path(tiny_root: Path, tmp_path: Path) -> None:
    meshless = tmp_path / "meshless"
    shutil.copytree(tiny_config(tiny_root).data.dataset_dir(), meshless)
    manifest = json.loads((meshless / "manifest.json").read_text())
    (meshless / "manifest.json").write_text(json.dumps({**manifest, "meshes": False}))
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", f"task_config.cdg.eval_data.path={meshless}", sim="constvel")
    with pytest.raises(ClodsError, match="no meshes") as err:
        run_task(cfg, default_registry())
    assert err.value.where == "task_config.cdg.eval_data.path"


def test_scoring_the_training_dataset_through_eval_data_gives_the_same_numbers(tiny_root: Path, tmp_path: Path) -> None:
    """eval_data naming the training dataset by its path takes the other code path (another DataConfig, its own
    store, splits from its manifest) and must land on the very same metrics; physics also rebuilds for the scored scene."""
    base = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", sim="physics")
    same = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", f"task_config.cdg.eval_data.path={base.data.dataset_dir()}", sim="physics")
    assert scored_data(same, default_registry()) != base.data
    a, b = _record(base), _record(same)
    assert b["metrics"] == a["metrics"] and len(a["metrics"]) == 13
    assert a["per_seed"]["0"]["extra"]["scored_data"] == b["per_seed"]["0"]["extra"]["scored_data"]
    assert b["per_seed"]["0"]["extra"]["scored_data"]["dataset"] == base.data.dataset_dir().name


def _strain_against(traj: Trajectory, rest: np.ndarray) -> float:
    """Largest |l/l0 - 1| over the triangle edges of the longhand constant-velocity rollout, rest lengths from `rest`."""
    pred = _independent_constvel(traj.world_pos, traj.node_type)
    edges = {tuple(sorted((int(c[i]), int(c[(i + 1) % 3])))) for c in traj.cells for i in range(3)}
    worst = 0.0
    for i, j in edges:
        l0 = np.linalg.norm(rest[i] - rest[j])
        worst = max(worst, float(np.max(np.abs(np.linalg.norm(pred[:, i] - pred[:, j], axis=1) / l0 - 1.0))))
    return worst


def test_an_eval_on_the_cylinder_rolls_out_the_cylinders_trajectories(tiny_root: Path, tmp_path: Path) -> None:
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", *CYLINDER, sim="constvel")
    rec = _record(cfg)
    scored = rec["per_seed"]["0"]["extra"]["scored_data"]
    d = scored_data(cfg, default_registry())
    assert scored == {"scene": "cylinder", "dataset": d.dataset_dir().name, "num_nodes": [20], "num_steps": 12, "interp_steps": 8,
                      "viewed": [1], "unviewed": [2]}  # fmt: skip
    assert rec["scene"] == "flag" and rec["config"]["task_config"]["cdg"]["eval_data"]["scene"] == "cylinder"
    store = DatasetStore.open(d.dataset_dir())
    for group, i in (("viewed", 1), ("unviewed", 2)):
        t = store.load_trajectory(i)
        curve = _independent_constvel_rmse(t.world_pos, t.node_type)
        assert rec["metrics"][f"{group}/interp/d_avg"]["mean"] == pytest.approx(curve[2:9].mean(), rel=1e-5)
        assert rec["metrics"][f"{group}/extrap/d_end"]["mean"] == pytest.approx(curve[11], rel=1e-5)
    # The strain column measures against the cylinder's 3D rest shape: the flat (u, 0, v) reading of its unrolled
    # mesh_pos (the flag's convention) would take each seam edge's rest length as the circumference minus one step.
    tube = make_cylinder_mesh(5, 4, 0.3, 1.0)
    trajs = [store.load_trajectory(i) for i in (1, 2)]
    assert np.array_equal(trajs[0].mesh_pos, tube.mesh_pos)
    strain = max(_strain_against(t, tube.rest_pos) for t in trajs)
    assert rec["metrics"]["max_strain"]["mean"] == pytest.approx(strain, rel=1e-5)
    flat = np.stack([tube.mesh_pos[:, 0], np.zeros(20), tube.mesh_pos[:, 1]], axis=1)
    assert abs(max(_strain_against(t, flat) for t in trajs) - strain) > 0.1
