"""Atomic writes: complete files only, with the mode a plain open() would give them."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from clods_bench import atomic


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.skipif(os.name != "posix", reason="Windows files have no POSIX permission bits (os.chmod sets only the read-only flag)")
def test_new_file_gets_the_mode_of_a_plain_open(tmp_path):
    reference = tmp_path / "plain.txt"
    with open(reference, "w") as fh:  # the independent reference: what the OS gives a new file under this umask
        fh.write("x")
    target = tmp_path / "table.md"
    atomic.write_text(target, "| a |\n")
    assert _mode(target) == _mode(reference)


@pytest.mark.skipif(os.name != "posix", reason="Windows files have no POSIX permission bits (os.chmod sets only the read-only flag)")
def test_rewrite_keeps_an_existing_files_mode(tmp_path):
    target = tmp_path / "result.json"
    atomic.write_json(target, {"a": 1})
    os.chmod(target, 0o640)
    atomic.write_json(target, {"a": 2})
    assert _mode(target) == 0o640
    assert target.read_text().strip().endswith("}") and '"a": 2' in target.read_text()


def test_failed_write_leaves_the_old_file_and_no_temp(tmp_path):
    target = tmp_path / "arrays.npz"
    atomic.write_npz(target, x=np.arange(3))
    with pytest.raises(RuntimeError):
        with atomic.atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("killed")
    assert np.array_equal(np.load(target)["x"], np.arange(3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arrays.npz"]
