"""The worked plugin example (examples/clods-bench-example-sim) pip-installs, registers, runs CDG and lands in the tables."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.cli import main
from tests.conftest import TINY
from tests.plugin_packages import only_own_plugins

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "clods-bench-example-sim"


@pytest.fixture(scope="module")
def installed_example(tmp_path_factory: pytest.TempPathFactory):
    """`pip install --target` the example (a copy: the checkout stays clean); the registry sees it and the built-ins only."""
    tmp_path = tmp_path_factory.mktemp("example")
    src = tmp_path / "src"
    shutil.copytree(EXAMPLE, src)
    site = tmp_path / "site"
    cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--target", str(site), str(src)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert (site / "clods_bench_example_sim-0.1.0.dist-info" / "entry_points.txt").is_file()
    with only_own_plugins(site):  # no other installed plugin can change the outcome; the cached registry restored after
        try:
            yield default_registry(refresh=True)
        finally:
            for name in [m for m in sys.modules if m.startswith("clods_bench_example_sim")]:
                sys.modules.pop(name)


def test_example_plugin_runs_through_the_cli_and_appears_in_tables(tmp_path: Path, tiny_root: Path, installed_example) -> None:
    reg = installed_example
    assert "damped-velocity" in reg.names("simulator")
    assert reg.origins[("simulator", "damped-velocity")] == "example_sim"
    source = reg.sources["example_sim"]  # declares CLODS_BENCH_API = "1.1", loads with nothing to report
    assert (source.distribution, source.version) == ("clods-bench-example-sim", "0.1.0") and not reg.failures and not reg.notices
    base = [*TINY, f"data.root={tiny_root / 'data'}", f"runs_dir={tmp_path / 'runs'}"]
    sets = [arg for o in base for arg in ("--set", o)]

    def run(sim: str, label: str, *extra: str) -> None:
        assert main(["run", "cdg", "--sim", sim, "--label", label, *sets, *[a for o in extra for a in ("--set", o)]]) == 0

    run("damped-velocity", "d0", "sim_config.damped-velocity.damping=0.0")
    run("damped-velocity", "d1", "sim_config.damped-velocity.damping=1.0")
    run("frozen", "frozen")
    run("constvel", "constvel")
    assert main(["tables", "--runs", str(tmp_path / "runs"), "--out", str(tmp_path / "tables"), "--task", "cdg"]) == 0
    csv = next((tmp_path / "tables").glob("cdg_*.csv"))
    table = pd.read_csv(csv).set_index("method")
    assert {"d0", "d1", "frozen", "constvel"} <= set(table.index)
    errors = [c for c in table.columns if c.endswith("/mean") and "/" in c[:-5]]
    assert len(errors) == 12
    # damping 0 is exactly the frozen cloth; damping 1 is constant velocity (up to float32 rounding)
    assert table.loc["d0", errors].to_numpy().tolist() == table.loc["frozen", errors].to_numpy().tolist()
    np.testing.assert_allclose(table.loc["d1", errors].to_numpy(float), table.loc["constvel", errors].to_numpy(float), rtol=1e-5)
    assert table.loc["d0", "viewed/extrap/d_avg/mean"] != table.loc["d1", "viewed/extrap/d_avg/mean"]


def test_example_plugin_config_is_typed(tmp_path: Path, tiny_root: Path, installed_example) -> None:
    sets = [arg for o in [*TINY, f"data.root={tiny_root / 'data'}", f"runs_dir={tmp_path / 'runs'}"] for arg in ("--set", o)]
    assert main(["run", "cdg", "--sim", "damped-velocity", *sets, "--set", "sim_config.damped-velocity.dampnig=0.5"]) == 2
    assert main(["run", "cdg", "--sim", "damped-velocity", *sets, "--set", "sim_config.damped-velocity.damping=1.5"]) == 2
