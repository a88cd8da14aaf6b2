"""Plugin isolation: each installed plugin that goes wrong is named once (distribution, version, entry point, error)
and left out, the built-ins and the other plugins load; strict mode makes any failure an error."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from clods_bench.api_version import PluginAPIDeprecationWarning
from clods_bench.benchmark.core.registry import STRICT_ENV, PluginLoadWarning, Registry, default_registry, make_plugin_manager
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.errors import ClodsError
from tests.plugin_packages import install, install_all, module_name, only_own_plugins


@pytest.fixture
def site(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """An empty 'site-packages' on sys.path whose plugins the registry sees besides the built-ins (and no other
    installed plugin, which could change the outcome); the plugin modules imported from it are forgotten afterwards."""
    monkeypatch.delenv(STRICT_ENV, raising=False)
    path = tmp_path / "site"
    path.mkdir()
    with only_own_plugins(path):
        yield path
    for name in [m for m in sys.modules if m.startswith("cbt_")]:
        sys.modules.pop(name)


def _load(site: Path, *dists: str) -> tuple[Registry, list[str], list[str]]:
    """Install `dists`, build the registry: (registry, load-warning lines, deprecation lines)."""
    install_all(site, list(dists))
    with pytest.warns() as caught:
        reg = Registry.from_plugin_manager(make_plugin_manager())
    load = [str(w.message) for w in caught if issubclass(w.category, PluginLoadWarning)]
    deprecated = [str(w.message) for w in caught if issubclass(w.category, PluginAPIDeprecationWarning)]
    return reg, load, deprecated


def _only_line(lines: list[str], dist: str) -> str:
    mine = [line for line in lines if line.startswith(f"plugin {dist} 0.1.0 (entry point {dist} = {module_name(dist)})")]
    assert len(mine) == 1, lines  # reported once, naming distribution, version and entry point
    return mine[0]


def _builtins_intact(reg: Registry) -> None:
    assert {"constvel", "frozen", "physics"} <= set(reg.names("simulator"))
    assert {"flag", "cylinder"} <= set(reg.names("scene")) and "cdg" in reg.names("task")


def test_builtins_load_without_problems(site: Path) -> None:
    reg = default_registry(refresh=True)
    assert reg.failures == [] and reg.notices == []
    assert reg.sources["simulators"].builtin and reg.sources["simulators"].value == "clods_bench.plugins.simulators.builtin"


def test_import_failure_is_named_and_the_rest_loads(site: Path) -> None:
    reg, load, _ = _load(site, "broken-import", "good")
    line = _only_line(load, "broken-import")
    assert "failed to load: ModuleNotFoundError: No module named 'clods_bench_missing_dependency'" in line
    assert "good-sim" in reg.names("simulator") and reg.origins[("simulator", "good-sim")] == "good"
    _builtins_intact(reg)


def test_raising_hook_is_named_and_the_rest_loads(site: Path) -> None:
    reg, load, _ = _load(site, "hook-raises", "good")
    assert "failed to load: RuntimeError: scene server unreachable" in _only_line(load, "hook-raises")
    assert "good-sim" in reg.names("simulator")
    _builtins_intact(reg)


def test_plugin_for_a_newer_api_gets_one_line(site: Path) -> None:
    reg, load, _ = _load(site, "newer-api", "good")  # good declares 1.0 and loads
    line = _only_line(load, "newer-api")
    assert line.endswith("failed to load: it needs plugin API 2.0; this release offers plugin API 1.2 (and loads plugins "
                         "for 1.0 to 1.2); clods-bench runs without it")  # fmt: skip
    assert "future-sim" not in reg.names("simulator") and "good-sim" in reg.names("simulator")


def test_wrong_return_type_is_named(site: Path) -> None:
    reg, load, _ = _load(site, "wrong-type")
    assert "hook clods_bench_simulators returned a dict, expected a list of PluginSpec" in _only_line(load, "wrong-type")
    assert "fine-renderer" not in reg.names("renderer")  # the whole plugin is left out, not half of it
    _builtins_intact(reg)


@pytest.mark.parametrize(
    "dist, needle",
    [
        ("config-no-default", "simulator 'steps-sim': config field StepsConfig.steps has no default"),
        ("config-no-type", "simulator 'untyped-sim': config attribute DampingConfig.damping has no type annotation, so it is "
                           "no field of the dataclass (write `damping: float = 0.5`)"),
    ],
)  # fmt: skip
def test_bad_config_dataclass_names_the_field(site: Path, dist: str, needle: str) -> None:
    reg, load, _ = _load(site, dist)
    assert needle in _only_line(load, dist)
    _builtins_intact(reg)


def test_a_name_two_plugins_provide_is_used_by_neither_and_a_builtin_name_stays_builtin(site: Path) -> None:
    reg, load, _ = _load(site, "twin-a", "twin-b")
    both = [line for line in load if "simulator 'twin' is provided by" in line]
    assert len(both) == 1 and "plugin twin-a 0.1.0" in both[0] and "plugin twin-b 0.1.0" in both[0] and "neither is used" in both[0]
    assert {"a-only", "b-only"} <= set(reg.names("simulator")) and "twin" not in reg.names("simulator")
    with pytest.raises(ClodsError) as exc:
        reg.get("simulator", "twin")
    assert both[0] in exc.value.message
    shadow = _only_line(load, "twin-a")
    assert "its simulator 'constvel' is not used: plugin clods-bench" in shadow
    assert reg.origins[("simulator", "constvel")] == "simulators" and reg.get("simulator", "constvel").description != "a"


def test_two_packages_may_name_their_entry_points_alike(site: Path) -> None:
    for dist in ("alpha", "beta"):
        install(site, dist, f"from clods_bench.api import PluginSpec, hookimpl\n\n@hookimpl\ndef clods_bench_simulators():\n"
                            f"    return [PluginSpec(name='{dist}-sim', description='{dist}', build=lambda c, x: None)]\n",
                entry_point="plugin")  # fmt: skip
    reg = Registry.from_plugin_manager(make_plugin_manager())
    assert reg.failures == [] and {"alpha-sim", "beta-sim"} <= set(reg.names("simulator"))
    assert (reg.origins[("simulator", "alpha-sim")], reg.origins[("simulator", "beta-sim")]) == ("plugin", "beta:plugin")
    assert reg.sources["beta:plugin"].describe() == "plugin beta 0.1.0 (entry point plugin = cbt_beta)"


def test_deprecated_scene_form_works_with_a_warning_saying_what_to_write(site: Path) -> None:
    reg, load, deprecated = _load(site, "deprecated-scene")
    assert load == []
    assert len(deprecated) == 2 and all("plugin deprecated-scene 0.1.0" in d and "#scenes-kind-and-build_mesh" in d for d in deprecated)
    assert any("NarrowFlag overrides SceneSpec.build_mesh" in d and "cloth=YourCloth(...)" in d for d in deprecated)
    assert any("SceneSpec(kind='flag', size=(1.0, 0.4), default_resolution=(8, 4)) is deprecated since clods-bench 0.2.0 "
               "and removed in 0.3.0" in d for d in deprecated)  # fmt: skip
    scene = reg.get("scene", "narrow-flag")
    mesh, expected = scene.build_mesh(), make_flag_mesh(8, 4, 1.0, 0.4)
    np.testing.assert_array_equal(mesh.cells, expected.cells)
    np.testing.assert_array_equal(mesh.rest_pos, expected.rest_pos)
    assert scene.kind == "flag" and scene.default_resolution == (8, 4)


def test_a_needed_plugin_that_failed_gives_its_line(site: Path) -> None:
    reg, load, _ = _load(site, "config-no-default", "hook-raises")
    with pytest.raises(ClodsError) as exc:
        reg.get("simulator", "steps-sim")  # the failed plugin's own name: its line, nothing else
    assert exc.value.message == f"simulator 'steps-sim' is not available: {_only_line(load, 'config-no-default').split('; clods')[0]}"
    with pytest.raises(ClodsError) as exc:
        reg.get("scene", "banner")  # what hook-raises would have provided is unknown: the unknown-name error names it
    assert "unknown scene 'banner'" in exc.value.message and "a plugin that failed to load may provide it: plugin hook-raises" in exc.value.message


def test_strict_mode_makes_any_failure_an_error(site: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    install_all(site, ["broken-import", "good"])
    with pytest.warns(PluginLoadWarning), pytest.raises(ClodsError) as exc:
        Registry.from_plugin_manager(make_plugin_manager(), strict=True)
    assert "1 plugin problem(s) in strict mode: plugin broken-import 0.1.0" in exc.value.message
    monkeypatch.setenv(STRICT_ENV, "1")
    with pytest.warns(PluginLoadWarning), pytest.raises(ClodsError, match="strict because of --strict-plugins"):
        default_registry(refresh=True)  # the registry cached before this test is put back by `site`
