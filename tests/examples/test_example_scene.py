"""The worked scene plugin (examples/clods-bench-example-scene) pip-installs, registers, generates data and runs CDG."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.cli import main
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import HANDLE, edges_from_cells
from tests.conftest import TINY, tiny_config
from tests.plugin_packages import only_own_plugins

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "clods-bench-example-scene"


@pytest.fixture(scope="module")
def installed_scene(tmp_path_factory: pytest.TempPathFactory):
    """`pip install --target` the example (a copy, so the checkout stays clean) and put the target on sys.path."""
    tmp_path = tmp_path_factory.mktemp("example_scene")
    src = tmp_path / "src"
    shutil.copytree(EXAMPLE, src)
    site = tmp_path / "site"
    cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--target", str(site), str(src)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert (site / "clods_bench_example_scene" / "banner.obj").is_file()  # package data travels with it
    with only_own_plugins(site):  # no other installed plugin can change the outcome; the cached registry restored after
        try:
            yield default_registry(refresh=True)
        finally:
            for name in [m for m in sys.modules if m.startswith("clods_bench_example_scene")]:
                sys.modules.pop(name)


def test_example_scene_generates_data_and_runs_cdg(tmp_path: Path, installed_scene) -> None:
    reg = installed_scene
    assert reg.origins[("scene", "banner")] == "example_scene"
    assert reg.sources["example_scene"].distribution == "clods-bench-example-scene" and not reg.failures and not reg.notices
    scene = reg.get("scene", "banner")
    overrides = [*TINY, "data.scene=banner", f"data.root={tmp_path / 'data'}", f"runs_dir={tmp_path / 'runs'}"]
    sets = [arg for o in overrides for arg in ("--set", o)]
    assert main(["data", "generate", *sets]) == 0

    store = DatasetStore.open(tiny_config(tmp_path, "data.scene=banner").data.dataset_dir())
    traj = store.load_trajectory(0)
    assert (traj.num_nodes, traj.cells.shape[0], traj.num_steps) == (63, 96, 12)  # the OBJ's mesh; data.resolution ignored
    assert traj.meta["kind"] == "banner" and traj.meta["scene"] == "banner"
    rest = scene.build_mesh().rest_pos
    e = edges_from_cells(traj.cells)
    l2 = np.linalg.norm(traj.mesh_pos[e[:, 0]] - traj.mesh_pos[e[:, 1]], axis=1)
    np.testing.assert_allclose(l2, np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1), rtol=1e-5)  # UVs scaled to metres
    handles = traj.node_type == HANDLE
    assert handles.sum() == 7 and np.allclose(rest[handles, 2], rest[:, 2].max())  # the top edge
    # the top edge follows the plugin's prescribed sway, frame k at t = warm-up + k dt
    cloth, warm, dt = scene.cloth, traj.meta["warmup_time"], traj.dt
    start = traj.world_pos[0, handles] - np.asarray(cloth.sway) * math.sin(2 * math.pi * warm / cloth.period)
    expected = np.stack([cloth.handle_positions(warm + k * dt, start) for k in range(traj.num_steps)])
    np.testing.assert_allclose(traj.world_pos[:, handles], expected, atol=2e-6)
    free = ~handles
    assert np.abs(traj.world_pos[-1, free] - traj.world_pos[0, free]).max() > 0.01  # the breeze moves it
    frames = store.load_frames(0, mmap=False)
    assert frames.shape == (12, 3, 24, 24, 3) and np.abs(frames[-1].astype(int) - frames[0]).max() > 0

    for sim in ("constvel", "physics"):
        assert main(["run", "cdg", "--sim", sim, "--label", sim, *sets]) == 0
    assert main(["tables", "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "tables"), "--task", "cdg"]) == 0
    table = pd.read_csv(next((tmp_path / "tables").glob("cdg_*.csv"))).set_index("method")
    errors = [c for c in table.columns if c.endswith("/mean") and "/" in c[:-5]]
    assert {"constvel", "physics"} <= set(table.index) and len(errors) == 12
    assert np.isfinite(table.loc[["constvel", "physics"], errors].to_numpy(float)).all()
