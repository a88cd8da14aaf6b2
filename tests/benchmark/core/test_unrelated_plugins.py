"""Plugins installed in the environment for other reasons change no plugin test: a plain registry sees them, the
tests' registry (`only_own_plugins`) sees the built-ins and what the test installs, and the isolation tests pass."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Iterator

import pytest

from clods_bench.benchmark.core import registry
from clods_bench.benchmark.core.registry import STRICT_ENV, PluginLoadWarning, Registry, default_registry, make_plugin_manager
from tests.plugin_packages import ROOT, install, module_name, only_own_plugins

FLAT_SHADE = '''
from clods_bench.api import PluginSpec, hookimpl
import flat_shade_gl  # a dependency not installed here: the plugin fails to load

@hookimpl
def clods_bench_renderers():
    return [PluginSpec(name="flat-shade", description="flat shading", build=lambda c, x: None)]
'''

SIM_ZOO = '''
from clods_bench.api import PluginSpec, hookimpl

@hookimpl
def clods_bench_simulators():  # names the isolation tests' and the worked example's plugins give
    names = ("good-sim", "twin", "alpha-sim", "damped-velocity")
    return [PluginSpec(name=n, description="zoo", build=lambda c, x: None) for n in names]
'''

BUILTIN_SOURCES = {"tasks", "scenes", "simulators", "renderers", "video_predictors"}


@pytest.fixture
def unrelated(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A site with two third-party plugins on sys.path, as if pip-installed: one fails to load, one takes test names."""
    monkeypatch.delenv(STRICT_ENV, raising=False)
    site = tmp_path / "unrelated"
    install(site, "flat-shade", FLAT_SHADE)
    install(site, "sim-zoo", SIM_ZOO)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(registry, "_DEFAULT", None)  # the registry cached before is put back afterwards
    yield site
    for dist in ("flat-shade", "sim-zoo"):
        sys.modules.pop(module_name(dist), None)


def test_a_plain_registry_sees_them_and_the_tests_registry_does_not(unrelated: Path) -> None:
    with pytest.warns(PluginLoadWarning) as caught:
        plain = default_registry(refresh=True)
    lines = [str(w.message) for w in caught]
    assert any(line.startswith("plugin flat-shade 0.1.0 (entry point flat-shade = cbt_flat_shade) failed to load: "
                               "ModuleNotFoundError: No module named 'flat_shade_gl'") for line in lines), lines  # fmt: skip
    assert [f.source.distribution for f in plain.failures] == ["flat-shade"]
    assert plain.origins[("simulator", "good-sim")] == plain.origins[("simulator", "twin")] == "sim-zoo"
    with only_own_plugins():
        own = Registry.from_plugin_manager(make_plugin_manager())
    assert own.failures == [] and own.notices == [] and set(own.sources) == BUILTIN_SOURCES
    assert not {"good-sim", "twin", "alpha-sim"} & set(own.names("simulator")) and "flat-shade" not in own.names("renderer")


def test_the_isolation_tests_pass_with_them_installed(unrelated: Path, tmp_path: Path) -> None:
    """Run tests/benchmark/core/test_plugin_isolation.py in an interpreter that has them installed (before the tests saw
    only their own plugins, eight of its twelve tests failed there)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(unrelated), str(ROOT)])}
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--basetemp={tmp_path / 'inner'}",
           "tests/benchmark/core/test_plugin_isolation.py"]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert res.returncode == 0 and " passed" in res.stdout and "failed" not in res.stdout, res.stdout[-4000:] + res.stderr[-2000:]
