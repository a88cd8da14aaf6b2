"""A task declares its own table: a third-party task installed as a distribution gets its table from `tables`,
`report` and `reproduce` in the layout it declares, with the row label it declares; a task that declares none gets
one error line naming the task and the field, only when its table is asked for."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Iterator

import pandas as pd
import pytest

from clods_bench.benchmark.core.registry import STRICT_ENV, default_registry
from clods_bench.benchmark.reproduction.reproduce import build_configs, load_plan
from clods_bench.cli import main
from clods_bench.errors import ClodsError
from tests.conftest import TINY
from tests.plugin_packages import TASKS, install, only_own_plugins

DIST = "coin-tasks"


@pytest.fixture
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The tasks' distribution installed into a directory on sys.path; the registry sees it and the built-ins only."""
    path = tmp_path_factory.mktemp("tasks") / "site"
    install(path, DIST, TASKS)
    with only_own_plugins(path) as mp:
        mp.delenv(STRICT_ENV, raising=False)
        try:
            yield path
        finally:
            sys.modules.pop("cbt_coin_tasks", None)


def _run(task: str, tiny_root: Path, runs: Path) -> None:
    sets = [arg for o in (*TINY, f"data.root={tiny_root / 'data'}", f"runs_dir={runs}") for arg in ("--set", o)]
    assert main(["run", task, *sets]) == 0


def test_a_third_party_task_gets_the_table_it_declares(site: Path, tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs, out = tmp_path / "runs", tmp_path / "tables"
    _run("coin-flip", tiny_root, runs)
    assert (runs / "coin-flip" / "coin").is_dir()  # the row label the task declares names the record
    assert main(["tables", "--runs", str(runs), "--out", str(out)]) == 0
    md = (out / "coin-flip_flag_ci.md").read_text()
    assert md.startswith("Coin flips (flag, preset ci): one coin per seed.\n") and "| coin   |    0.25 |" in md
    csv = pd.read_csv(out / "coin-flip_flag_ci.csv")
    assert list(csv.columns) == ["method", "score"] and list(csv["method"]) == ["coin"] and csv["score"][0] == 0.25
    assert main(["report", "--runs", str(runs), "--out", str(tmp_path / "report")]) == 0
    assert "<th>Coin</th>" in (tmp_path / "report" / "index.html").read_text()


def test_a_task_without_a_layout_is_one_error_naming_the_field(site: Path, tiny_root: Path, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    runs = tmp_path / "runs"
    _run("no-table", tiny_root, runs)  # running it needs no table
    capsys.readouterr()
    assert main(["tables", "--runs", str(runs), "--task", "no-table", "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("error: TaskSpec(name='no-table').table: task 'no-table' declares no table layout") and "TableLayout(frame=" in err
    assert main(["tables", "--runs", str(runs), "--out", str(tmp_path / "t")]) == 2  # `all` asks for it too
    assert main(["report", "--runs", str(runs), "--out", str(tmp_path / "r")]) == 2
    plan = tmp_path / "plan.yaml"
    plan.write_text("version: 1\ntables:\n  - {id: t, task: no-table, title: T}\nruns:\n  - {table: t, task: no-table, label: a}\n")
    with pytest.raises(ClodsError, match=r"table 't': TaskSpec\(name='no-table'\).table: task 'no-table' declares no table layout"):
        build_configs(load_plan(plan), "ci", default_registry())  # reproduce says so before it runs anything
