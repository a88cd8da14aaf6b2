"""Every reader of a trusted artefact checks the hash written with it: sealed zip files (.npz, .pt), sealed JSON,
files whose hash the dataset manifest keeps. A changed byte anywhere is one error naming the file and the remedy;
files written before seals existed are read as before; a verified file is hashed once per process."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from clods_bench import integrity
from clods_bench.atomic import write_npz as unsealed_npz
from clods_bench.benchmark.clods.cache import Extracted, ExtractionCache
from clods_bench.benchmark.clods.stage1 import fit_stage1_keyed
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.tasks.nvs import _load_partial, _save_partial
from clods_bench.datasets.digest import CONTENT_DIGEST_FILE, content_digest
from clods_bench.datasets.generate import generate
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.checkpoint import load_checkpoint, load_snapshot, save_checkpoint, save_snapshot
from tests.benchmark.clods.conftest import cameras, grid
from tests.conftest import tiny_config
from tests.reliability.integrity_helpers import flip_bit

CHANGED = "content differs from the SHA-256 written with it: the file was changed or damaged after it was written"


def _message(path: Path, remedy: str) -> str:
    return f"{path}: {CHANGED} ({remedy})"


@pytest.fixture(autouse=True)
def _fresh_cache():
    integrity.forget()
    yield
    integrity.forget()


def test_a_sealed_npz_and_pt_read_as_before_and_every_flipped_byte_is_caught(tmp_path: Path) -> None:
    npz, pt = tmp_path / "a.npz", tmp_path / "b.pt"
    integrity.write_npz(npz, x=np.arange(50.0), y=np.eye(3))
    integrity.save_torch({"w": torch.arange(40.0)}, pt)
    with np.load(npz) as z:
        assert z["x"].tolist() == list(range(50))
    assert torch.load(pt, weights_only=True)["w"].tolist() == list(range(40))
    assert zipfile.ZipFile(npz).comment.startswith(b"clods-sha256:")
    for path in (npz, pt):
        good = path.read_bytes()
        for offset in range(0, len(good), max(1, len(good) // 97)):  # about 100 positions across the file, seal included
            flip_bit(path, offset, bit=offset % 8)
            integrity.forget()
            with pytest.raises(ClodsError) as err:
                integrity.check_zip(path, "delete it")
            assert str(err.value) in (_message(path, "delete it"),
                                      f"{path}: content differs from the SHA-256 written with it (its zip end record is damaged): "
                                      f"the file was changed or damaged after it was written (delete it)"), offset  # fmt: skip
            path.write_bytes(good)
        integrity.forget()
        integrity.check_zip(path, "delete it")


def test_files_written_before_seals_are_read_as_before(tmp_path: Path) -> None:
    npz, pt = tmp_path / "old.npz", tmp_path / "old.pt"
    unsealed_npz(npz, x=np.arange(3))
    torch.save({"w": torch.zeros(2)}, pt)
    integrity.check_zip(npz, "x")
    integrity.check_zip(pt, "x")
    assert integrity.check_json({"a": 1.5}, tmp_path / "r.json", "x") == {"a": 1.5}
    doc = integrity.seal_json({"a": 1.5, "b": [float("nan"), 2]})
    assert doc["b"] == [None, 2] and integrity.check_json(json.loads(json.dumps(doc)), tmp_path / "r.json", "x") == doc
    with pytest.raises(ClodsError, match="r.json: content differs"):
        integrity.check_json({**doc, "a": 1.25}, tmp_path / "r.json", "x")


def test_a_verified_file_is_hashed_once_per_process_until_it_changes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    log = tmp_path / "hashes.log"
    monkeypatch.setenv(integrity.LOG_ENV, str(log))
    path = tmp_path / "a.npz"
    integrity.write_npz(path, x=np.arange(1000.0))
    for _ in range(5):
        integrity.check_zip(path, "x")
    kinds = [line.split()[0] for line in log.read_text().splitlines()]
    assert kinds == ["seal", "check-zip"]
    integrity.write_npz(path, x=np.arange(1000.0) + 1)  # rewritten: another inode and ctime
    integrity.check_zip(path, "x")
    assert [line.split()[0] for line in log.read_text().splitlines()] == ["seal", "check-zip", "seal", "check-zip"]


def test_extraction_cache(tmp_path: Path) -> None:
    cache = ExtractionCache(tmp_path, "k", {"t": 1})
    ext = Extracted(np.ones((2, 4, 3), np.float32), np.array([0, 3]), np.array([np.nan, 0.5]), np.array([0.0, 1.0]))
    for partial in (False, True):
        cache.save(2, ext, partial=partial)
        path = cache.path(2, partial)
        np.testing.assert_array_equal(cache.load(2, partial).world_pos, ext.world_pos)
        flip_bit(path, 40)
        with pytest.raises(ClodsError) as err:
            cache.load(2, partial)
        assert str(err.value) == _message(path, "delete it to extract again")


def test_learned_simulator_checkpoint_and_snapshot(tmp_path: Path) -> None:
    path = tmp_path / "mgn.ckpt"
    save_checkpoint(path, "mgn", "cfg", "mesh", {"w": torch.arange(8.0)}, {})
    assert load_checkpoint(path, "mgn", "cfg", "mesh")["trainer"]["w"].tolist() == list(range(8))
    flip_bit(path, path.stat().st_size // 3)
    with pytest.raises(ClodsError) as err:
        load_checkpoint(path, "mgn", "cfg", "mesh")
    assert str(err.value) == _message(path, "delete it to train from scratch (or use another work directory)")
    snap = save_snapshot(tmp_path, 10, "mgn", "cfg", "mesh", {"w": torch.ones(3)})
    assert load_snapshot(snap, "mgn", "cfg", "mesh")["w"].tolist() == [1.0, 1.0, 1.0]
    flip_bit(snap, snap.stat().st_size // 3)
    with pytest.raises(ClodsError) as err:
        load_snapshot(snap, "mgn", "cfg", "mesh")
    assert str(err.value) == _message(snap, "delete the snapshots folder to take them again")


def test_nvs_resume_file(tmp_path: Path) -> None:
    path, key = tmp_path / "nvs_partial.pt", {"k": 1}
    _save_partial(path, {"format": 1, "key": key, "done": [1, 2]})
    assert _load_partial(path, key)["done"] == [1, 2]
    flip_bit(path, path.stat().st_size // 2)
    with pytest.raises(ClodsError) as err:
        _load_partial(path, key)
    assert str(err.value) == _message(path, "delete it to start this seed again")


def test_stage1_fit_cache(tmp_path: Path) -> None:
    cfg = tiny_config(tmp_path, "renderer_config.games.iterations=2", "renderer_config.games.gaussians_per_face=1", task="cdg", renderer="games")
    ctx = TaskContext(config=cfg, seed=0, work_dir=tmp_path, registry=default_registry())
    verts, cells, mesh_pos, _ = grid(3, 2)
    cams = cameras(2, 16)
    images = np.full((1, 2, 16, 16, 3), 128, np.uint8)
    _, stats, key = fit_stage1_keyed(ctx, verts[None], cells, mesh_pos, images, cams)
    assert stats["stage1_cached"] == 0.0
    assert fit_stage1_keyed(ctx, verts[None], cells, mesh_pos, images, cams)[1]["stage1_cached"] == 1.0
    path = tmp_path / "runs" / "clods_cache" / f"stage1-{key}.pt"
    flip_bit(path, path.stat().st_size // 2)
    with pytest.raises(ClodsError) as err:
        fit_stage1_keyed(ctx, verts[None], cells, mesh_pos, images, cams)
    assert str(err.value) == _message(path, "delete it to fit again")
    path.unlink()
    assert fit_stage1_keyed(ctx, verts[None], cells, mesh_pos, images, cams)[1]["stage1_cached"] == 0.0


def test_a_kept_content_digest_is_recomputed_when_it_or_the_manifest_changed(tmp_path: Path) -> None:
    cfg = tiny_config(tmp_path, "data.frames=on_demand")
    store = generate(cfg.data, default_registry().get("scene", cfg.data.scene), progress=False)
    digest = content_digest(store)
    kept = store.root / CONTENT_DIGEST_FILE
    doc = json.loads(kept.read_text())
    assert doc["digest"] == digest and doc["files"] and integrity.JSON_KEY in doc
    kept.write_text(json.dumps({**doc, "digest": "0" * 16}))  # damaged: its own hash fails, so it is computed again
    assert content_digest(DatasetStore.open(store.root)) == digest
    kept.write_text(json.dumps(integrity.seal_json({**doc, "digest": "0" * 16, "files": "elsewhere"})))  # made from other files
    assert content_digest(DatasetStore.open(store.root)) == digest
    legacy = {"version": doc["version"], "frames": doc["frames"], "digest": "1" * 16}
    kept.write_text(json.dumps(legacy))  # written before these checks: read as before
    assert content_digest(DatasetStore.open(store.root)) == "1" * 16
    flip_bit(store.root / "render_setup.npz", 64)  # what renders the frames: checked like the meshes
    with pytest.raises(ClodsError, match="render_setup.npz: content differs from the SHA-256 the dataset's manifest records"):
        content_digest(DatasetStore.open(store.root))


def test_a_datasets_frame_arrays_are_checked_with_its_meshes(tiny_root: Path, tmp_path: Path) -> None:
    """`zarr.json` against the manifest's sha256, the chunks by their byte total (their crc32c when decoded)."""
    source = tiny_config(tiny_root).data.dataset_dir()
    root = tmp_path / source.name
    shutil.copytree(source, root)
    digest = content_digest(DatasetStore.open(source))
    assert content_digest(DatasetStore.open(root)) == digest
    meta = root / "frames_0001.zarr" / "zarr.json"
    meta.write_text(meta.read_text().replace('"shape"', '"shape" ', 1))  # same meaning, other bytes
    with pytest.raises(ClodsError, match=f"{meta}: content differs from the SHA-256 the dataset's manifest records for it"):
        content_digest(DatasetStore.open(root))
    shutil.rmtree(root)
    shutil.copytree(source, root)
    chunk = next((root / "frames_0002.zarr").glob("c.*"))
    chunk.write_bytes(chunk.read_bytes()[:-1])
    with pytest.raises(ClodsError, match=f"{root / 'frames_0002.zarr'}: frame array holds"):
        content_digest(DatasetStore.open(root))
