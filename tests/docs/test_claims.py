"""The claims page's rules decide on known tables as worked out by hand, and a stale claim fails naming its line."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from clods_bench.benchmark.outputs.claim_rules import Columns, MissingRows, evaluate
from clods_bench.docsgen.claims import FAILS, HOLDS, NOISE, NOT_RUN, evaluate_claims
from clods_bench.docsgen.claims_page import counts, summary_table
from clods_bench.benchmark.outputs.table_sources import CsvTable
from clods_bench.errors import ClodsError
from tests.docs.pages import ROOT

COLS = {"err": Columns("err", "error", ("a/mean", "b/mean"), False), "psnr": Columns("psnr", "PSNR", ("p/mean",), True)}


def _table(tmp_path: Path, rows: str) -> CsvTable:
    path = tmp_path / "t.csv"
    path.write_text("method,seeds,a/mean,b/mean,p/mean\n" + rows)
    return CsvTable([path])


@pytest.fixture
def table(tmp_path: Path) -> CsvTable:
    return _table(tmp_path, "A,2,1.0,2.0,30\nB,2,1.5,2.5,29\nC,2,1.2,1.9,31\nN,1,nan,1.0,\n")


def test_better_compares_every_column_in_the_right_direction(table: CsvTable) -> None:
    v = evaluate({"better": {"row": "A", "than": ["B"], "columns": "err"}}, table, COLS.__getitem__)
    assert (v.holds, v.passed, v.total) == (True, 2, 2)
    v = evaluate({"better": {"row": "A", "than": ["B", "C"], "columns": "err"}}, table, COLS.__getitem__)
    assert (v.holds, v.passed, v.total) == (False, 3, 4)  # C's b (1.9) is below A's (2.0)
    assert evaluate({"better": {"row": "C", "than": ["A", "B"], "columns": "psnr"}}, table, COLS.__getitem__).holds  # higher PSNR
    v = evaluate({"better": {"row": "A", "than": ["B"], "columns": "err", "by": 1.2}}, table, COLS.__getitem__)
    assert (v.holds, v.passed) == (True, 2)  # 1.2 * 1.0 < 1.5 and 1.2 * 2.0 < 2.5
    v = evaluate({"better": {"row": "A", "than": ["B"], "columns": "err", "by": 1.3}}, table, COLS.__getitem__)
    assert (v.holds, v.passed) == (False, 1)  # 1.3 * 2.0 = 2.6 > 2.5


def test_within_and_order(table: CsvTable) -> None:
    v = evaluate({"within": {"rows": ["B"], "of": "A", "columns": "err", "factor": 1.5}}, table, COLS.__getitem__)
    assert (v.holds, v.passed) == (True, 2)  # 1.5 <= 1.5 * 1.0 (the bound is inclusive) and 2.5 <= 1.5 * 2.0
    v = evaluate({"within": {"rows": ["B"], "of": "A", "columns": "err", "factor": 1.4}}, table, COLS.__getitem__)
    assert (v.holds, v.passed) == (False, 1)  # 1.5 > 1.4 * 1.0; 2.5 <= 1.4 * 2.0
    assert evaluate({"order": {"rows": ["C", "A", "B"], "columns": "psnr"}}, table, COLS.__getitem__).holds
    v = evaluate({"order": {"rows": ["A", "C", "B"], "columns": "err"}}, table, COLS.__getitem__)
    assert (v.holds, v.passed, v.total) == (False, 3, 4)  # A < C < B on a, but C's b (1.9) < A's (2.0)


def test_a_diverged_value_never_holds_and_all_needs_every_part(table: CsvTable) -> None:
    v = evaluate({"better": {"row": "N", "than": ["A"], "columns": "err"}}, table, COLS.__getitem__)
    assert (v.holds, v.passed, v.total) == (False, 1, 2)  # NaN against 1.0 on a does not hold; 1.0 < 2.0 on b does
    rule = {"all": [{"better": {"row": "A", "than": ["B"], "columns": "err"}}, {"order": {"rows": ["A", "B"], "columns": "psnr"}}]}
    v = evaluate(rule, table, COLS.__getitem__)
    assert (v.holds, v.passed, v.total) == (True, 3, 3)
    with pytest.raises(MissingRows) as exc:
        evaluate({"better": {"row": "A", "than": ["Z", "Y"], "columns": "err"}}, table, COLS.__getitem__)
    assert exc.value.missing == ["Z", "Y"]


def test_the_committed_claims_evaluate_at_every_size() -> None:
    claims = evaluate_claims(ROOT)
    assert len({c.id for c in claims}) == len(claims) >= 20
    for c in claims:
        assert c.outcomes, c.id
        for o in c.outcomes:
            assert o.status in (HOLDS, FAILS, NOISE, NOT_RUN), (c.id, o)
            if o.size == "`ci`":
                assert o.status != NOT_RUN, f"{c.id}: every claim on a plan table must be decided at ci"
                assert o.seeds is not None and o.seeds >= 1


def _claims_root(tmp_path: Path, claims: str, ci_csv: str | None) -> Path:
    (tmp_path / "docs").mkdir(parents=True)
    (tmp_path / "results/ci").mkdir(parents=True)
    (tmp_path / "results/small-partial").mkdir(parents=True)
    if ci_csv is not None:
        (tmp_path / "results/ci/t.csv").write_text(ci_csv)
    (tmp_path / "results/small-partial/t_small.csv").write_text("method,seeds,a/mean\nA,1,1.0\n")
    (tmp_path / "docs/claims.yaml").write_text(
        "sizes:\n"
        "  ci: {label: ci, kind: fixture, folder: results/ci, file: '{table}.csv', partial: false}\n"
        "  small: {label: small, kind: evidence, folder: results/small-partial, file: '{table}_small.csv', partial: true}\n"
        "columns:\n  err: {label: error, better: lower, columns: [a/mean]}\n"
        "claims:\n" + claims
    )  # fmt: skip
    return tmp_path


CLAIM = "  - id: c1\n    title: C one\n    claim: A beats B.\n    where: Table 9\n    paper: 1 against 2.\n    table: t\n    rule: {better: {row: A, than: [B], columns: err}}\n"


def test_a_claim_whose_table_or_row_is_gone_fails_naming_its_line(tmp_path: Path) -> None:
    root = _claims_root(tmp_path / "a", CLAIM, ci_csv="method,seeds,a/mean\nA,2,1.0\nB,2,2.0\n")
    (c,) = evaluate_claims(root)
    assert [(o.size, o.status) for o in c.outcomes] == [("ci", HOLDS), ("small", NOT_RUN)]  # small lacks B: not run
    assert "B" in c.outcomes[1].ours
    root = _claims_root(tmp_path / "b", CLAIM, ci_csv=None)
    with pytest.raises(ClodsError, match=r"claims\.yaml:7: claim 'c1': table file results/ci/t\.csv is missing"):
        evaluate_claims(root)
    root = _claims_root(tmp_path / "c", CLAIM, ci_csv="method,seeds,a/mean\nA,2,1.0\n")
    with pytest.raises(ClodsError, match=r"claims\.yaml:7: claim 'c1': results/ci/t\.csv has no B"):
        evaluate_claims(root)
    root = _claims_root(tmp_path / "d", CLAIM.replace("columns: err", "columns: nope"), ci_csv="method,seeds,a/mean\nA,2,1.0\nB,2,2.0\n")
    with pytest.raises(ClodsError, match=r"claims\.yaml:7: unknown column group 'nope'"):
        evaluate_claims(root)


def test_nan_in_a_committed_csv_reads_as_not_holding(tmp_path: Path) -> None:
    root = _claims_root(tmp_path, CLAIM, ci_csv="method,seeds,a/mean\nA,2,nan\nB,2,2.0\n")
    (c,) = evaluate_claims(root)
    assert c.outcomes[0].status == FAILS and "n/a" in c.outcomes[0].ours
    assert math.isnan(CsvTable([root / "results/ci/t.csv"]).value("A", "a/mean"))


NOISY = ("sizes:\n"
         "  ci: {label: ci, kind: regression fixture, folder: results/ci, file: '{table}.csv', partial: false}\n"
         "  small: {label: small, kind: evidence, folder: results/small-partial, file: '{table}_small.csv', partial: true,\n"
         "          noise: {value: 0.1, columns: [err], what: paired fits}}\n"
         "columns:\n  err: {label: error, better: lower, columns: [a/mean]}\n  psnr: {label: PSNR, better: higher, columns: [p/mean]}\n"
         "claims:\n")  # fmt: skip


def _noisy_root(tmp_path: Path, small_csv: str, claims: str = CLAIM) -> Path:
    (tmp_path / "docs").mkdir(parents=True)
    (tmp_path / "results/ci").mkdir(parents=True)
    (tmp_path / "results/small-partial").mkdir(parents=True)
    (tmp_path / "results/ci/t.csv").write_text("method,seeds,a/mean,p/mean\nA,2,1.0,30\nB,2,2.0,29\n")
    (tmp_path / "results/small-partial/t_small.csv").write_text(small_csv)
    (tmp_path / "docs/claims.yaml").write_text(NOISY + claims)
    return tmp_path


@pytest.mark.parametrize("a,b,status", [
    (1.0, 1.5, HOLDS),    # holds by 0.5, outside the 0.1 band
    (1.0, 1.05, NOISE),   # holds by 0.05: inside the band
    (1.05, 1.0, NOISE),   # fails by 0.05: inside the band
    (1.3, 1.0, FAILS),    # fails by 0.3
])  # fmt: skip
def test_a_one_seed_margin_inside_the_noise_band_reads_within_noise(tmp_path: Path, a: float, b: float, status: str) -> None:
    (c,) = evaluate_claims(_noisy_root(tmp_path, f"method,seeds,a/mean,p/mean\nA,1,{a},30\nB,1,{b},29\n"))
    small = next(o for o in c.outcomes if o.size == "small")
    assert small.status == status and "paired fits" in small.noise


def test_the_band_applies_to_one_seed_and_its_own_columns_only(tmp_path: Path) -> None:
    (c,) = evaluate_claims(_noisy_root(tmp_path / "two", "method,seeds,a/mean,p/mean\nA,2,1.05,30\nB,2,1.0,29\n"))
    assert next(o for o in c.outcomes if o.size == "small").status == FAILS  # two seeds: the one-seed band is not theirs
    psnr = CLAIM.replace("columns: err", "columns: psnr")
    (c,) = evaluate_claims(_noisy_root(tmp_path / "psnr", "method,seeds,a/mean,p/mean\nA,1,1.0,29.95\nB,1,1.0,30\n", psnr))
    small = next(o for o in c.outcomes if o.size == "small")
    assert small.status == FAILS and small.noise == ""  # PSNR has no band: 0.05 dB short fails, and no band is named


def test_evidence_comes_first_and_a_claim_the_paper_scores_otherwise_is_not_counted(tmp_path: Path) -> None:
    extra = CLAIM.replace("id: c1", "id: c2").replace("title: C one", "title: C two").replace("    rule:", "    counts: false\n    rule:")
    claims = evaluate_claims(_noisy_root(tmp_path, "method,seeds,a/mean,p/mean\nA,1,1.0,30\nB,1,1.5,29\n", CLAIM + extra))
    assert [o.size for o in claims[0].outcomes] == ["small", "ci"]  # the fixture after the evidence
    assert list(counts(claims)) == ["small", "ci"]
    assert counts(claims)["small"] == {HOLDS: 1, NOISE: 0, FAILS: 0, NOT_RUN: 0}  # c2 holds too but is not counted
    header = summary_table(claims, None)[0]
    assert header.index("small") < header.index("other measurements") < header.index("ci (regression fixture, not evidence)")
    assert "(not counted)" in summary_table(claims, None)[3]
