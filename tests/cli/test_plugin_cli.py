"""The command line beside broken, outdated and deprecated plugins: `list` and `run` keep working and name each
problem once; a run that needs a failed plugin exits 2 with its line; `--strict-plugins` makes any failure an error."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Iterator

import pytest

import clods_bench.benchmark.core.registry as registry_module
from clods_bench.benchmark.core.registry import STRICT_ENV, default_registry
from clods_bench.cli import main
from tests.conftest import TINY
from tests.plugin_packages import PACKAGES, install_all, module_name, run_cli

FAILING = ["broken-import", "hook-raises", "newer-api", "wrong-type", "config-no-default", "config-no-type", "twin-b"]
"""The distributions whose warning starts with their own name (twin-b's names twin-a too)."""


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Every test plugin of `plugin_packages` installed into one directory on sys.path."""
    path = tmp_path_factory.mktemp("plugins") / "site"
    install_all(path)
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv(STRICT_ENV, raising=False)
        mp.syspath_prepend(str(path))
        try:
            yield path
        finally:
            for name in [m for m in sys.modules if m.startswith("cbt_")]:
                sys.modules.pop(name)
    default_registry(refresh=True)


@pytest.fixture
def fresh(site: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The next command builds the registry anew (and so reports the plugins again)."""
    monkeypatch.setattr(registry_module, "_DEFAULT", None)
    return site


def _sets(*overrides: str) -> list[str]:
    return [arg for o in overrides for arg in ("--set", o)]


def _once_each(err: str) -> None:
    for dist in FAILING:
        prefix = f"warning: plugin {dist} 0.1.0 (entry point {dist} = {module_name(dist)})"
        assert err.count(prefix) == 1, (dist, err)
    assert err.count("deprecated: plugin deprecated-scene 0.1.0") == 2  # the override and the kind= call


def test_list_names_each_failure_once_and_lists_the_rest(fresh: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    captured = capsys.readouterr()
    _once_each(captured.err)
    assert "internal error" not in captured.err
    out = captured.out
    assert "plugin API 1.2" in out and "failed plugins (left out; --strict-plugins makes this an error):" in out
    section = out.split("failed plugins")[1]
    for dist in FAILING:
        assert f"  - plugin {dist} 0.1.0 (entry point {dist} = {module_name(dist)})" in section
    assert "deprecated forms in use" in out and "narrow-flag" in out and "good-sim" in out and "constvel" in out


def test_unrelated_run_works_beside_them(fresh: Path, tiny_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sets = _sets(*TINY, f"data.root={tiny_root / 'data'}", f"runs_dir={tmp_path / 'runs'}")
    assert main(["run", "cdg", "--sim", "constvel", *sets]) == 0
    _once_each(capsys.readouterr().err)
    assert main(["run", "cdg", "--sim", "good-sim", *sets]) == 0  # a working plugin from the same place runs too


def test_run_needing_a_failed_plugin_exits_2_with_its_line(fresh: Path, tiny_root: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    sets = _sets(*TINY, f"data.root={tiny_root / 'data'}", f"runs_dir={tmp_path / 'runs'}")
    assert main(["run", "cdg", "--sim", "steps-sim", *sets]) == 2
    err = capsys.readouterr().err
    line = ("plugin config-no-default 0.1.0 (entry point config-no-default = cbt_config_no_default) failed to load: "
            "simulator 'steps-sim': config field StepsConfig.steps has no default")  # fmt: skip
    assert f"error: sim: simulator 'steps-sim' is not available: {line}" in err
    assert "internal error" not in err and "Traceback" not in err
    assert not (tmp_path / "runs").exists()


def test_deprecated_scene_runs_through_data_and_cdg(fresh: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sets = _sets(*TINY, "data.resolution=[5,3]", f"data.root={tmp_path / 'data'}", f"runs_dir={tmp_path / 'runs'}")
    assert main(["run", "cdg", "--sim", "constvel", "--scene", "narrow-flag", *sets]) == 0
    assert "deprecated: plugin deprecated-scene 0.1.0" in capsys.readouterr().err
    (record,) = (tmp_path / "runs" / "cdg" / "Const._velocity").iterdir()
    assert record.name.startswith("narrow-flag-")


def test_strict_plugins_makes_any_failure_an_error(fresh: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--strict-plugins", "list"]) == 2
    err = capsys.readouterr().err
    problems = len(FAILING) + 1  # and twin-a's 'constvel', left to the built-in
    assert f"error: plugins: {problems} plugin problem(s) in strict mode: plugin broken-import 0.1.0" in err
    assert "strict because of --strict-plugins or CLODS_BENCH_STRICT_PLUGINS=1" in err
    assert STRICT_ENV not in os.environ  # the option lasts one command


def test_a_fresh_interpreter_with_the_plugins_installed(site: Path, tmp_path: Path) -> None:
    """As a user meets it: the plugins pip-installed beside clods-bench, `clods-bench list` run from a shell."""
    res = run_cli(site, "list")
    assert res.returncode == 0, res.stderr
    _once_each(res.stderr)
    assert "internal error" not in res.stderr and "failed plugins" in res.stdout
    assert set(PACKAGES) == set(FAILING) | {"twin-a", "good", "deprecated-scene"}


@pytest.mark.slow
def test_a_fresh_interpreter_runs_cdg_beside_them(site: Path, tiny_root: Path, tmp_path: Path) -> None:
    sets = _sets(*TINY, f"data.root={tiny_root / 'data'}", f"runs_dir={tmp_path / 'runs'}")
    res = run_cli(site, "run", "cdg", "--sim", "constvel", *sets)
    assert res.returncode == 0, res.stderr
    _once_each(res.stderr)
