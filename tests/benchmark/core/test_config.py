"""Config loading: presets, YAML files, overrides and the errors for bad input."""

from __future__ import annotations

import pytest

from clods_bench.benchmark.core.config import RunConfig, load_config, parse_override, preset_names, read_yaml, save_config
from clods_bench.datasets.data_config import DataConfig
from clods_bench.errors import ClodsError


def test_presets_exist_and_load() -> None:
    assert {"ci", "small", "paper"} <= set(preset_names())
    paper = load_config("paper")
    assert paper.data.resolution == "flagsimple"
    assert (paper.data.num_train, paper.data.num_test, paper.data.num_steps, paper.data.interp_steps) == (100, 20, 401, 300)
    assert paper.data.num_cameras == 30
    # stage 2 at paper size: the larger step and the progress rule (measured there), not the ci/small defaults
    assert paper.task_config["clods"] == {"learning_rate": 0.01, "stop_requires_progress": True}
    assert "stop_requires_progress" not in load_config("ci").task_config["clods"]


def test_overrides_are_typed() -> None:
    cfg = load_config("ci", overrides=["data.num_train=8", "seeds=[3, 4]", "data.fov_deg=40", "sim_config.mgn.latent=64"])
    assert cfg.data.num_train == 8 and cfg.seeds == [3, 4]
    assert cfg.data.fov_deg == 40.0 and isinstance(cfg.data.fov_deg, float)
    assert cfg.sim_config["mgn"]["latent"] == 64  # merged into the preset's sim_config.mgn, which keeps its keys
    assert cfg.sim_config["mgn"]["train_steps"] == load_config("ci").sim_config["mgn"]["train_steps"]
    assert parse_override("a.b=true") == ("a.b", True)


def test_unknown_key_suggests_closest() -> None:
    with pytest.raises(ClodsError) as exc:
        load_config("ci", overrides=["data.num_trian=8"])
    assert "data.num_trian" in exc.value.message and "data.num_train" in exc.value.message


def test_wrong_type_and_literal() -> None:
    with pytest.raises(ClodsError, match="data.num_train"):
        load_config("ci", overrides=["data.num_train=many"])
    with pytest.raises(ClodsError, match="first_half"):
        load_config("ci", overrides=["train_subset=firsthalf"])


def test_unknown_preset_suggests() -> None:
    with pytest.raises(ClodsError, match="did you mean 'small'"):
        load_config("smal")


def test_user_file_and_malformed_yaml(tmp_path) -> None:
    good = tmp_path / "run.yaml"
    good.write_text("preset: small\ndata:\n  num_test: 3\n")
    cfg = load_config(config_file=good)
    assert cfg.preset == "small" and cfg.data.num_test == 3 and cfg.data.num_train == 10
    bad = tmp_path / "bad.yaml"
    bad.write_text("data: [1, 2\n")
    with pytest.raises(ClodsError) as exc:
        load_config(config_file=bad)
    assert str(bad) in exc.value.message and "line" in exc.value.message
    with pytest.raises(ClodsError, match="not found"):
        load_config(config_file=tmp_path / "missing.yaml")


def test_resolved_config_round_trips(tmp_path) -> None:
    cfg = load_config("ci", overrides=["data.num_train=6"], sim="constvel")
    save_config(cfg, tmp_path / "c.yaml")
    from clods_bench.typed_config import dataclass_from_dict

    again = dataclass_from_dict(RunConfig, read_yaml(tmp_path / "c.yaml"), "saved")
    assert again == cfg


def test_dataset_dir_depends_on_data_not_root() -> None:
    a, b = DataConfig(root="x"), DataConfig(root="y")
    assert a.dataset_dir().name == b.dataset_dir().name
    assert DataConfig(num_train=5).dataset_dir().name != a.dataset_dir().name


def test_a_key_for_a_plugin_that_takes_no_configuration_says_so() -> None:
    from clods_bench.api import EmptyConfig
    from clods_bench.typed_config import dataclass_from_dict

    with pytest.raises(ClodsError) as exc:
        dataclass_from_dict(EmptyConfig, {"noise_gamma": 1.0}, "sim_config.frozen")
    assert "noise_gamma" in exc.value.message and "takes no keys" in str(exc.value)


def test_ci_and_small_pin_the_stated_recipe_rule() -> None:
    """docs/presets.md: every mesh model trains with MGN's noise gamma 0.1 at ci and small, except BSMS, HCMT and
    DHMP at small, which keep their authors' gamma (the plugin default)."""
    from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig, DhmpConfig, HcmtConfig

    ci, small = load_config("ci").sim_config, load_config("small").sim_config
    for sim in ("bsms", "hcmt", "dhmp"):
        assert ci[sim]["noise_gamma"] == 0.1, sim
    assert small["dhmp"]["noise_gamma"] == DhmpConfig().noise_gamma == 1.0
    assert small["bsms"]["noise_gamma"] == BsmsConfig().noise_gamma == 1.0
    assert small["hcmt"]["noise_gamma"] == HcmtConfig().noise_gamma == 1.0
