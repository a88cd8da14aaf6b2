"""The plugin manager: built-ins come through entry points; duplicates, typos and bad hooks fail loudly."""

from __future__ import annotations

import pytest

from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.core.registry import Registry, default_registry, make_plugin_manager
from clods_bench.errors import ClodsError


def test_builtins_arrive_through_entry_points() -> None:
    reg = default_registry(refresh=True)
    assert {"constvel", "frozen"} <= set(reg.names("simulator"))
    assert {"flag", "flag-stiff", "flag-storm", "flag-large-dt", "cylinder"} <= set(reg.names("scene"))
    assert "cdg" in reg.names("task")
    assert reg.origins[("simulator", "constvel")] == "simulators"  # the entry-point name


def test_no_entry_points_means_nothing_registered() -> None:
    reg = Registry.from_plugin_manager(make_plugin_manager(load_entry_points=False))
    assert reg.names("simulator") == [] and reg.names("task") == []


def test_unknown_name_suggests_closest() -> None:
    with pytest.raises(ClodsError) as exc:
        default_registry().get("simulator", "constvell")
    assert "did you mean 'constvel'" in exc.value.message
    with pytest.raises(ClodsError, match="unknown scene 'flagg'"):
        default_registry().get("scene", "flagg")


class _Dup:
    @hookimpl
    def clods_bench_simulators(self):
        return [PluginSpec(name="constvel", description="again", build=lambda c, x: None)]


def test_duplicate_name_is_an_error() -> None:
    pm = make_plugin_manager([_Dup()])
    with pytest.raises(ClodsError, match="provided twice"):
        Registry.from_plugin_manager(pm)


class _Typo:
    @hookimpl
    def clods_bench_simulatorz(self):
        return []


def test_misspelled_hook_fails() -> None:
    with pytest.raises(ClodsError, match="unknown hook"):
        make_plugin_manager([_Typo()], load_entry_points=False)
