"""Dataset content digests: independent of how the files were written, and naming the first differing frame."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from clods_bench.cli import main
from clods_bench.datasets.digest import _hash_arrays, compare_digests, dataset_digest, frames_digest
from clods_bench.datasets.store import DatasetStore
from tests.conftest import tiny_config


def _copy(tiny_root: Path, dst: Path) -> Path:
    src = tiny_config(tiny_root).data.dataset_dir()
    return Path(shutil.copytree(src, dst / src.name))


def _rewrite(store: DatasetStore, index: int, frame: int | None) -> None:
    """Write trajectory `index` again, uncompressed (another file: its size and sha256 updated in the manifest);
    with `frame`, one coordinate of that frame moved by one ulp."""
    path = store.root / store.entry(index)["files"]["traj"]["name"]
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    if frame is not None:
        wp = arrays["world_pos"]
        wp[frame, 0, 0] = np.nextafter(wp[frame, 0, 0], np.inf)
    with path.open("wb") as f:
        np.savez(f, **arrays)
    manifest_path = store.root / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    for entry in manifest["trajectories"]:
        if entry["index"] == index:
            entry["files"]["traj"].update(bytes=path.stat().st_size, sha256=hashlib.sha256(path.read_bytes()).hexdigest())
    manifest_path.write_text(json.dumps(manifest))


def test_digest_is_over_the_arrays_and_names_the_first_differing_frame(tiny_root: Path, tmp_path: Path) -> None:
    ref = DatasetStore.open(tiny_config(tiny_root).data.dataset_dir())
    ours = dataset_digest(ref, frames=True)
    traj = ref.load_trajectory(1)
    assert ours["trajectories"]["1"]["world_pos"][5] == _hash_arrays(traj.world_pos[5])[:16]
    images = ref.load_frames(1, mmap=False)  # (T, N, H, W, 3): camera-major order, whatever the read block
    whole = hashlib.sha256(f"|u1{images.shape}".encode())
    for view in range(images.shape[1]):
        whole.update(np.ascontiguousarray(images[:, view]).tobytes())
    assert ours["trajectories"]["1"]["frames"] == whole.hexdigest() == frames_digest(ref.frames(1), block=5)
    copy_root = _copy(tiny_root, tmp_path)
    _rewrite(DatasetStore.open(copy_root), 0, None)  # same arrays, another file
    copy = DatasetStore.open(copy_root)
    assert copy.entry(0)["files"]["traj"]["sha256"] != ref.entry(0)["files"]["traj"]["sha256"]
    assert compare_digests(dataset_digest(copy, frames=True), ours) == []
    _rewrite(copy, 1, 7)  # one coordinate of frame 7 one ulp off
    copy = DatasetStore.open(copy_root)
    problems = compare_digests(dataset_digest(copy), ours)
    n = traj.world_pos.shape[0]
    assert problems == [f"trajectory 1: world_pos differs from frame 7 on (1 of {n} frames)"]
    del ours["trajectories"]["2"]
    assert "trajectory 2: only in the first dataset" in compare_digests(dataset_digest(copy), ours)


def test_cli_writes_and_compares(tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = tiny_config(tiny_root).data.dataset_dir()
    out = tmp_path / "digest.json"
    assert main(["data", "digest", str(root), "--out", str(out)]) == 0
    assert json.loads(out.read_text())["scene"] == "flag"
    copy = _copy(tiny_root, tmp_path)
    assert main(["data", "digest", str(copy), "--against", str(out)]) == 0
    _rewrite(DatasetStore.open(copy), 0, 3)
    capsys.readouterr()
    assert main(["data", "digest", str(copy), "--against", str(out)]) == 1
    assert "trajectory 0: world_pos differs from frame 3 on" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    assert main(["data", "digest", str(copy), "--against", str(bad)]) == 2
    assert "not a digest file" in capsys.readouterr().err
