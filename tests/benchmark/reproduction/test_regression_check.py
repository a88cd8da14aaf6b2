"""`reproduce --check` on exact numbers: a planted 5 % change in a learned row's training fails the check naming the
row and the stage (the tolerance of release 0.1 let it pass); `--only` regenerates tables in place; a dry run names
the tables a config change invalidates."""

from __future__ import annotations

import json
import shutil
import textwrap
from pathlib import Path

import pytest

from clods_bench.benchmark.reproduction.compare import compare_dirs
from clods_bench.cli import main
from tests.conftest import TINY

PLAN = textwrap.dedent(
    """\
    version: 1
    description: a learned row and a baseline, in tables named like the committed ones
    tables:
      - {id: table2_cdg, task: cdg, title: "CDG"}
      - {id: stability, task: stability, title: "stability"}
    runs:
      - {table: table2_cdg, task: cdg, label: Const. velocity, sim: constvel}
      - {table: table2_cdg, task: cdg, label: MGN, sim: mgn}
      - {table: stability, task: stability, label: Frozen, sim: frozen}
    """
)
MGN = ["sim_config.mgn.train_steps=15", "sim_config.mgn.latent_size=16", "sim_config.mgn.message_passing_steps=2", "sim_config.mgn.warmup_steps=2"]
OLD_TOLERANCE = Path(__file__).parent / "data" / "tolerance_0.1.yaml"
"""`results/ci/tolerance.yaml` as release 0.1 shipped it (Table 2's learned rows: rel 1.0)."""
EXACT = "default: {rel: 0.0, abs: 0.0}\nexclude: ['*_ms_per_*', '*seconds*', 'time/*']\n"


def _args(plan: Path, root: Path, runs: Path, *extra: str) -> list[str]:
    sets = [*TINY, f"data.root={root / 'data'}", f"runs_dir={runs}", "seeds=[0, 1]", *MGN, *extra]
    return ["reproduce", "--plan", str(plan), "--no-progress", *[a for o in sets for a in ("--set", o)]]


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory, tiny_root: Path) -> tuple[Path, Path]:
    """The plan's 2-seed reproduction, made once for the module (its records stay in `runs`)."""
    root = tmp_path_factory.mktemp("committed")
    plan = root / "plan.yaml"
    plan.write_text(PLAN)
    out = root / "committed"
    assert main([*_args(plan, tiny_root, root / "runs"), "--out", str(out)]) == 0
    (out / "tolerance.yaml").write_text(EXACT)
    return plan, out


@pytest.fixture()
def committed(pristine: tuple[Path, Path], tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the pristine reproduction for one test to check against or rewrite."""
    plan, out = pristine
    shutil.copytree(out, tmp_path / "committed")
    return plan, tmp_path / "committed"


def test_a_planted_learning_rate_change_fails_naming_the_row_and_passed_the_old_tolerance(
    committed: tuple[Path, Path], tmp_path: Path, tiny_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan, out = committed
    assert (out / "first_seed" / "table2_cdg.csv").is_file() and json.loads((out / "digests.json").read_text())["rows"]["table2_cdg/MGN"]["seeds"].keys() == {"0", "1"}
    same = tmp_path / "same"
    assert main([*_args(plan, tiny_root, tmp_path / "runs_same"), "--first-seeds", "1", "--out", str(same), "--check", str(out)]) == 0
    capsys.readouterr()
    planted = tmp_path / "planted"  # MGN's learning rate 1e-3 -> 1.05e-3, a fresh runs folder
    args = _args(plan, tiny_root, tmp_path / "runs_planted", "sim_config.mgn.learning_rate=0.00105")
    assert main([*args, "--first-seeds", "1", "--out", str(planted), "--check", str(out)]) == 1
    err = capsys.readouterr().err
    assert "table2_cdg/MGN seed 0: differs from stage 'fit' on (equal: data)" in err
    assert "Const. velocity" not in err and "Frozen" not in err
    assert "tables to regenerate: table2_cdg;" in err and "--only table2_cdg --out" in err
    assert compare_dirs(out / "first_seed", planted, OLD_TOLERANCE) == []  # release 0.1's check let it through


def test_only_regenerates_its_tables_in_place_and_keeps_the_others(committed: tuple[Path, Path], tmp_path: Path, tiny_root: Path) -> None:
    plan, out = committed
    before = json.loads((out / "digests.json").read_text())
    stability = (out / "stability.csv").read_text()
    args = _args(plan, tiny_root, tmp_path / "runs_only", "sim_config.mgn.learning_rate=0.00105")
    assert main([*args, "--only", "table2_cdg", "--out", str(out)]) == 0
    after = json.loads((out / "digests.json").read_text())
    assert after["rows"]["stability/Frozen"] == before["rows"]["stability/Frozen"]
    assert after["rows"]["table2_cdg/MGN"] != before["rows"]["table2_cdg/MGN"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(manifest["tables"]) == {"table2_cdg", "stability"} and "stability.csv" in manifest["files"]
    assert (out / "stability.csv").read_text() == stability


def test_a_dry_run_names_the_tables_a_config_change_invalidates(
    committed: tuple[Path, Path], tmp_path: Path, tiny_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan, out = committed
    capsys.readouterr()
    assert main([*_args(plan, tiny_root, tmp_path / "runs"), "--dry-run", "--check", str(out)]) == 0
    assert "every row's config is the one" in capsys.readouterr().out.replace("\n", " ")
    assert main([*_args(plan, tiny_root, tmp_path / "runs", "sim_config.mgn.learning_rate=0.00105"), "--dry-run", "--check", str(out)]) == 0
    text = capsys.readouterr().out.replace("\n", " ")
    assert "table2_cdg/MGN: config changed" in text and "tables to regenerate: table2_cdg:" in text and "stability" not in text.split("tables to regenerate")[1]


def test_a_committed_folder_without_first_seed_tables_is_refused_for_a_first_seed_check(
    committed: tuple[Path, Path], tmp_path: Path, tiny_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan, out = committed
    shutil.rmtree(out / "first_seed")
    assert main([*_args(plan, tiny_root, tmp_path / "runs"), "--first-seeds", "1", "--out", str(tmp_path / "f"), "--check", str(out)]) == 2
    assert "no first-seed tables" in capsys.readouterr().err
