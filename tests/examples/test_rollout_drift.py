"""examples/studies/rollout_drift.py: it finds every stability record of a seed, names rows by label or by NAME=, and
writes each curve's values at the listed frames (empty past a rollout's end)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from tests.examples.example_module import load_example

rd = load_example("examples/studies/rollout_drift.py")


def _record(root: Path, label: str, frames: int, seed: int = 0) -> None:
    run = root / "stability" / label.replace(" ", "_") / "flag-small-0"
    (run / f"seed_{seed}").mkdir(parents=True)
    (run / "record.json").write_text(json.dumps({"label": label}))
    curves = {"rmse": list(np.arange(frames) * 0.01), "max_strain": [0.5] * frames, "energy_ratio": [1.0] * frames}
    (run / f"seed_{seed}" / "result.json").write_text(json.dumps({"curves": curves}))


def test_rows_by_label_and_by_name_and_values_at_the_frames(tmp_path: Path) -> None:
    _record(tmp_path / "a", "MGN", 201)
    _record(tmp_path / "a", "Frozen", 41)
    _record(tmp_path / "b", "BSMS", 201)
    _record(tmp_path / "c", "BSMS", 201, seed=1)  # another seed: not read
    rows = {**rd.read_rows(str(tmp_path / "a"), 0), **rd.read_rows(f"BSMS, gamma 1={tmp_path / 'b'}", 0)}
    assert sorted(rows) == ["BSMS, gamma 1", "Frozen", "MGN"]
    rd.write_csv(rows, tmp_path / "drift.csv")
    lines = {(r["row"], r["curve"]): r for r in csv.DictReader(open(tmp_path / "drift.csv"))}
    assert float(lines[("MGN", "rmse")]["frame_120"]) == pytest.approx(1.2)
    assert lines[("Frozen", "rmse")]["frame_40"] == "0.4" and lines[("Frozen", "rmse")]["frame_80"] == ""
    with pytest.raises(SystemExit, match="no stability record with seed 0"):
        rd.read_rows(str(tmp_path / "c"), 0)
    with pytest.raises(SystemExit, match="must hold one stability record"):  # one name for two rows: refused
        rd.read_rows(f"both={tmp_path / 'a'}", 0)
