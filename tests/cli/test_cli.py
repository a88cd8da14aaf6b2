"""The command line: one clear error line and exit code 2 for bad input, no traceback unless --debug."""

from __future__ import annotations

from pathlib import Path

import pytest

from clods_bench.cli import main
from clods_bench.errors import ClodsError
from tests.conftest import TINY


def test_list_shows_everything(capsys) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ("constvel", "cdg", "flag-storm", "ci", "paper"):
        assert name in out


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["run", "cdg", "--sim", "constvell"], "did you mean 'constvel'"),
        (["run", "cdgg", "--sim", "constvel"], "unknown task 'cdgg'"),
        (["run", "cdg", "--sim", "constvel", "--preset", "tiny"], "unknown preset 'tiny'"),
        (["run", "cdg", "--sim", "constvel", "--scene", "flg"], "did you mean 'flag'"),
        (["run", "cdg", "--sim", "constvel", "--set", "data.nm_train=3"], "did you mean 'data.num_train'"),
    ],
)
def test_bad_names_exit_2_with_one_line(argv, needle, capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
    assert not (tmp_path / "data").exists()  # nothing generated before the names were checked


def test_malformed_yaml_names_file(tmp_path, capsys) -> None:
    bad = tmp_path / "run.yaml"
    bad.write_text("data:\n  num_train: [1\n")
    assert main(["run", "cdg", "--sim", "constvel", "--config", str(bad)]) == 2
    assert str(bad) in capsys.readouterr().err


def test_debug_reraises(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ClodsError):
        main(["--debug", "run", "cdg", "--sim", "nope"])


def test_run_and_tables_end_to_end(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    args = [a for s in TINY for a in ("--set", s)]
    assert main(["run", "cdg", "--sim", "constvel", *args]) == 0
    out = capsys.readouterr().out
    assert "viewed/interp/d_avg" in out and "infer_ms_per_step" in out
    assert main(["tables", "--runs", "runs", "--out", "tables"]) == 0
    assert (Path("tables") / "cdg_flag_ci.md").is_file()
    assert main(["run", "cdg", "--sim", "frozen", *args, "--set", "runs_dir=runs2"]) == 0
    capsys.readouterr()
    assert main(["tables", "--runs", "runs", "runs2", "--out", "tables2"]) == 0  # two folders, one table
    assert [r.split(",")[0] for r in (Path("tables2") / "cdg_flag_ci.csv").read_text().splitlines()[1:]] == ["Const. velocity", "Frozen"]
    assert main(["tables", "--runs", "runs", "--out", "tables", "--task", "nvs"]) == 2  # no nvs records: a clear error
    assert "no 'nvs' run records" in capsys.readouterr().err
    assert main(["report", "--runs", "runs", "--out", "report"]) == 0
    assert (Path("report") / "error_vs_time_flag_ci.png").stat().st_size > 1000
    assert "constvel" in (Path("report") / "error_vs_time_flag_ci.csv").read_text()
