"""A finished seed is reused only when it was computed from the same data and under the same numeric pins: a result
of other data or other pins stops the run with one error naming the file, before anything is overwritten."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from rich.console import Console

from clods_bench import integrity, numerics
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.running.executors import LocalExecutor
from clods_bench.benchmark.running.records import seed_result_path
from clods_bench.benchmark.running.runner import run_task
from clods_bench.benchmark.running.seed_jobs import run_configs
from clods_bench.datasets.digest import CONTENT_DIGEST_FILE, content_digest
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config


def _edit(path: Path, seal: bool = True, **changes: object) -> None:
    """Rewrite a result as if it had been written so (sealed with its new content hash, or written before seals)."""
    doc = json.loads(path.read_text())
    for key, value in changes.items():
        if value is None:
            doc.pop(key, None)
        else:
            doc[key] = value
    path.write_text(json.dumps(integrity.seal_json(doc) if seal else {k: v for k, v in doc.items() if k != integrity.JSON_KEY}))


@pytest.fixture()
def finished(tiny_root: Path, tmp_path: Path):
    """(config, result path) of a finished constant-velocity CDG seed."""
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", "seeds=[0]", sim="constvel")
    rdir = run_task(cfg, default_registry(), Console(quiet=True))
    return cfg, seed_result_path(rdir, 0)


def test_a_result_records_its_datas_content_and_is_reused(finished) -> None:
    cfg, path = finished
    doc = json.loads(path.read_text())
    store = DatasetStore.open(cfg.data.dataset_dir())
    cached = store.root / CONTENT_DIGEST_FILE
    kept = cached.read_text()
    cached.unlink()  # the digest recomputed from the dataset's arrays, not read back from its cache
    try:
        assert doc["data_digests"] == [content_digest(store)]
    finally:
        cached.write_text(kept)
    before = path.read_text()
    run_task(cfg, default_registry(), Console(quiet=True))
    assert path.read_text() == before  # reused, not rerun


def test_a_result_from_other_data_is_an_error_naming_it(finished) -> None:
    cfg, path = finished
    _edit(path, data_digests=["0123456789abcdef"])
    before = path.read_text()
    with pytest.raises(ClodsError, match="other data") as err:
        run_task(cfg, default_registry(), Console(quiet=True))
    assert str(path) in str(err.value) and "0123456789abcdef" in str(err.value)
    assert path.read_text() == before  # nothing overwritten
    # reproduce's executor says it before starting any job
    with pytest.raises(ClodsError, match="other data"):
        run_configs([("row", cfg)], LocalExecutor(jobs=1), default_registry(), Console(quiet=True))


def test_a_result_under_other_pins_is_an_error(finished, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg, path = finished
    now = {"mode": "deterministic", "pins_version": numerics.PINS_VERSION}
    monkeypatch.setattr(numerics, "describe", lambda: dict(now))  # deterministic whatever this process runs
    older = numerics.PINS_VERSION - 1
    _edit(path, numerics={"mode": "deterministic", "pins_version": now["pins_version"]})
    run_task(cfg, default_registry(), Console(quiet=True))  # the same pins: reused
    _edit(path, numerics={"mode": "deterministic", "pins_version": older})
    with pytest.raises(ClodsError, match=f"pins version {older}; this release computes with version {now['pins_version']}"):
        run_task(cfg, default_registry(), Console(quiet=True))
    _edit(path, numerics={"mode": "host", "pins_version": None})
    run_task(cfg, default_registry(), Console(quiet=True))  # a host-mode result has no pins to compare


def test_a_result_written_before_provenance_was_recorded_is_reused(finished) -> None:
    cfg, path = finished
    _edit(path, seal=False, data_digests=None, numerics=None, identity=None)
    before = path.read_text()
    run_task(cfg, default_registry(), Console(quiet=True))
    assert path.read_text() == before
