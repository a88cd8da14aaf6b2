"""The runner's resolved config: every used plugin's options with their defaults, saved and in the record's identity."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.core.resolve import resolve_plugins
from clods_bench.benchmark.running.records import record_dir
from clods_bench.benchmark.running.run_data import ensure_complete_dataset
from clods_bench.benchmark.running.runner import run_task
from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.gs3d import Gs3dConfig
from tests.conftest import tiny_config


def test_plugin_defaults_are_filled_in_and_resolving_twice_changes_nothing() -> None:
    reg = default_registry()
    cfg = load_config("ci", overrides=["renderer_config.gs3d.iterations=7"], task="nvs", renderer="gs3d")
    assert cfg.renderer_config.get("gs3d") == {"iterations": 7}
    full = resolve_plugins(cfg, reg)
    gs3d = full.renderer_config["gs3d"]
    assert gs3d["iterations"] == 7 and gs3d["init"] == Gs3dConfig().init and gs3d["num_gaussians"] == Gs3dConfig().num_gaussians
    assert gs3d["background"] == list(Gs3dConfig().background)  # tuples as lists: what YAML gives back
    assert resolve_plugins(full, reg) == full
    assert "mgn" in full.sim_config and full.sim_config["mgn"] == cfg.sim_config["mgn"]  # an unused plugin is left alone


def test_a_changed_plugin_default_names_another_record_and_stating_the_default_does_not() -> None:
    reg = default_registry()

    def rdir(*sets: str) -> Path:
        return record_dir(resolve_plugins(load_config("ci", overrides=list(sets), task="nvs", renderer="gs3d"), reg), reg)

    default = rdir()
    assert rdir(f"renderer_config.gs3d.init={Gs3dConfig().init}") == default  # the same run, said explicitly
    assert rdir("renderer_config.gs3d.init=random") != default


def test_the_saved_config_holds_the_plugins_full_options(tmp_path: Path, tiny_root: Path) -> None:
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", task="cdg", sim="physics")
    rdir = run_task(cfg, default_registry(), ensure_data=ensure_complete_dataset)
    saved = yaml.safe_load((rdir / "config.yaml").read_text())
    assert saved["sim_config"]["physics"] == resolve_plugins(cfg, default_registry()).sim_config["physics"]
    assert "dt_factor" in saved["sim_config"]["physics"]  # a default nobody set, recorded all the same
    assert rdir == record_dir(resolve_plugins(cfg, default_registry()), default_registry())


def test_options_of_plugins_the_run_does_not_use_do_not_move_its_record() -> None:
    """A preset gaining options of another installed plugin (e.g. a third-party simulator's) keeps every other run's
    record; options of a plugin that is not installed are an error naming them (a misspelt name is no silent no-op)."""
    reg = default_registry()

    def rdir(*sets: str, **fields: str) -> Path:
        return record_dir(resolve_plugins(load_config("ci", overrides=list(sets), **fields), reg), reg)

    cdg = {"task": "cdg", "sim": "mgn", "renderer": "smgs"}
    base = rdir(**cdg)
    assert rdir("sim_config.bsms.levels=2", "renderer_config.gs3d.iterations=7", **cdg) == base
    with pytest.raises(ClodsError) as err:
        rdir("sim_config.mythirdpartysim.depth=3", **cdg)
    assert err.value.where == "sim_config.mythirdpartysim" and err.value.what.startswith("unknown simulator 'mythirdpartysim'; known: bsms,")
    assert rdir("sim_config.mgn.latent_size=32", **cdg) != base  # the used simulator's options do count
    assert rdir("renderer_config.smgs.gaussians_per_face=10", **cdg) != base  # and the used renderer's
    assert rdir("sim_config.mgn.latent_size=32", task="nvs", renderer="gs3d") == rdir(task="nvs", renderer="gs3d")
