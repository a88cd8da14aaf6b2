"""What the records and artefact tests share: the CLI run in-process with its one-line errors, bit flips."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from clods_bench.cli import main
from tests.conftest import TINY


def tiny_args(root: Path, runs: Path, *extra: str) -> list[str]:
    """`--set` options of the tiny config with data under `root` and records under `runs`."""
    sets = [*TINY, f"data.root={root / 'data'}", f"runs_dir={runs}", *extra]
    return [a for s in sets for a in ("--set", s)]


def cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, list[str]]:
    """(exit status, non-empty stderr lines) of `clods-bench argv`, run in this process."""
    capsys.readouterr()
    code = main(list(argv))
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return code, err


def error_line(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    """The one error line of a `clods-bench argv` that must exit 2."""
    code, err = cli(capsys, *argv)
    errors = [line for line in err if line.startswith("error:")]
    assert code == 2 and len(errors) == 1, (code, err)
    return errors[0]


def flip_bit(path: Path, offset: int, bit: int = 0) -> None:
    """Flip one bit of `path` in place (offset < 0 counts from the end)."""
    data = bytearray(path.read_bytes())
    data[offset] ^= 1 << bit
    path.write_bytes(bytes(data))


def flip_digit_of(path: Path, key_path: list[str]) -> tuple[Any, Any]:
    """Flip the lowest bit of the first significant digit of the number at `key_path` in a JSON file's text (0.1282 ->
    0.1382 style: still a number, one bit changed); return (old value, new value)."""
    text = path.read_text()
    doc = json.loads(text)
    value = doc
    for key in key_path:
        value = value[key]
    old = repr(float(value)) if isinstance(value, float) else str(value)
    start = text.index(f'"{key_path[-1]}": {old}')
    first = start + len(f'"{key_path[-1]}": ') + re.search(r"[1-9]", old).start()
    data = bytearray(text.encode())
    data[first] ^= 1
    path.write_bytes(bytes(data))
    new = json.loads(path.read_text())
    for key in key_path:
        new = new[key]
    assert new != value
    return value, new
