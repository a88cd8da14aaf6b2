"""`data convert`: a schema-1 store (raw .npy frames) is refused with a pointer to the command, and converts in
place to identical frames, resumably, losing nothing when killed midway."""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from clods_bench.atomic import write_json, write_npz
from clods_bench.cli import main
from clods_bench.datasets import convert
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from tests.datasets.test_store import CONFIG, cams, make_frames, make_traj


def _record(path: Path) -> dict:
    return {"name": path.name, "sha256": hashlib.sha256(path.read_bytes()).hexdigest(), "bytes": path.stat().st_size}


def make_v1_store(root: Path, n: int = 3) -> Path:
    """A dataset as clods-bench wrote it before schema 2: traj_XXXX.npz, frames_XXXX.npy, manifest version 1."""
    root.mkdir(parents=True)
    entries = []
    for i in range(n):
        traj = make_traj(i)
        write_npz(root / f"traj_{i:04d}.npz", cells=traj.cells, mesh_pos=traj.mesh_pos, node_type=traj.node_type,
                  world_pos=traj.world_pos, dt=np.float64(traj.dt), meta=np.str_(json.dumps(traj.meta)))  # fmt: skip
        np.save(root / f"frames_{i:04d}.npy", make_frames(i))
        entries.append({"index": i, "split": "train" if i < 2 else "test", "seed": i, "complete": True,
                        "files": {"traj": _record(root / f"traj_{i:04d}.npz"), "frames": _record(root / f"frames_{i:04d}.npy")},
                        "shapes": {"cells": list(traj.cells.shape), "mesh_pos": list(traj.mesh_pos.shape),
                                   "node_type": list(traj.node_type.shape), "world_pos": list(traj.world_pos.shape),
                                   "frames": list(make_frames(i).shape)}})  # fmt: skip
    write_json(root / "manifest.json", {"schema_version": 1, "scene": "flag", "config": CONFIG, "texture": None,
                                        "cameras": [c.to_dict() for c in cams()], "trajectories": entries})  # fmt: skip
    return root


def test_v1_store_error_names_data_convert(tmp_path):
    root = make_v1_store(tmp_path / "flag-0123456789")
    with pytest.raises(ClodsError, match="schema version 1") as info:
        DatasetStore.open(root)
    assert f"clods-bench data convert {root}" in str(info.value)
    with pytest.raises(ClodsError, match="data convert"):  # what generation into the same directory meets
        DatasetStore.create(root, "flag", CONFIG, cams())


def test_generate_into_an_old_store_points_to_convert(tmp_path):
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.datasets.generate import generate
    from tests.conftest import tiny_config

    cfg = tiny_config(tmp_path)
    make_v1_store(cfg.data.dataset_dir())
    with pytest.raises(ClodsError, match="data convert"):
        generate(cfg.data, default_registry().get("scene", cfg.data.scene), progress=False)


def test_convert_gives_identical_frames(tmp_path, capsys):
    root = make_v1_store(tmp_path / "data" / "flag-0123456789")
    assert main(["data", "convert", str(tmp_path / "data")]) == 0  # a data root: every dataset in it
    assert "converted 3 trajectories" in capsys.readouterr().out
    store = DatasetStore.open(root)
    store.verify()
    for i in range(3):
        np.testing.assert_array_equal(store.load_frames(i), make_frames(i))
        np.testing.assert_array_equal(store.load_trajectory(i).world_pos, make_traj(i).world_pos)
    assert not list(root.glob("*.npy")) and len(list(root.glob("frames_*.zarr"))) == 3
    again = convert.convert_dataset(root)
    assert again.already and again.npy_bytes == 0


def test_kill_before_commit_loses_nothing_and_resumes(tmp_path, monkeypatch):
    root = make_v1_store(tmp_path / "ds")
    old_manifest = (root / "manifest.json").read_bytes()
    written = []
    real = convert.write_frames

    def dies_on_second(path, *args, **kwargs):
        if written:
            raise KeyboardInterrupt("killed mid-convert")
        written.append(path)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(convert, "write_frames", dies_on_second)
    with pytest.raises(KeyboardInterrupt):
        convert.convert_dataset(root)
    monkeypatch.undo()
    assert (root / "manifest.json").read_bytes() == old_manifest and len(list(root.glob("*.npy"))) == 3
    assert [p.name for p in root.glob("frames_*.zarr")] == ["frames_0000.zarr"]
    done = convert.convert_dataset(root)  # resumes: checks the finished array against its .npy, writes the rest
    assert done.trajectories == 3 and not list(root.glob("*.npy"))
    for i in range(3):
        np.testing.assert_array_equal(DatasetStore.open(root).load_frames(i, verify=True), make_frames(i))


def test_kill_during_cleanup_and_damaged_source(tmp_path, monkeypatch):
    root = make_v1_store(tmp_path / "ds")
    monkeypatch.setattr(convert, "_delete_npy", lambda root, manifest: 0)  # killed right after the commit
    convert.convert_dataset(root)
    monkeypatch.undo()
    assert len(list(root.glob("*.npy"))) == 3
    DatasetStore.open(root).verify()  # already usable
    done = convert.convert_dataset(root)
    assert done.already and done.npy_bytes > 0 and not list(root.glob("*.npy"))

    bad = make_v1_store(tmp_path / "bad")
    npy = bad / "frames_0001.npy"
    data = bytearray(npy.read_bytes())
    data[-1] ^= 1
    npy.write_bytes(bytes(data))
    with pytest.raises(ClodsError, match="differs from its manifest record") as info:
        convert.convert_dataset(bad)
    assert str(npy) in str(info.value)
    assert json.loads((bad / "manifest.json").read_text())["schema_version"] == 1
