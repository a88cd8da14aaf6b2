"""Frame store: bit-exact round trip, lazy reads touch only their chunks, damaged chunks fail naming the file,
an interrupted write leaves nothing that looks complete."""

import json

import numpy as np
import pytest

from clods_bench.datasets.frame_store import FrameWriter, LazyFrames, chunk_key, default_chunk_frames, write_frames
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from tests.datasets.test_store import CONFIG, cams, make_frames, make_traj

T, N, H, W = 7, 3, 6, 5


def frames() -> np.ndarray:
    """Random pixels plus flat and smooth regions (what the delta filter and the compressor see in real frames)."""
    rng = np.random.default_rng(3)
    out = rng.integers(0, 256, (T, N, H, W, 3), dtype=np.uint8)
    out[:, :, :2] = 255
    out[:, :, 4:] = np.arange(W, dtype=np.uint8)[None, None, None, :, None] * 40
    return out


@pytest.fixture
def array(tmp_path):
    write_frames(tmp_path / "f.zarr", frames(), chunk_frames=3)  # time chunks [0,3) [3,6) [6,7)
    return tmp_path / "f.zarr"


def test_round_trip_is_bit_exact(tmp_path, array):
    ref, lazy = frames(), LazyFrames(array)
    assert lazy.shape == ref.shape and lazy.dtype == np.uint8 and len(lazy) == T and lazy.chunk_frames == 3
    np.testing.assert_array_equal(lazy[:], ref)
    np.testing.assert_array_equal(np.asarray(lazy), ref)
    for key in (np.s_[1:5, [2, 0]], np.s_[4], np.s_[-1, 1], np.s_[:, 1, 2:4], np.s_[2:7:2, -1, :, :, 0], np.s_[[6, 0], 1], np.s_[5, [1, 2]]):
        np.testing.assert_array_equal(lazy[key], ref[key])
    np.testing.assert_array_equal(lazy.read([0, 6], [2, 1]), ref[[0, 6]][:, [2, 1]])  # orthogonal
    with pytest.raises(ClodsError, match="both the time and the camera"):
        lazy[[0, 1], [0, 1]]
    with pytest.raises(IndexError):
        lazy[T]
    streamed = write_frames(tmp_path / "s.zarr", iter(ref), ref.shape, chunk_frames=3)  # one step at a time
    assert streamed["chunks"] == 3 * N and streamed["chunk_shape"] == [3, 1, H, W, 3]
    assert all((tmp_path / "s.zarr" / p.name).read_bytes() == p.read_bytes() for p in array.iterdir())


def test_chunk_length_from_image_size():
    assert default_chunk_frames((401, 30, 800, 800, 3)) == 4
    assert default_chunk_frames((41, 6, 64, 64, 3)) == 41
    assert default_chunk_frames((101, 10, 128, 128, 3)) == 64


def test_lazy_read_touches_only_its_chunks(array):
    keep = {chunk_key(1, 2)}  # frames 3..5 of camera 2
    for p in array.glob("c.*"):
        if p.name not in keep:
            p.unlink()
    lazy = LazyFrames(array)
    np.testing.assert_array_equal(lazy[3:6, 2], frames()[3:6, 2])
    np.testing.assert_array_equal(lazy[4, [2]], frames()[4, [2]])
    assert lazy.chunks_read == 2
    with pytest.raises(ClodsError, match="chunk file missing") as info:
        lazy[2:4, 2]  # frame 2 lives in a deleted chunk: an error, never zarr's zero fill
    assert chunk_key(0, 2) in str(info.value)


def test_sparse_frames_decode_only_their_chunks(array):
    lazy = LazyFrames(array)
    lazy.read([0, 6], [1])
    assert lazy.chunks_read == 2  # time chunks 0 and 2, not chunk 1 between them


def test_selection_reads_nothing_until_indexed_and_equals_numpy(array):
    ref, lazy = frames(), LazyFrames(array)
    sel = lazy.select(slice(1, 7), [2, 0])
    assert lazy.chunks_read == 0 and sel.shape == (6, 2, H, W, 3) and len(sel) == 6
    want = ref[1:7][:, [2, 0]]
    np.testing.assert_array_equal(sel[:], want)
    for key in (np.s_[3], np.s_[-1], np.s_[2:5, 1], np.s_[0, [1]], np.s_[4, :, 1:3]):
        np.testing.assert_array_equal(sel[key], want[key])
    np.testing.assert_array_equal(sel.read([5, 0], [1]), want[[5, 0]][:, [1]])
    np.testing.assert_array_equal(lazy.select()[:], ref)
    with pytest.raises(IndexError):
        sel[6]
    with pytest.raises(IndexError):
        lazy.select(slice(None), [3])


