"""DatasetStore: round trip, resume after interruption, and clear errors for damaged files."""

import hashlib
import json
import os
import shutil

import numpy as np
import pytest

from clods_bench.datasets.cameras import camera_rig
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import HANDLE, Trajectory
from clods_bench.errors import ClodsError

CONFIG = {"scene": "flag", "num_train": 2, "num_test": 2, "resolution": [4, 3]}
T, NX, NY, H, W = 5, 4, 3, 8, 10


def make_traj(seed: int = 0) -> Trajectory:
    """A small flag: NX x NY grid, two handle nodes, T frames of random motion."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(NX, dtype=np.float32), np.arange(NY, dtype=np.float32), indexing="ij")
    mesh_pos = np.stack([xs.ravel(), ys.ravel()], axis=1) * 0.1
    idx = np.arange(NX * NY).reshape(NX, NY)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    cells = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    node_type = np.zeros(NX * NY, np.int32)
    node_type[idx[0]] = HANDLE
    rest = np.concatenate([mesh_pos, np.zeros((NX * NY, 1), np.float32)], axis=1)
    world_pos = (rest[None] + 0.01 * rng.standard_normal((T, NX * NY, 3))).astype(np.float32)
    return Trajectory(cells, mesh_pos, node_type, world_pos, 0.02, {"seed": seed, "wind": [1.0, 0.0, 0.0]})


def make_frames(seed: int = 0, views: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (T, views, H, W, 3), dtype=np.uint8)


def cams(n: int = 3):
    return camera_rig(n, np.zeros(3), 3.0, W, H)


def new_store(tmp_path, n_written: int = 0) -> DatasetStore:
    store = DatasetStore.create(tmp_path / "ds", "flag", CONFIG, cams())
    for i in range(n_written):
        store.write_trajectory(i, "train" if i < 2 else "test", 100 + i, make_traj(i), make_frames(i))
    return store


def test_round_trip(tmp_path):
    store = new_store(tmp_path, 4)
    again = DatasetStore.open(tmp_path / "ds")
    assert len(again) == 4 and again.indices("train") == [0, 1] and again.indices("test") == [2, 3]
    assert again.scene == "flag" and again.config == CONFIG
    for a, b in zip(again.cameras(), cams()):
        assert np.allclose(a.K, b.K) and np.allclose(a.R, b.R) and np.allclose(a.t, b.t) and (a.width, a.height) == (W, H)
    for i in range(4):
        ref, got = make_traj(i), again.load_trajectory(i, verify=True)
        for key in ("cells", "mesh_pos", "node_type", "world_pos"):
            np.testing.assert_array_equal(getattr(got, key), getattr(ref, key))
        assert got.world_pos.dtype == np.float32 and got.cells.dtype == np.int32
        assert got.dt == 0.02 and got.meta == ref.meta
        frames = again.load_frames(i)
        assert type(frames) is np.ndarray and frames.dtype == np.uint8
        np.testing.assert_array_equal(frames, make_frames(i))
        np.testing.assert_array_equal(again.frames(i)[1:4, [2, 0]], make_frames(i)[1:4, [2, 0]])
    entry = json.loads((tmp_path / "ds" / "manifest.json").read_text())["trajectories"][1]
    assert entry["seed"] == 101 and entry["complete"] is True and entry["shapes"]["frames"] == [T, 3, H, W, 3]
    array_dir = tmp_path / "ds" / "frames_0001.zarr"
    assert entry["files"]["frames"]["bytes"] == sum(p.stat().st_size for p in array_dir.iterdir())
    again.verify()
    assert store.texture_path() is None
    store.write_texture(b"\x89PNG fake")
    assert DatasetStore.open(tmp_path / "ds").texture_path().read_bytes() == b"\x89PNG fake"


def test_trajectory_without_frames(tmp_path):
    store = new_store(tmp_path)
    store.write_trajectory(0, "train", 0, make_traj(), None)
    assert store.load_trajectory(0).num_steps == T
    with pytest.raises(ClodsError, match="without frames"):
        store.load_frames(0)


def test_resume(tmp_path):
    new_store(tmp_path, 2)
    store = DatasetStore.create(tmp_path / "ds", "flag", dict(CONFIG), cams())
    assert store.completed_indices() == {0, 1}
    store.write_trajectory(2, "test", 2, make_traj(2), make_frames(2))
    assert DatasetStore.open(tmp_path / "ds").completed_indices() == {0, 1, 2}


def test_crash_mid_write_leaves_no_entry(tmp_path, monkeypatch):
    store = new_store(tmp_path, 1)

    def crash(src, dst):
        raise KeyboardInterrupt("power cut")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(KeyboardInterrupt):
        store.write_trajectory(1, "train", 1, make_traj(1), make_frames(1))
    monkeypatch.undo()
    reopened = DatasetStore.open(tmp_path / "ds")
    assert reopened.completed_indices() == {0}
    assert not (tmp_path / "ds" / "traj_0001.npz").exists()
    with pytest.raises(ClodsError, match="not in the dataset"):
        reopened.load_trajectory(1)
    reopened.load_trajectory(0)


def test_crash_after_files_before_manifest(tmp_path, monkeypatch):
    """Files written but the manifest update killed: no entry, resume rewrites the trajectory."""
    store = new_store(tmp_path)
    monkeypatch.setattr(DatasetStore, "_save_manifest", lambda self: (_ for _ in ()).throw(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        store.write_trajectory(0, "train", 0, make_traj(0), make_frames(0))
    monkeypatch.undo()
    assert (tmp_path / "ds" / "traj_0000.npz").exists()
    store = DatasetStore.create(tmp_path / "ds", "flag", CONFIG, cams())
    assert store.completed_indices() == set()


def test_stale_temp_files_removed_on_resume(tmp_path):
    new_store(tmp_path, 1)
    stale = tmp_path / "ds" / ".traj_0001.npz.abc123.tmp.npz"
    stale.write_bytes(b"half")
    stale_dir = tmp_path / "ds" / ".frames_0001.zarr.abc123.tmp"
    stale_dir.mkdir()
    (stale_dir / "c.0.0.0.0.0").write_bytes(b"half")
    DatasetStore.create(tmp_path / "ds", "flag", CONFIG, cams())
    assert not stale.exists() and not stale_dir.exists()


def test_rewrite_index_replaces_entry(tmp_path):
    store = new_store(tmp_path, 1)
    store.write_trajectory(0, "train", 7, make_traj(5), make_frames(5))
    np.testing.assert_array_equal(store.load_trajectory(0, verify=True).world_pos, make_traj(5).world_pos)
    assert store.entry(0)["seed"] == 7 and len(store) == 1


def test_truncated_file(tmp_path):
    store = new_store(tmp_path, 1)
    for name, load in (("traj_0000.npz", store.load_trajectory),):  # truncated frame chunks: test_frame_store.py
        path = tmp_path / "ds" / name
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        with pytest.raises(ClodsError, match="truncated") as info:
            load(0)
        assert name in str(info.value) and f"expected {len(data)} bytes, found {len(data) // 2}" in str(info.value)


def test_missing_file(tmp_path):
    store = new_store(tmp_path, 1)
    shutil.rmtree(tmp_path / "ds" / "frames_0000.zarr")
    with pytest.raises(ClodsError, match="missing") as info:
        store.load_frames(0)
    assert "frames_0000.zarr" in str(info.value)
    with pytest.raises(ClodsError, match="frames_0000.zarr"):
        store.verify()


def test_corrupt_content_same_size(tmp_path):
    store = new_store(tmp_path, 1)
    path = tmp_path / "ds" / "traj_0000.npz"
    path.write_bytes(b"\0" * path.stat().st_size)
    with pytest.raises(ClodsError, match="SHA-256 the dataset's manifest records") as info:
        store.load_trajectory(0, verify=True)
    assert "traj_0000.npz" in str(info.value)
    with pytest.raises(ClodsError, match="changed or damaged after it was written") as info:
        store.load_trajectory(0)  # checked on first read too, not only by verify
    assert "traj_0000.npz" in str(info.value)
    chunk = tmp_path / "ds" / "frames_0000.zarr" / "c.0.1.0.0.0"
    chunk.write_bytes(b"\0" * chunk.stat().st_size)
    with pytest.raises(ClodsError, match="crc32c") as info:
        store.load_frames(0)
    assert str(chunk) in str(info.value)
    with pytest.raises(ClodsError, match="c.0.1.0.0.0"):
        store.verify()


def test_missing_and_malformed_manifest(tmp_path):
    with pytest.raises(ClodsError, match="not found") as info:
        DatasetStore.open(tmp_path / "nope")
    assert "nope" in str(info.value)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ClodsError, match="manifest not found") as info:
        DatasetStore.open(tmp_path / "empty")
    assert "manifest.json" in str(info.value)
    new_store(tmp_path)
    manifest = tmp_path / "ds" / "manifest.json"
    manifest.write_text('{"schema_version": 1,\n "scene": }')
    with pytest.raises(ClodsError, match="malformed JSON at line 2, column") as info:
        DatasetStore.open(tmp_path / "ds")
    assert str(manifest) in str(info.value)


def test_wrong_schema_version(tmp_path):
    new_store(tmp_path)
    path = tmp_path / "ds" / "manifest.json"
    m = json.loads(path.read_text())
    m["schema_version"] = 99
    path.write_text(json.dumps(m))
    with pytest.raises(ClodsError, match="schema version 99"):
        DatasetStore.open(tmp_path / "ds")


def test_wrong_shapes(tmp_path):
    store = new_store(tmp_path, 1)
    path = tmp_path / "ds" / "manifest.json"
    m = json.loads(path.read_text())
    m["trajectories"][0]["shapes"]["world_pos"] = [T + 1, NX * NY, 3]
    m["trajectories"][0]["shapes"]["frames"] = [T, 2, H, W, 3]
    path.write_text(json.dumps(m))
    store = DatasetStore.open(tmp_path / "ds")
    with pytest.raises(ClodsError, match="manifest says") as info:
        store.load_trajectory(0)
    assert "traj_0000.npz.world_pos" in str(info.value)
    with pytest.raises(ClodsError, match="manifest says"):
        store.load_frames(0)


def test_write_rejects_bad_frames(tmp_path):
    store = new_store(tmp_path)
    for bad, msg in (
        (make_frames().astype(np.float32), "uint8"),
        (make_frames()[:-1], "frames but world_pos"),
        (make_frames(views=2), "cameras"),
        (make_frames()[:, :, :4], "image size"),
    ):
        with pytest.raises(ClodsError, match=msg):
            store.write_trajectory(0, "train", 0, make_traj(), bad)
    with pytest.raises(ClodsError, match="split"):
        store.write_trajectory(0, "valid", 0, make_traj(), None)
    assert store.completed_indices() == set()


def test_nan_in_world_pos(tmp_path):
    store = new_store(tmp_path)
    bad = make_traj()
    bad.world_pos[3, 2, 1] = np.nan
    with pytest.raises(ClodsError, match="world_pos"):
        store.write_trajectory(0, "train", 0, bad, None)  # refused at write time
    # NaN that got into a file anyway (written by other code) is caught at load time, naming the file.
    store.write_trajectory(0, "train", 0, make_traj(), None)
    path = tmp_path / "ds" / "traj_0000.npz"
    with np.load(path) as npz:
        arrays = dict(npz)
    arrays["world_pos"][3, 2, 1] = np.nan
    np.savez_compressed(path, **arrays)
    m = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    m["trajectories"][0]["files"]["traj"].update(bytes=path.stat().st_size, sha256=hashlib.sha256(path.read_bytes()).hexdigest())
    (tmp_path / "ds" / "manifest.json").write_text(json.dumps(m))  # the other code kept the manifest in step
    with pytest.raises(ClodsError, match="non-finite") as info:
        DatasetStore.open(tmp_path / "ds").load_trajectory(0)
    assert "traj_0000.npz" in str(info.value) and "world_pos" in str(info.value)


def test_config_mismatch(tmp_path):
    new_store(tmp_path, 1)
    other = dict(CONFIG, num_train=10)
    with pytest.raises(ClodsError) as info:
        DatasetStore.create(tmp_path / "ds", "flag", other, cams())
    text = str(info.value)
    assert "num_train (existing 2, requested 10)" in text and "--force" in text and "manifest.json" in text
    with pytest.raises(ClodsError, match="cameras"):
        DatasetStore.create(tmp_path / "ds", "flag", CONFIG, cams(4))
    store = DatasetStore.create(tmp_path / "ds", "flag", other, cams(), force=True)
    assert len(store) == 0 and not (tmp_path / "ds" / "traj_0000.npz").exists()
    assert DatasetStore.open(tmp_path / "ds").config["num_train"] == 10


def test_verify_reports_every_problem(tmp_path):
    store = new_store(tmp_path, 2)
    for name in ("traj_0000.npz", "frames_0001.zarr/c.0.2.0.0.0"):
        p = tmp_path / "ds" / name
        data = bytearray(p.read_bytes())
        data[-10] ^= 0xFF
        p.write_bytes(bytes(data))
    with pytest.raises(ClodsError, match="2 problem") as info:
        store.verify()
    assert "traj_0000.npz" in str(info.value) and "frames_0001.zarr/c.0.2.0.0.0" in str(info.value)
