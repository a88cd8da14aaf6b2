"""`digests.json`: comparison by stage, refusal of files that cannot match bit for bit, merging, tables of rows."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from clods_bench.benchmark.reproduction import run_digests
from clods_bench.benchmark.reproduction.compare import ToleranceRule, ToleranceSpec
from clods_bench.errors import ClodsError

NUMERICS = {"mode": "deterministic", "pins_version": 1, "threads": 1}


def _file(metric: float = 0.5, fit: str = "f1", rollout: str = "r1") -> dict:
    rows = {
        "t/MGN": {"table": "t", "label": "MGN", "record": "cdg/MGN/flag-ci-1", "seeds": {
            "0": {"stages": {"data": "d", "fit": fit, "rollout": rollout, "score": f"s{metric}"}, "metrics": {"rmse": metric, "strain": 1.0}}}},
        "u/MGN": {"table": "u", "label": "MGN", "record": "cdg/MGN/flag-ci-1", "same_as": "t/MGN"},
        "u/Frozen": {"table": "u", "label": "Frozen", "record": "cdg/Frozen/flag-ci-2", "seeds": {
            "0": {"stages": {"data": "d", "score": "z"}, "metrics": {"rmse": 0.1}}}},
    }  # fmt: skip
    return run_digests.build("ci", rows, NUMERICS)


def test_equal_files_compare_equal_and_a_moved_fit_is_named_with_the_stages_before_it() -> None:
    assert run_digests.compare(_file(), _file()) == []
    moved = run_digests.compare(_file(), _file(0.51, fit="f2", rollout="r2"))
    assert [row for row, _ in moved] == ["t/MGN"]
    line = moved[0][1]
    assert "t/MGN seed 0: differs from stage 'fit' on (equal: data)" in line and "rmse 0.5 -> 0.51" in line and "strain" not in line
    assert run_digests.tables_of(["t/MGN"], _file()) == ["t", "u"]  # u's MGN row shares the run


def test_a_tolerance_rule_can_let_a_metric_move() -> None:
    spec = ToleranceSpec(rules=[ToleranceRule(table="t.csv", row="MGN", column="rmse/mean", rel=0.05)])
    assert run_digests.compare(_file(), _file(0.51, fit="f2"), spec) == []
    assert len(run_digests.compare(_file(), _file(0.6, fit="f2"), spec)) == 1


def test_files_that_cannot_match_bit_for_bit_are_refused_in_one_line(tmp_path: Path) -> None:
    host = {**_file(), "numerics": {"mode": "host", "pins_version": None, "threads": None}}
    with pytest.raises(ClodsError, match="made in deterministic mode and fresh.json in host mode"):
        run_digests.check_comparable(_file(), host, "committed.json", "fresh.json")
    two = {**_file(), "numerics": {**NUMERICS, "threads": 2}}
    with pytest.raises(ClodsError, match="1 thread\\(s\\) per job"):
        run_digests.check_comparable(_file(), two, "committed.json", "fresh.json")
    newer = {**_file(), "numerics": {**NUMERICS, "pins_version": 2}}
    with pytest.raises(ClodsError, match="made with pins 1 .* with pins 2"):
        run_digests.check_comparable(_file(), newer, "committed.json", "fresh.json")
    path = tmp_path / "digests.json"
    path.write_text(json.dumps({**_file(), "format": 99, "clods_bench": "9.0.0"}))
    with pytest.raises(ClodsError, match=r"digests.json: digests format 99 \(written by clods-bench 9.0.0\); this release reads format 1"):
        run_digests.load(path)
    path.write_text("{not json")
    with pytest.raises(ClodsError, match="unreadable digests file"):
        run_digests.load(path)


def test_writing_with_merge_keeps_the_rows_of_other_tables(tmp_path: Path) -> None:
    path = tmp_path / "digests.json"
    run_digests.write(path, _file())
    only_t = run_digests.build("ci", {"t/MGN": _file(0.7)["rows"]["t/MGN"]}, NUMERICS)
    run_digests.write(path, only_t, merge_into_existing=True)
    merged = run_digests.load(path)
    assert set(merged["rows"]) == {"t/MGN", "u/MGN", "u/Frozen"}
    assert merged["rows"]["t/MGN"]["seeds"]["0"]["metrics"]["rmse"] == 0.7


def test_changed_configs_name_the_rows_whose_record_key_moved() -> None:
    current = {"t/MGN": "cdg/MGN/flag-ci-9", "u/Frozen": "cdg/Frozen/flag-ci-2", "u/New": "cdg/New/flag-ci-3"}
    changed = dict(run_digests.changed_configs(_file(), current))
    assert set(changed) == {"t/MGN", "u/New"} and "flag-ci-1 -> cdg/MGN/flag-ci-9" in changed["t/MGN"]