def test_walking_a_selection_frame_by_frame_decodes_each_chunk_once(array):
    ref, lazy = frames(), LazyFrames(array)
    sel = lazy.select(slice(0, 7), [0, 2])
    for t in range(7):
        np.testing.assert_array_equal(sel[t], ref[t][[0, 2]])
    assert lazy.chunks_read == 3 * 2  # time chunks [0,3) [3,6) [6,7) of 2 cameras, each once (frame by frame: 7 x 2)
    np.testing.assert_array_equal(sel[6], ref[6][[0, 2]])  # the last block is held
    assert lazy.chunks_read == 6
    odd = lazy.select([5, 1, 2], [1])  # not consecutive: each frame its own block, values still right
    np.testing.assert_array_equal(np.stack([odd[t] for t in range(3)]), ref[[5, 1, 2]][:, [1]])


@pytest.mark.parametrize("damage", ["flip", "truncate", "empty"])
def test_damaged_chunk_names_the_file(array, damage):
    path = array / chunk_key(1, 0)
    data = bytearray(path.read_bytes())
    if damage == "flip":
        data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data[: len(data) // 2] if damage == "truncate" else b"" if damage == "empty" else data))
    lazy = LazyFrames(array)
    np.testing.assert_array_equal(lazy[:, 1], frames()[:, 1])  # other chunks still read
    with pytest.raises(ClodsError, match="crc32c check or cannot be decoded") as info:
        lazy[:, 0]
    assert str(path) in str(info.value) and "frames 3..5 of camera 0" in str(info.value)
    with pytest.raises(ClodsError, match=chunk_key(1, 0)):
        lazy.verify()


def test_metadata_checked_against_the_manifest(array):
    record = {"sha256": "0" * 64}
    with pytest.raises(ClodsError, match="zarr.json differs from the manifest"):
        LazyFrames(array, record)
    meta = array / "zarr.json"
    meta.write_text(meta.read_text()[:40])
    with pytest.raises(ClodsError, match="cannot open frame array") as info:
        LazyFrames(array)
    assert str(array) in str(info.value)


def test_interrupted_writer_leaves_nothing(tmp_path):
    ref = frames()

    def steps():
        yield from ref[:4]  # the first time chunk is flushed to disk, then the producer dies
        raise KeyboardInterrupt("killed mid-write")

    with pytest.raises(KeyboardInterrupt):
        write_frames(tmp_path / "f.zarr", steps(), ref.shape, chunk_frames=3)
    assert list(tmp_path.iterdir()) == []  # no target, no temp directory
    with pytest.raises(ClodsError, match="4 time steps written, 7 declared"):
        with FrameWriter(tmp_path / "g.zarr", ref.shape, 3) as writer:
            for step in ref[:4]:
                writer.append(step)
            writer.close()
    assert list(tmp_path.iterdir()) == []


def test_kill_between_chunk_writes_keeps_the_manifest(tmp_path):
    """A trajectory whose frames die between chunk writes gets no entry; the manifest is byte-identical; a rerun resumes."""
    store = DatasetStore.create(tmp_path / "ds", "flag", CONFIG, cams())
    store.write_trajectory(0, "train", 100, make_traj(0), make_frames(0))
    before = (tmp_path / "ds" / "manifest.json").read_bytes()

    def dying():
        for t, step in enumerate(make_frames(1)):
            if t == 3:
                raise RuntimeError("killed between chunk writes")
            yield step

    with pytest.raises(RuntimeError):
        store.write_trajectory(1, "train", 101, make_traj(1), dying())
    assert (tmp_path / "ds" / "manifest.json").read_bytes() == before
    assert not (tmp_path / "ds" / "frames_0001.zarr").exists()
    assert not any(p.name.startswith(".frames_0001") for p in (tmp_path / "ds").iterdir())
    resumed = DatasetStore.create(tmp_path / "ds", "flag", CONFIG, cams())
    assert resumed.completed_indices() == {0}
    resumed.write_trajectory(1, "train", 101, make_traj(1), iter(make_frames(1)))
    np.testing.assert_array_equal(DatasetStore.open(tmp_path / "ds").load_frames(1, verify=True), make_frames(1))
    entry = json.loads((tmp_path / "ds" / "manifest.json").read_text())["trajectories"][1]["files"]["frames"]
    assert entry["format"] == "zarr-v3" and entry["name"] == "frames_0001.zarr"
