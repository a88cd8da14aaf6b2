"""The regression check: every moved number beyond tolerance is listed, timings are ignored; seed spread is measured right."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from clods_bench.benchmark.reproduction.compare import TOLERANCE_FILE, Tolerance, compare_dirs, load_tolerance, seed_spread
from clods_bench.cli import main
from clods_bench.errors import ClodsError

TOL = """\
default: {rel: 0.01, abs: 1.0e-6}
rules:
  - {column: "*/std", rel: 0.5, abs: 1.0e-6}
  - {table: t.csv, row: B, column: "*/mean", rel: 0.3}
exclude: ["*_ms_per_*", "*seconds*"]
justification: test
"""


def _tables(root: Path) -> Path:
    root.mkdir()
    pd.DataFrame(
        {
            "method": ["A", "B"],
            "seeds": [2, 2],
            "viewed/interp/d_avg/mean": [0.10, 0.20],
            "viewed/interp/d_avg/std": [0.01, float("nan")],
            "infer_ms_per_step": [1.0, 2.0],
            "fit_seconds": [3.0, 4.0],
        }
    ).to_csv(root / "t.csv", index=False)
    (root / "tolerance.yaml").write_text(TOL)
    return root


def test_tolerance_rule() -> None:
    tol = Tolerance(rel=0.1, abs=0.01)
    assert tol.allows(1.0, 1.109) and not tol.allows(1.0, 1.111)  # 0.01 + 0.1 * 1.0 = 0.11
    assert tol.allows(float("nan"), float("nan")) and not tol.allows(1.0, float("nan")) and not tol.allows(float("nan"), 1.0)


def test_identical_and_within_tolerance_pass_and_timings_are_ignored(tmp_path: Path) -> None:
    committed = _tables(tmp_path / "c")
    fresh = _tables(tmp_path / "f")
    assert compare_dirs(committed, fresh) == []
    frame = pd.read_csv(fresh / "t.csv")
    frame.loc[0, "viewed/interp/d_avg/mean"] = 0.1009  # 0.9 % < 1 %
    frame.loc[0, "viewed/interp/d_avg/std"] = 0.014  # std column: 50 %
    frame.loc[1, "viewed/interp/d_avg/mean"] = 0.259  # row B's rule: 30 % of 0.2 + 1e-6
    frame["infer_ms_per_step"] *= 100
    frame["fit_seconds"] *= 100
    frame.to_csv(fresh / "t.csv", index=False)
    assert compare_dirs(committed, fresh) == []
    frame.loc[1, "viewed/interp/d_avg/mean"] = 0.261
    frame.to_csv(fresh / "t.csv", index=False)
    assert compare_dirs(committed, fresh) == ["t.csv: B: viewed/interp/d_avg/mean: 0.2 -> 0.261 (moved 0.061, allowed 0.06)"]


def test_every_moved_cell_and_missing_row_or_table_is_listed(tmp_path: Path) -> None:
    committed = _tables(tmp_path / "c")
    fresh = _tables(tmp_path / "f")
    pd.DataFrame({"method": ["X"], "seeds": [2]}).to_csv(committed / "u.csv", index=False)
    frame = pd.read_csv(fresh / "t.csv")
    frame.loc[0, "viewed/interp/d_avg/mean"] = 0.1011  # 1.1 % > 1 %
    frame.loc[1, "viewed/interp/d_avg/mean"] = float("nan")  # diverged now
    frame.loc[1, "viewed/interp/d_avg/std"] = 0.5  # NaN before
    frame.loc[1, "method"] = "C"
    frame.to_csv(fresh / "t.csv", index=False)
    problems = compare_dirs(committed, fresh)
    text = "\n".join(problems)
    assert "t.csv: A: viewed/interp/d_avg/mean: 0.1 -> 0.1011" in text
    assert "row 'B' missing" in text and "row 'C' is new" in text
    assert "u.csv: not produced" in text
    assert len(problems) == 4
    assert main(["compare", str(committed), str(fresh)]) == 1
    assert main(["compare", str(committed), str(committed)]) == 0


def test_tolerance_file_is_checked(tmp_path: Path) -> None:
    bad = tmp_path / "tol.yaml"
    bad.write_text("default: {rel: 0.01, absolute: 1.0}\n")
    with pytest.raises(ClodsError, match=r"unknown config key 'default.absolute' \(did you mean 'default.abs'"):
        load_tolerance(bad)
    bad.write_text("default: {rel: -0.01}\n")
    with pytest.raises(ClodsError, match="must be >= 0"):
        load_tolerance(bad)


def test_seed_spread_matches_a_hand_computation(tmp_path: Path) -> None:
    rdir = tmp_path / "runs" / "cdg" / "m" / "x"
    rdir.mkdir(parents=True)
    values = [0.10, 0.14, 0.12]
    rec = {
        "task": "cdg",
        "label": "m",
        "preset": "ci",
        "scene": "flag",
        "metrics": {"viewed/interp/d_avg": {"mean": 0.12, "std": 0.02}, "constant": {"mean": 1.0, "std": 0.0}},
        "per_seed": {str(i): {"metrics": {"viewed/interp/d_avg": v, "constant": 1.0}} for i, v in enumerate(values)},
    }
    (rdir / "record.json").write_text(json.dumps(rec))
    frame = seed_spread(tmp_path / "runs").set_index("metric")
    row = frame.loc["viewed/interp/d_avg"]
    assert row["std"] == pytest.approx(np.std(values, ddof=1)) and row["rel_std"] == pytest.approx(0.02 / 0.12)
    assert row["max_rel_dev"] == pytest.approx(0.02 / 0.12)
    assert frame.loc["constant", "rel_std"] == 0.0
    assert main(["seed-spread", "--runs", str(tmp_path / "runs"), "--csv", str(tmp_path / "s.csv")]) == 0
    assert len(pd.read_csv(tmp_path / "s.csv")) == 2


def test_committed_tolerance_file_is_exact_but_for_timings() -> None:
    """results/ci is made in deterministic mode: every cell but the timings must be equal, learned rows included."""
    spec = load_tolerance(Path(__file__).resolve().parents[3] / "results" / "ci" / TOLERANCE_FILE)
    assert "deterministic mode" in spec.justification and spec.rules == []
    assert spec.for_cell("table2_cdg.csv", "Frozen", "infer_ms_per_step") is None
    assert spec.for_cell("table3_nvs.csv", "SMGS", "fit_seconds") is None
    assert spec.for_cell("error_vs_time.csv", "MGN", "time/seed_seconds") is None
    for table, row, column in [("table2_cdg.csv", "BSMS", "viewed/interp/d_avg/mean"), ("stability.csv", "MGN", "first_divergence"),
                               ("table4_dvc.csv", "TAU", "Quality/LPIPS/mean"), ("initial_mesh.csv", "CloDS", "rmse/mean")]:  # fmt: skip
        tol = spec.for_cell(table, row, column)
        assert tol is not None and tol.rel == 0.0 and tol.abs == 0.0, (table, row, column)


def test_a_skip_rule_leaves_its_cells_out(tmp_path: Path) -> None:
    committed = _tables(tmp_path / "c")
    fresh = _tables(tmp_path / "f")
    tol = TOL.replace("rules:\n", 'rules:\n  - {table: t.csv, row: A, column: "viewed/*", skip: true, why: test}\n')
    (committed / "tolerance.yaml").write_text(tol)
    frame = pd.read_csv(fresh / "t.csv")
    frame.loc[0, "viewed/interp/d_avg/mean"] = 9.0  # row A: skipped
    frame.loc[1, "viewed/interp/d_avg/std"] = 1.0  # row B: NaN -> 1.0 is still caught
    frame.to_csv(fresh / "t.csv", index=False)
    assert compare_dirs(committed, fresh) == ["t.csv: B: viewed/interp/d_avg/std: nan -> 1 (moved nan, allowed 0)"]


def test_skip_columns_leave_std_and_seed_count_out(tmp_path: Path) -> None:
    committed = _tables(tmp_path / "c")
    fresh = _tables(tmp_path / "f")
    frame = pd.read_csv(fresh / "t.csv")
    frame["seeds"] = 1
    frame.loc[0, "viewed/interp/d_avg/std"] = float("nan")  # one seed: no std
    frame.to_csv(fresh / "t.csv", index=False)
    assert len(compare_dirs(committed, fresh)) == 3  # two seed counts and the std
    assert compare_dirs(committed, fresh, skip_columns=("*/std", "seeds")) == []
    frame.loc[0, "viewed/interp/d_avg/mean"] = 0.2
    frame.to_csv(fresh / "t.csv", index=False)
    assert compare_dirs(committed, fresh, skip_columns=("*/std", "seeds")) == ["t.csv: A: viewed/interp/d_avg/mean: 0.1 -> 0.2 (moved 0.1, allowed 0.001)"]


def test_failure_kind_drops_the_measured_values() -> None:
    from clods_bench.benchmark.outputs.rollout_tables import failure_kind

    assert failure_kind("edge strain 0.523 > 0.5") == "edge strain"
    assert failure_kind("kinetic energy 1.2e+03 J > 10 J") == "kinetic energy"
    assert failure_kind("non-finite positions (NaN/Inf)") == "non-finite positions (NaN/Inf)"
    assert failure_kind("exception: FloatingPointError: overflow in step 3") == "exception: FloatingPointError"
