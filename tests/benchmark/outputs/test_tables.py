"""Tables from records: paper layout, markdown/LaTeX/CSV, values equal to the records."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.outputs.rollout_tables import cdg_caption, stability_caption
from clods_bench.benchmark.outputs.tables import fmt_cell, metric_frame, seeds_phrase, write_tables
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config


def test_tables_from_two_runs(tiny_root: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    recs = {}
    for sim in ("constvel", "frozen"):
        rdir = run_task(tiny_config(tiny_root, f"runs_dir={runs}", sim=sim), default_registry())
        recs[sim] = json.loads((rdir / RECORD_FILE).read_text())
    paths = write_tables(runs, tmp_path / "tables")
    assert sorted(p.suffix for p in paths) == [".csv", ".md", ".tex"]
    md = next(p for p in paths if p.suffix == ".md").read_text()
    assert "Viewed / Interpolation / d(t=8)" in md and "Unviewed / Extrapolation / d(t=11)" in md
    csv = pd.read_csv(next(p for p in paths if p.suffix == ".csv"))
    assert list(csv["method"]) == ["Const. velocity", "Frozen"]  # each plugin's own row label
    for sim, label in (("constvel", "Const. velocity"), ("frozen", "Frozen")):
        row = csv[csv["method"] == label].iloc[0]
        assert row["unviewed/extrap/d_avg/mean"] == pytest.approx(recs[sim]["metrics"]["unviewed/extrap/d_avg"]["mean"])
    tex = next(p for p in paths if p.suffix == ".tex").read_text()
    assert "\\begin{table}" in tex and "Viewed" in tex


def test_tables_from_two_runs_folders(tiny_root: Path, tmp_path: Path) -> None:
    """Records from several runs folders (e.g. two machines) make one table; one run in two folders is an error."""
    one = run_task(tiny_config(tiny_root, f"runs_dir={tmp_path / 'a'}", sim="constvel"), default_registry())
    two = run_task(tiny_config(tiny_root, f"runs_dir={tmp_path / 'b'}", sim="frozen"), default_registry())
    paths = write_tables([tmp_path / "a", tmp_path / "b"], tmp_path / "tables")
    csv = pd.read_csv(next(p for p in paths if p.suffix == ".csv"))
    assert list(csv["method"]) == ["Const. velocity", "Frozen"]
    for rdir, method in ((one, "Const. velocity"), (two, "Frozen")):
        rec = json.loads((rdir / RECORD_FILE).read_text())
        row = csv[csv["method"] == method].iloc[0]
        assert row["viewed/interp/d_avg/mean"] == rec["metrics"]["viewed/interp/d_avg"]["mean"]
    # the constant-velocity run copied into b as well: two records for one row
    copy = tmp_path / "b" / one.relative_to(tmp_path / "a")
    copy.mkdir(parents=True)
    (copy / RECORD_FILE).write_text((one / RECORD_FILE).read_text())
    with pytest.raises(ClodsError, match="recorded in two runs folders") as err:
        write_tables([tmp_path / "a", tmp_path / "b"], tmp_path / "tables")
    assert str(one / RECORD_FILE) in str(err.value) and str(copy / RECORD_FILE) in str(err.value)
    with pytest.raises(ClodsError, match="not found") as err:
        write_tables([tmp_path / "a", tmp_path / "nope"], tmp_path / "tables")
    assert "nope" in str(err.value)


def test_no_records_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    with pytest.raises(ClodsError, match="no 'cdg' run records"):
        write_tables(tmp_path / "runs", tmp_path / "t")
    with pytest.raises(ClodsError, match="not found"):
        write_tables(tmp_path / "nope", tmp_path / "t")


def test_a_row_on_fewer_seeds_is_named_in_the_caption() -> None:
    """Equal seed counts read as before ('2 seeds'); a row with another count is named with it, so a table mixing a
    two-seed mean with one-seed rows says which rows are which."""
    rows = [{"label": "MGN", "seeds": [0, 1]}, {"label": "HCMT", "seeds": [0]}, {"label": "BSMS", "seeds": [0, 1]},
            {"label": "DHMP", "seeds": [0]}, {"label": "Frozen", "seeds": [0, 1]}, {"label": "X", "seeds": [0, 1, 2]}]  # fmt: skip
    assert seeds_phrase(rows[:1] + rows[2:3]) == "2 seeds"
    assert seeds_phrase(rows) == "2 seeds (1: DHMP, HCMT; 3: X)"
    assert seeds_phrase(rows[1:2], "extraction seeds") == "1 extraction seeds"
    assert "over 2 seeds (1: HCMT);" in cdg_caption("flag", "small", rows[:3], [])
    assert "mean ± std over seeds;" in stability_caption("", "ci", rows[:1] + rows[2:3], [])  # the committed ci wording
    assert "over 2 seeds (1: HCMT);" in stability_caption("", "small", rows[:3], [])


def test_fmt_cell() -> None:
    assert fmt_cell(0.12934, 0.0241) == "0.1293 ± 0.0241"
    assert fmt_cell(float("nan"), 0.0, diverged=17) == "diverged@17"


def test_the_metric_layout_gives_one_column_per_metric() -> None:
    """`metric_frame` (the initial-mesh task's layout, and a third-party task's in one line)."""
    recs = [
        {"label": "copy", "seeds": [0, 1], "metrics": {"psnr": {"mean": 20.0, "std": 0.5}}, "timings": {"fit_seconds": {"mean": 2.0, "std": 0.0}, "fit/loss": {"mean": 1.0}}},
        {"label": "simvp", "seeds": [0, 1], "metrics": {"psnr": {"mean": 25.0, "std": None}, "ssim": {"mean": 0.9, "std": 0.01}}, "timings": {}},
    ]
    display, numeric, notes = metric_frame(recs)
    assert list(display.index) == ["copy", "simvp"] and notes == []
    assert display.loc["copy", "psnr"] == "20.0000 ± 0.5000" and display.loc["copy", "ssim"] == "n/a"
    row = numeric.set_index("method").loc["simvp"]
    assert row["psnr/mean"] == 25.0 and np.isnan(row["psnr/std"]) and row["ssim/mean"] == 0.9 and np.isnan(row["time/fit_seconds"])
    assert "time/fit/loss" not in numeric.columns
