"""`data export --format nerf` and `data import-video`: the round trip against the generated dataset, and bad input.

The tiny dataset (tests/conftest.py: 3 trajectories of 12 frames, 3 cameras of 24 px) is exported, imported and
compared with the original: cameras to 1e-6, PNG frames bit-equal, MP4 frames (written here with PyAV) within the
codec's error, meshes re-attached equal. Every bad input must raise one ClodsError naming the file and field and
leave the output folder absent (or, with --force over an existing one, untouched).
"""

from __future__ import annotations

import json
import shutil
from fractions import Fraction
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from clods_bench.datasets import video_import
from clods_bench.datasets.nerf import camera_to_c2w_gl, export_nerf
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.video_import import BACKGROUND, import_video
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config


@pytest.fixture(scope="module")
def original(tiny_root: Path) -> DatasetStore:
    return DatasetStore.open(tiny_config(tiny_root).data.dataset_dir())


@pytest.fixture(scope="module")
def exported(original: DatasetStore, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny dataset in the NeRF layout with PLY meshes (and a copy of trajectory 0 with OBJ meshes)."""
    out = tmp_path_factory.mktemp("nerf")
    cfg = original.config
    export_nerf(original, out / "ply", "ply", None, cfg["num_views_test"], cfg["interp_steps"])
    export_nerf(original, out / "obj", "obj", [0], cfg["num_views_test"], cfg["interp_steps"])
    return out


def _captures(root: Path) -> list[Path]:
    return sorted(root.glob("traj_*/transforms.json"))


def _copy(exported: Path, tmp_path: Path) -> Path:
    """A writable copy of the PLY export (bad-input tests edit it)."""
    dst = tmp_path / "src"
    shutil.copytree(exported / "ply", dst)
    return dst


def _write_mp4(path: Path, frames: np.ndarray, fps: Fraction | int, pix_fmt: str = "yuv444p", crf: int = 0) -> None:
    """(T,H,W,3) uint8 frames as an H.264 video through PyAV (crf 0 + yuv444p: only the RGB<->YUV rounding is lost)."""
    av = pytest.importorskip("av")
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt, stream.options = frames.shape[2], frames.shape[1], pix_fmt, {"crf": str(crf)}
        for f in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def _as_video_capture(src: Path, capture: Path, frames: np.ndarray, fps=50, lengths: dict[int, int] | None = None,
                      rates: dict[int, int] | None = None) -> Path:  # fmt: skip
    """Rewrite one exported capture as one MP4 per camera (one `frames` entry each); returns its transforms.json."""
    doc = json.loads((capture / "transforms.json").read_text())
    entries = {}
    for e in doc["frames"]:
        entries.setdefault(e["camera"], e)
    new = []
    for n, (name, e) in enumerate(entries.items()):
        T = (lengths or {}).get(n, frames.shape[0])
        _write_mp4(capture / f"{name}.mp4", frames[:T, n], (rates or {}).get(n, fps))
        new.append({**e, "file_path": f"{name}.mp4"})
        shutil.rmtree(capture / "images" / name)
    doc["frames"] = new
    doc.pop("fps")
    doc.pop("dt")  # the rate comes from the videos
    (capture / "transforms.json").write_text(json.dumps(doc))
    return capture / "transforms.json"


# ------------------------------------------------------------------ round trip


def test_export_writes_nerf_layout_with_opengl_cameras(original: DatasetStore, exported: Path) -> None:
    doc = json.loads((exported / "ply" / "traj_0000" / "transforms.json").read_text())
    cams = original.cameras()
    assert doc["fps"] == pytest.approx(1.0 / original.dt(0)) and doc["dt"] == original.dt(0)
    assert doc["fl_x"] == cams[0].K[0, 0] and doc["cx"] == cams[0].K[0, 2] and (doc["w"], doc["h"]) == (cams[0].width, cams[0].height)
    assert len(doc["frames"]) == original.frames(0).shape[0] * len(cams)
    frames = original.load_frames(0)
    for e in doc["frames"][:: 7]:
        n = int(e["camera"][-2:])
        assert np.array_equal(e["transform_matrix"], camera_to_c2w_gl(cams[n]))
        assert np.array_equal(iio.imread(exported / "ply" / "traj_0000" / e["file_path"]), frames[e["frame"], n])
    assert (exported / "ply" / "traj_0000" / "meshes" / "frame_0011.ply").is_file()
    assert not list((exported / "ply").glob(".*"))  # no temporary folders left


def _assert_same_cameras(a: DatasetStore, b: DatasetStore) -> None:
    for ca, cb in zip(a.cameras(), b.cameras(), strict=True):
        for key in ("K", "R", "t"):
            assert np.abs(getattr(ca, key) - getattr(cb, key)).max() < 1e-6
        assert (ca.width, ca.height) == (cb.width, cb.height)


def test_round_trip_without_meshes_is_bit_equal(original: DatasetStore, exported: Path, tmp_path: Path) -> None:
    imp = import_video(_captures(exported / "ply"), tmp_path / "imp")
    assert not imp.has_meshes and len(imp) == len(original)
    _assert_same_cameras(original, imp)
    for key in ("num_train", "num_test", "num_steps", "interp_steps", "num_cameras", "num_views_test", "image_size"):
        assert imp.config[key] == original.config[key], key
    for i in sorted(original.completed_indices()):
        assert imp.entry(i)["split"] == original.entry(i)["split"]
        assert imp.dt(i) == original.dt(i)
        assert np.array_equal(imp.load_frames(i), original.load_frames(i))
    with pytest.raises(ClodsError, match="has no meshes"):
        imp.load_trajectory(0)
    imp.verify()


@pytest.mark.parametrize("fmt", ["ply", "obj"])
def test_round_trip_reattaches_the_meshes(original: DatasetStore, exported: Path, tmp_path: Path, fmt: str) -> None:
    imp = import_video(_captures(exported / fmt), tmp_path / "imp", meshes="meshes")
    assert imp.has_meshes
    for i in sorted(imp.completed_indices()):
        a, b = original.load_trajectory(i), imp.load_trajectory(i)
        assert np.array_equal(a.cells, b.cells) and np.array_equal(a.mesh_pos, b.mesh_pos) and np.array_equal(a.node_type, b.node_type)
        err = np.abs(a.world_pos - b.world_pos).max()
        assert err == 0.0 if fmt == "ply" else err < 1e-6  # binary PLY keeps every float32 bit; OBJ text 8 decimals
        assert b.dt == a.dt


def test_mp4_round_trip_is_within_the_codec_error(original: DatasetStore, exported: Path, tmp_path: Path) -> None:
    pytest.importorskip("av")
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    for i, cap in enumerate(caps):
        _as_video_capture(src, cap.parent, original.load_frames(i))
    imp = import_video(caps, tmp_path / "imp")
    _assert_same_cameras(original, imp)
    assert imp.dt(0) == pytest.approx(original.dt(0), rel=1e-9)  # 50 fps from the videos
    for i in sorted(original.completed_indices()):
        a, b = original.load_frames(i).astype(np.float64), imp.load_frames(i).astype(np.float64)
        psnr = 10 * np.log10(255.0**2 / np.mean((a - b) ** 2))
        assert psnr > 45.0, psnr  # lossless H.264 in YUV 4:4:4: only the colour conversion rounds (56.5 dB at worst on ci)


def test_mp4_without_pyav_is_one_clear_line(exported: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, original) -> None:
    pytest.importorskip("av")
    src = _copy(exported, tmp_path)
    cap = _as_video_capture(src, _captures(src)[0].parent, original.load_frames(0))
    monkeypatch.setattr(video_import, "_av", lambda: None)
    with pytest.raises(ClodsError, match="PyAV") as info:
        import_video([cap], tmp_path / "imp")
    assert "clods-bench[video]" in info.value.message and "\n" not in info.value.message
    assert not (tmp_path / "imp").exists()


def test_alpha_and_mask_folders_turn_masked_pixels_white(original: DatasetStore, exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    cap = _captures(src)[0]
    frames = original.load_frames(0)
    rng = np.random.default_rng(1)
    alpha = rng.integers(0, 256, size=frames.shape[2:4], dtype=np.uint8)  # cam_00 frame 3 gets an alpha channel
    rgba = np.dstack([frames[3, 0], alpha])
    iio.imwrite(cap.parent / "images/cam_00/frame_0003.png", rgba)
    mask = np.full(frames.shape[2:4], 255, np.uint8)
    mask[:, :5] = 0  # mask folder: the 5 left columns of every camera's frames are masked out
    for name in ("cam_00", "cam_01", "cam_02"):
        (cap.parent / "masks" / name).mkdir(parents=True)
        for t in range(frames.shape[0]):
            iio.imwrite(cap.parent / "masks" / name / f"frame_{t:04d}.png", mask)
    # masks are looked up for every capture: give the others the same folders
    for other in _captures(src)[1:]:
        shutil.copytree(cap.parent / "masks", other.parent / "masks")
    imp = import_video(_captures(src), tmp_path / "imp", masks="masks")
    got = imp.load_frames(0)
    assert (got[:, :, :, :5] == BACKGROUND).all()
    assert np.array_equal(got[:, :, :, 5:][:, 1:], frames[:, 1:, :, 5:])  # unmasked pixels untouched
    a = alpha[:, 5:, None].astype(np.float64) / 255.0
    expected = np.rint(frames[3, 0, :, 5:] * a + 255.0 * (1.0 - a))
    assert np.abs(got[3, 0, :, 5:].astype(np.float64) - expected).max() <= 1  # alpha blended over white


# ------------------------------------------------------------------ bad input


def _edit(cap: Path, fn) -> None:
    doc = json.loads(cap.read_text())
    fn(doc)
    cap.write_text(json.dumps(doc))


def _refused(caps: list[Path], out: Path, match: str, where: str, **kw) -> ClodsError:
    with pytest.raises(ClodsError, match=match) as info:
        import_video(caps, out, **kw)
    assert where in (info.value.where or ""), info.value.message
    assert not out.exists() or (out / "keep.txt").read_text() == "old"  # nothing half-written
    assert not list(out.parent.glob(f".{out.name}.*"))  # no temporary folder left behind
    return info.value


def test_missing_matrix(exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    _edit(caps[1], lambda d: d["frames"][4].pop("transform_matrix"))
    _refused(caps, tmp_path / "imp", "missing", f"{caps[1]}: frames[4].transform_matrix")


def test_non_invertible_matrix(exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    _edit(caps[0], lambda d: d["frames"][2].__setitem__("transform_matrix", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]))
    _refused(caps, tmp_path / "imp", "not invertible", f"{caps[0]}: frames[2].transform_matrix")


def test_image_size_disagrees_with_the_camera(exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    _edit(caps[2], lambda d: d.update(w=32))
    err = _refused([caps[2]], tmp_path / "imp", "image is 24x24 but transforms.json says w=32", "frame_0000.png")
    assert ".w/h" in err.where


def test_failure_late_in_the_import_leaves_an_existing_output_untouched(exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    last = caps[-1].parent / "images" / "cam_02" / "frame_0011.png"
    iio.imwrite(last, np.zeros((20, 24, 3), np.uint8))  # the very last image read is the wrong size
    out = tmp_path / "imp"
    out.mkdir()
    (out / "keep.txt").write_text("old")
    _refused(caps, out, "image is 24x20", str(last), force=True)


def test_videos_of_different_lengths(original: DatasetStore, exported: Path, tmp_path: Path) -> None:
    pytest.importorskip("av")
    src = _copy(exported, tmp_path)
    cap = _as_video_capture(src, _captures(src)[0].parent, original.load_frames(0), lengths={2: 9})
    _refused([cap], tmp_path / "imp", "camera 'cam_02' has 9 frames, camera 'cam_00' has 12", "cam_02.mp4")


def test_videos_of_different_frame_rates(original: DatasetStore, exported: Path, tmp_path: Path) -> None:
    pytest.importorskip("av")
    src = _copy(exported, tmp_path)
    cap = _as_video_capture(src, _captures(src)[0].parent, original.load_frames(0), rates={1: 25})
    _refused([cap], tmp_path / "imp", "frame rate 25 fps, camera 'cam_00' has 50 fps", "cam_01.mp4")


def test_video_rate_disagrees_with_transforms(original: DatasetStore, exported: Path, tmp_path: Path) -> None:
    pytest.importorskip("av")
    src = _copy(exported, tmp_path)
    cap = _as_video_capture(src, _captures(src)[0].parent, original.load_frames(0))
    _edit(cap, lambda d: d.update(fps=30))
    _refused([cap], tmp_path / "imp", "disagrees", f"{cap}: fps")


def test_masks_of_the_wrong_size(exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    for cap in caps:
        for name in ("cam_00", "cam_01", "cam_02"):
            (cap.parent / "m" / name).mkdir(parents=True)
            for t in range(12):
                size = (12, 24) if (name, t) == ("cam_01", 5) else (24, 24)
                iio.imwrite(cap.parent / "m" / name / f"{t:04d}.png", np.full(size, 255, np.uint8))
    err = _refused(caps, tmp_path / "imp", "mask is 24x12, its frame 24x24", "m/cam_01/0005.png", masks="m")
    assert "(size)" in err.where


def test_mask_count_must_match_the_frames(exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    (caps[0].parent / "m" / "cam_00").mkdir(parents=True)
    _refused(caps, tmp_path / "imp", "0 mask images, camera 'cam_00' has 12 frames", "m/cam_00", masks="m")
    for t in range(12):
        iio.imwrite(caps[0].parent / "m" / "cam_00" / f"{t:04d}.png", np.full((24, 24), 255, np.uint8))
    _refused(caps, tmp_path / "imp", "mask folder of camera 'cam_01' not found", "m/cam_01", masks="m")


def test_empty_first_frame(exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    first = caps[1].parent / "images" / "cam_01" / "frame_0000.png"
    iio.imwrite(first, np.full((24, 24, 3), 250, np.uint8))  # white but for noise below the threshold
    err = _refused(caps, tmp_path / "imp", "first frame shows no foreground", str(first))
    assert "frames[" in err.where


def test_moving_camera_and_missing_frame_rate(exported: Path, tmp_path: Path) -> None:
    src = _copy(exported, tmp_path)
    caps = _captures(src)
    _edit(caps[0], lambda d: d["frames"][3]["transform_matrix"][0].__setitem__(3, 9.0))  # frame 1 of cam_00 moves
    _refused(caps, tmp_path / "imp", "moving cameras are not supported", f"{caps[0]}: frames[3].transform_matrix")
    src2 = tmp_path / "b"
    shutil.copytree(exported / "ply", src2)
    cap = _captures(src2)[0]
    _edit(cap, lambda d: (d.pop("fps"), d.pop("dt")))
    _refused([cap], tmp_path / "imp2", "frame rate unknown", f"{cap}: fps")


def test_existing_output_is_refused_without_force(exported: Path, tmp_path: Path) -> None:
    out = tmp_path / "imp"
    out.mkdir()
    (out / "keep.txt").write_text("old")
    _refused(_captures(exported / "ply"), out, "exists and is not empty", str(out))


# ------------------------------------------------------------------ command line


def test_cli_export_and_import(original: DatasetStore, tiny_root: Path, tmp_path: Path, capsys) -> None:
    from clods_bench.cli import main
    from tests.conftest import TINY

    sets = [a for s in [*TINY, f"data.root={tiny_root / 'data'}"] for a in ("--set", s)]
    assert main(["data", "export", *sets, "--format", "nerf", "--traj", "0", "2", "--out", str(tmp_path / "nerf")]) == 0
    caps = _captures(tmp_path / "nerf")
    assert [c.parent.name for c in caps] == ["traj_0000", "traj_0002"]
    assert main(["data", "import-video", *map(str, caps), "--out", str(tmp_path / "imp")]) == 0
    assert "run on it with --set data.path=" in " ".join(capsys.readouterr().out.split())  # rich wraps at any space
    imp = DatasetStore.open(tmp_path / "imp")
    assert np.array_equal(imp.load_frames(1), original.load_frames(2)) and imp.entry(1)["split"] == "test"
    _edit(caps[0], lambda d: d["frames"][0].pop("transform_matrix"))
    assert main(["data", "import-video", *map(str, caps), "--out", str(tmp_path / "imp2")]) == 2
    err = capsys.readouterr().err
    assert "frames[0].transform_matrix: missing" in " ".join(err.split()) and not (tmp_path / "imp2").exists()
    assert main(["data", "export", *sets, "--format", "obj", "--meshes", "ply", "--out", str(tmp_path / "o")]) == 2
