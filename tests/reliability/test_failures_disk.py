"""A full disk while the data is written or while a checkpoint is saved: one line naming the file and the stage,
exit 2, and the next run resumes to the digests of a run that never failed. Injected (ENOSPC from the atomic writer,
torch's 'unexpected pos' from a checkpoint save on a full file system), and for real on a small tmpfs where the
tests may mount one."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
from collections import namedtuple
from pathlib import Path
from typing import Iterator

import pytest
import torch

from clods_bench import atomic
from clods_bench.cli import main
from tests.conftest import TINY

ADVICE = "free space or point runs_dir / data.root elsewhere, then rerun: finished work is kept"
MGN = ["sim_config.mgn.train_steps=20", "sim_config.mgn.warmup_steps=2", "sim_config.mgn.checkpoint_every=5", "sim_config.mgn.latent_size=16"]


def _run(data: Path, runs: Path, sim: str, *sets: str) -> int:
    all_sets = (*TINY, f"data.root={data}", f"runs_dir={runs}", *sets)
    return main(["run", "cdg", "--sim", sim, *[a for s in all_sets for a in ("--set", s)]])


def _result(runs: Path) -> dict:
    """The one seed result under `runs` (its stage digests: data, fit, rollout, score)."""
    (path,) = runs.glob("cdg/*/*/seed_0/result.json")
    return json.loads(path.read_text())


def _line(capsys: pytest.CaptureFixture[str]) -> str:
    return capsys.readouterr().err.strip().splitlines()[-1]


def test_disk_full_while_writing_the_data(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """ENOSPC when trajectory 1's file is written: the line names it and the dataset; the rerun keeps trajectory 0
    and ends with the digests of a clean run."""
    replace = os.replace

    def full(src: str, dst: str) -> None:
        if Path(dst).name == "traj_0001.npz":
            raise OSError(errno.ENOSPC, "No space left on device")
        replace(src, dst)

    data, runs = tmp_path / "data", tmp_path / "runs"
    monkeypatch.setattr(atomic.os, "replace", full)
    assert _run(data, runs, "constvel") == 2
    (ddir,) = data.glob("flag-*")
    assert _line(capsys) == f"error: disk full (No space left on device): {ddir / 'traj_0001.npz'} (stage: generating dataset {ddir}); {ADVICE}"
    kept = (ddir / "traj_0000.npz").stat().st_mtime_ns
    monkeypatch.setattr(atomic.os, "replace", replace)
    assert _run(data, runs, "constvel") == 0
    assert (ddir / "traj_0000.npz").stat().st_mtime_ns == kept  # resumed: the finished trajectory is not written again
    assert _run(tmp_path / "clean-data", tmp_path / "clean-runs", "constvel") == 0
    assert _result(runs)["extra"]["stage_digests"] == _result(tmp_path / "clean-runs")["extra"]["stage_digests"]


def test_disk_full_while_saving_a_checkpoint(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """torch.save on a full file system fails with 'unexpected pos' (a RuntimeError): named as the full disk it is,
    with the checkpoint's path and the fit; the rerun resumes from the checkpoint before and ends where a clean run does."""
    save, saves = torch.save, []

    def full_at_second_save(obj: object, f: object, *args: object, **kwargs: object) -> None:
        saves.append(f)
        if len(saves) == 2:
            Path(f).write_bytes(b"PK\x03\x04 partial")  # type: ignore[arg-type]
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 638976 vs 638864")
        save(obj, f, *args, **kwargs)

    Usage = namedtuple("Usage", "total used free")
    data, runs = tmp_path / "data", tmp_path / "runs"
    monkeypatch.setattr(torch, "save", full_at_second_save)
    monkeypatch.setattr(atomic.shutil, "disk_usage", lambda path: Usage(1 << 30, 1 << 30, 0))
    assert _run(data, runs, "mgn", *MGN) == 2
    (ckpt,) = runs.glob("fit_cache/mgn-*/mgn.ckpt")  # the first save, kept whole
    assert _line(capsys) == f"error: disk full (No space left on device): {ckpt} (stage: fit of simulator 'mgn', seed 0); {ADVICE}"
    assert not list(ckpt.parent.glob(".mgn.ckpt.*"))  # no temp file left behind
    monkeypatch.undo()
    assert _run(data, runs, "mgn", *MGN) == 0
    resumed = _result(runs)
    assert resumed["timings"]["fit/resumed_from_step"] == 5.0
    assert _run(data, tmp_path / "clean-runs", "mgn", *MGN) == 0
    clean = _result(tmp_path / "clean-runs")
    assert clean["timings"]["fit/resumed_from_step"] == 0.0
    assert resumed["extra"]["stage_digests"] == clean["extra"]["stage_digests"]


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[callable]:
    """`mount(path, kib)`: a tmpfs of that size at `path` (unmounted after the test); skips where mounting is not allowed."""
    mounted: list[Path] = []

    def mount(path: Path, kib: int) -> None:
        path.mkdir(parents=True, exist_ok=True)
        options = f"size={kib}k" if path not in mounted else f"remount,size={kib}k"
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True, text=True)
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
        mounted.append(path)

    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    try:
        yield mount
    finally:
        for path in dict.fromkeys(reversed(mounted)):
            subprocess.run(["umount", str(path)], capture_output=True)


def test_a_real_full_disk_on_tmpfs(tmp_path: Path, tmpfs: callable, capsys) -> None:
    """The same two failures on a file system that is really full: the data on a tmpfs a few KiB smaller than the
    dataset, the runs on one that holds one checkpoint but not a second beside it; each grown, the rerun resumes."""
    clean_data, clean_runs = tmp_path / "clean-data", tmp_path / "clean-runs"
    assert _run(clean_data, clean_runs, "mgn", *MGN) == 0
    (dataset,) = clean_data.glob("flag-*")
    data_kib = sum(-(-p.stat().st_size // 4096) * 4 for p in dataset.rglob("*") if p.is_file())
    (ckpt,) = clean_runs.glob("fit_cache/mgn-*/mgn.ckpt")
    ckpt_kib = -(-ckpt.stat().st_size // 1024)

    data, runs = tmp_path / "data", tmp_path / "runs"
    tmpfs(data, data_kib - 8)
    assert _run(data, runs, "mgn", *MGN) == 2
    line = _line(capsys)
    assert line.startswith("error: disk full (No space left on device): ") and line.endswith(f" (stage: generating dataset {data / dataset.name}); {ADVICE}")
    tmpfs(data, 64 << 10)
    tmpfs(runs, ckpt_kib * 3 // 2 + 64)
    assert _run(data, runs, "mgn", *MGN) == 2
    (ckpt,) = runs.glob("fit_cache/mgn-*/mgn.ckpt")
    assert _line(capsys) == f"error: disk full (No space left on device): {ckpt} (stage: fit of simulator 'mgn', seed 0); {ADVICE}"
    tmpfs(runs, 64 << 10)
    assert _run(data, runs, "mgn", *MGN) == 0
    resumed = _result(runs)
    assert resumed["timings"]["fit/resumed_from_step"] > 0
    assert resumed["extra"]["stage_digests"] == _result(clean_runs)["extra"]["stage_digests"]
