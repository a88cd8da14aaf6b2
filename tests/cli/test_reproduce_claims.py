"""`reproduce --dry-run` checks the claims file against the plan: a table, row or column group that does not exist is
one line naming the claim's line, before any job starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from clods_bench.cli import main

ROOT = Path(__file__).resolve().parents[2]
COLUMNS = "columns:\n  err: {label: error, better: lower, columns: [viewed/interp/avg/mean]}\n"


def claims_file(tmp_path: Path, rule: str, table: str = "table2_cdg") -> Path:
    path = tmp_path / "claims.yaml"
    path.write_text("sizes: {}\n" + COLUMNS + "claims:\n  - id: c1\n    title: T\n    claim: C.\n    where: W\n    paper: P.\n"
                    f"    table: {table}\n    rule: {rule}\n")  # fmt: skip
    return path


@pytest.mark.parametrize("rule,table,needle", [
    ("{better: {row: MGN, than: [Frozen], columns: err}}", "table9", "table 'table9' is not a table of the plan"),
    ("{better: {row: MGN, than: [BSMS], columns: err}}", "table2_cdg", "the plan makes no row 'BSMS' in table 'table2_cdg'"),
    ("{better: {row: MGN, than: [Frozen], columns: psnr}}", "table2_cdg", "unknown column group psnr"),
])  # fmt: skip
def test_a_claim_naming_what_the_plan_lacks_stops_the_dry_run(tmp_path, capsys, rule, table, needle) -> None:
    path = claims_file(tmp_path, rule, table)
    assert main(["reproduce", "--dry-run", "--claims", str(path), "--set", f"runs_dir={tmp_path}"]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert needle in err and f"{path}:5" in err  # the claim's line


def test_the_committed_claims_pass_the_dry_run(tmp_path, capsys) -> None:
    assert main(["reproduce", "--dry-run", "--claims", str(ROOT / "docs/claims.yaml"), "--set", f"runs_dir={tmp_path}"]) == 0
    assert "every claim's table, rows and columns are in the plan" in " ".join(capsys.readouterr().out.split())
