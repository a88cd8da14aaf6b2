"""FLAGSIMPLE reader on real TFRecord files written in the meshgraphnets format."""

import json

import numpy as np
import pytest

from clods_bench.datasets.flagsimple import import_flagsimple, read_flagsimple, read_meta
from clods_bench.datasets.flagsimple_writer import flag_meta, trajectory_record, write_flagsimple, write_records
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import HANDLE, Trajectory
from clods_bench.errors import ClodsError

T, NX, NY = 5, 5, 4  # 20 nodes, 5 frames


def make_traj(seed: int) -> Trajectory:
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(NX, dtype=np.float32), np.arange(NY, dtype=np.float32), indexing="ij")
    mesh_pos = np.stack([xs.ravel(), ys.ravel()], axis=1) * 0.1
    idx = np.arange(NX * NY).reshape(NX, NY)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    cells = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    node_type = np.zeros(NX * NY, np.int32)
    node_type[idx[0]] = HANDLE
    world_pos = rng.standard_normal((T, NX * NY, 3)).astype(np.float32)
    return Trajectory(cells, mesh_pos, node_type, world_pos, 0.02)


@pytest.fixture
def src(tmp_path):
    write_flagsimple(tmp_path / "flag_simple", [make_traj(0), make_traj(1)], split="train")
    return tmp_path / "flag_simple"


def test_read_back_equals_written(src):
    trajs = list(read_flagsimple(src, "train"))
    assert len(trajs) == 2
    for i, got in enumerate(trajs):
        ref = make_traj(i)
        for key in ("cells", "mesh_pos", "node_type", "world_pos"):
            np.testing.assert_array_equal(getattr(got, key), getattr(ref, key))
        assert got.cells.shape == (2 * (NX - 1) * (NY - 1), 3) and got.node_type.shape == (NX * NY,)
        assert got.cells.dtype == np.int32 and got.world_pos.dtype == np.float32
        assert got.dt == 0.02 and got.meta["record"] == i and got.meta["split"] == "train"
    assert len(list(read_flagsimple(src, limit=1))) == 1
    assert next(read_flagsimple(src, dt=0.01)).dt == 0.01


def test_meta_written_in_mgn_format(src):
    meta = json.loads((src / "meta.json").read_text())
    assert meta["field_names"] == ["cells", "mesh_pos", "node_type", "world_pos"]
    assert meta["features"]["world_pos"] == {"type": "dynamic", "shape": [T, -1, 3], "dtype": "float32"}
    assert meta["trajectory_length"] == T


def test_tf_dtype_repr_in_meta_is_accepted(src):
    meta = json.loads((src / "meta.json").read_text())
    meta["features"]["world_pos"]["dtype"] = "<dtype: 'float32'>"
    del meta["dt"]  # the reader then falls back to FLAGSIMPLE's 0.02 s
    (src / "meta.json").write_text(json.dumps(meta))
    assert read_meta(src)["features"]["world_pos"]["dtype"] == "float32"
    assert next(read_flagsimple(src)).dt == 0.02


def test_import_into_store(src, tmp_path):
    store = import_flagsimple(src, tmp_path / "store", "train", num_train=1, num_steps=4)
    assert store.indices("train") == [0] and store.indices("test") == [1] and store.cameras() == []
    got = store.load_trajectory(1, verify=True)
    np.testing.assert_array_equal(got.world_pos, make_traj(1).world_pos[:4])
    again = import_flagsimple(src, tmp_path / "store", "train", num_train=1, num_steps=4)  # resume: nothing to do
    assert again.completed_indices() == {0, 1}
    with pytest.raises(ClodsError, match="fewer than num_steps"):
        import_flagsimple(src, tmp_path / "store2", "train", num_steps=T + 1)
    with pytest.raises(ClodsError, match="different config"):
        import_flagsimple(src, tmp_path / "store", "train", num_train=2, num_steps=4)


def test_missing_files(tmp_path, src):
    with pytest.raises(ClodsError, match="meta.json not found") as info:
        list(read_flagsimple(tmp_path / "nothing"))
    assert "nothing" in str(info.value)
    with pytest.raises(ClodsError, match="test.tfrecord not found") as info:
        list(read_flagsimple(src, "test"))
    assert str(src / "test.tfrecord") in str(info.value)
    with pytest.raises(ClodsError, match="unknown split"):
        list(read_flagsimple(src, "training"))


def test_field_missing_from_record(src):
    good = trajectory_record(make_traj(0))
    bad = {k: v for k, v in good.items() if k != "node_type"}
    write_records(src / "train.tfrecord", [good, bad])
    with pytest.raises(ClodsError, match="field missing") as info:
        list(read_flagsimple(src))
    text = str(info.value)
    assert "train.tfrecord record 1" in text and "'node_type'" in text


def test_wrong_byte_length(src):
    rec = trajectory_record(make_traj(0))
    rec["world_pos"] = rec["world_pos"][:-4]  # one float short
    write_records(src / "train.tfrecord", [rec])
    with pytest.raises(ClodsError, match="bytes do not fit") as info:
        list(read_flagsimple(src))
    assert "record 0" in str(info.value) and "'world_pos'" in str(info.value)
    rec = trajectory_record(make_traj(0))
    rec["cells"] = rec["cells"][:-2]  # not a whole number of int32
    write_records(src / "train.tfrecord", [rec])
    with pytest.raises(ClodsError, match="record 0 field 'cells'"):
        list(read_flagsimple(src))


def test_truncated_tfrecord(src):
    path = src / "train.tfrecord"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 100])
    with pytest.raises(ClodsError, match="cannot read record 1") as info:
        list(read_flagsimple(src))
    assert "train.tfrecord" in str(info.value)


def test_meta_errors(src):
    (src / "meta.json").write_text("{not json")
    with pytest.raises(ClodsError, match="malformed JSON"):
        read_meta(src)
    meta = flag_meta(T)
    del meta["features"]["world_pos"]
    (src / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(ClodsError, match="no field 'world_pos'"):
        read_meta(src)


def test_nan_in_record_names_record_and_field(src):
    traj = make_traj(0)
    traj.world_pos[2, 3, 0] = np.nan
    write_records(src / "train.tfrecord", [trajectory_record(traj)])
    with pytest.raises(ClodsError, match="non-finite") as info:
        list(read_flagsimple(src))
    assert "record 0" in str(info.value) and "world_pos" in str(info.value)
