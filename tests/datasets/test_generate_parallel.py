"""Parallel generation writes the same bytes as serial generation, whatever the order workers finish in."""

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.datasets.generate import generate
from clods_bench.datasets.store import DatasetStore
from tests.conftest import tiny_config


class ReversedThreads:
    """An executor running the jobs last-first on 2 threads: concurrent manifest updates, out-of-order completion."""

    name = "threads"

    def map(self, fn, items, describe=str, progress=True):
        with ThreadPoolExecutor(2) as pool:
            return list(reversed(list(pool.map(fn, list(reversed(items))))))


def _snapshot(root: Path) -> dict:
    """Every frame array file's bytes, every trajectory array, and the manifest minus what holds wall-clock time.

    `traj_XXXX.npz` stores the simulation's wall time (meta.sim_seconds), so its sha256 and size differ between any
    two runs, serial or not; every array in it is compared instead.
    """
    store = DatasetStore.open(root)
    out = {p.relative_to(root).as_posix(): p.read_bytes() for p in root.glob("frames_*.zarr/*")}
    out["texture.png"] = (root / "texture.png").read_bytes()
    for i in sorted(store.completed_indices()):
        traj = store.load_trajectory(i)
        for key in ("cells", "mesh_pos", "node_type", "world_pos"):
            out[f"traj_{i}.{key}"] = getattr(traj, key).tobytes()
        out[f"traj_{i}.meta"] = json.dumps({k: v for k, v in traj.meta.items() if k != "sim_seconds"}, sort_keys=True)
    manifest = json.loads((root / "manifest.json").read_text())
    for entry in manifest["trajectories"]:
        entry["files"].pop("traj")
    out["manifest.json"] = json.dumps(manifest, sort_keys=True)
    return out


def _generate(tmp_path: Path, name: str, executor) -> Path:
    cfg = tiny_config(tmp_path / name, "data.num_steps=6", "data.interp_steps=3", "data.image_size=16")
    scene = default_registry().get("scene", cfg.data.scene)
    return generate(cfg.data, scene, progress=False, executor=executor).root


def test_parallel_equals_serial(tmp_path):
    serial = _snapshot(_generate(tmp_path, "serial", None))
    parallel = _snapshot(_generate(tmp_path, "threads", ReversedThreads()))
    assert serial.keys() == parallel.keys() and len([k for k in serial if k.startswith("frames_")]) > 3
    assert [k for k in serial if serial[k] != parallel[k]] == []


@pytest.mark.slow
@pytest.mark.parametrize("executor", ["local", "ray"])
def test_worker_processes_equal_serial(tmp_path, executor):
    from clods_bench.benchmark.running.executors import make_executor

    if executor == "ray":
        pytest.importorskip("ray")
    serial = _snapshot(_generate(tmp_path, "serial", None))
    parallel = _snapshot(_generate(tmp_path, executor, make_executor(executor, jobs=2)))
    assert serial.keys() == parallel.keys() and [k for k in serial if serial[k] != parallel[k]] == []
