"""bench sim: per-step train/inference times from a fake clock, skipping unknown names; physics on a real mesh."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from rich.console import Console

from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.core.registry import Registry, make_plugin_manager
from clods_bench.benchmark.speed.sim_bench import bench_sim
from tests.benchmark.speed.fake_clock import FakeClock

CLOCK = FakeClock()


@dataclass(frozen=True)
class StepsConfig:
    """A learned simulator's options."""

    steps: int = 1000


class FakeLearned:
    """fit costs 5 s of set-up plus 0.25 s per step; rollout `step_seconds` (10 ms) per step (on the fake clock)."""

    step_seconds = 0.010

    def __init__(self, cfg: StepsConfig) -> None:
        self.cfg = cfg

    def fit(self, train, ctx):
        CLOCK.now += 5.0 + 0.25 * self.cfg.steps
        return {}

    def rollout(self, inp):
        CLOCK.now += self.step_seconds * (inp.num_frames - 2)
        return np.repeat(inp.init_pos[1:], inp.num_frames, axis=0)


class FakeSolver(FakeLearned):
    """40 ms per rollout step, nothing to train."""

    step_seconds = 0.040

    def fit(self, train, ctx):
        return {}


class Fakes:
    @hookimpl
    def clods_bench_simulators(self) -> list[PluginSpec]:
        return [
            PluginSpec("learned", "fake", lambda cfg, ctx: FakeLearned(cfg), StepsConfig, learned=True),
            PluginSpec("stepless", "fake", lambda cfg, ctx: FakeLearned(StepsConfig(3)), learned=True),
            PluginSpec("solver", "fake", lambda cfg, ctx: FakeSolver(StepsConfig())),
        ]


def test_bench_sim_times_per_step_and_skips_unknown() -> None:
    reg = Registry.from_plugin_manager(make_plugin_manager(extra_plugins=[Fakes()], load_entry_points=False))
    console = Console(record=True, width=200)
    out = bench_sim(
        console, sims=("learned", "stepless", "nope", "solver"), frames=6, resolution=(5, 3), registry=reg, reference="solver", clock=CLOCK
    )
    assert set(out) == {"learned", "stepless", "solver"}
    assert out["learned"].train_s_per_step == pytest.approx(0.25)  # set-up cost cancels in the difference
    assert out["learned"].infer_ms_per_step == pytest.approx(10.0)
    assert out["solver"].infer_ms_per_step == pytest.approx(40.0) and np.isnan(out["solver"].train_s_per_step)
    assert np.isnan(out["stepless"].train_s_per_step) and "not timed" in out["stepless"].note
    text = console.export_text()
    assert "nope" in text and "not registered" in text and "0.25" in text  # ratio learned / solver = 10 / 40
    assert "learned" in text and " 0.25 " in text.split("learned")[1].split("\n")[0]


def test_bench_sim_physics_runs_on_a_small_flag() -> None:
    out = bench_sim(Console(quiet=True), sims=("physics", "constvel"), frames=5, resolution=(6, 4))
    assert out["physics"].infer_ms_per_step > 0 and out["constvel"].note == "not trained"


@dataclass(frozen=True)
class WarmupConfig:
    """Options of a learned simulator whose first `warmup_steps` steps only gather statistics (like MGN's)."""

    train_steps: int = 10
    warmup_steps: int = 1000


class FakeWarmup(FakeLearned):
    """Warm-up steps cost 0.01 s, optimiser steps 0.25 s (on the fake clock)."""

    def fit(self, train, ctx):
        warm = min(self.cfg.train_steps, self.cfg.warmup_steps)
        CLOCK.now += 5.0 + 0.01 * warm + 0.25 * (self.cfg.train_steps - warm)
        return {}


class WarmupFakes:
    @hookimpl
    def clods_bench_simulators(self) -> list[PluginSpec]:
        return [PluginSpec("warm", "fake", lambda cfg, ctx: FakeWarmup(cfg), WarmupConfig, learned=True)]


def test_bench_sim_times_optimiser_steps_not_warm_up() -> None:
    reg = Registry.from_plugin_manager(make_plugin_manager(extra_plugins=[WarmupFakes()], load_entry_points=False))
    out = bench_sim(Console(quiet=True), sims=("warm",), frames=5, resolution=(5, 3), registry=reg, reference="warm", clock=CLOCK)
    assert out["warm"].train_s_per_step == pytest.approx(0.25) and "warmup_steps=0" in out["warm"].note


@dataclass(frozen=True)
class DeviceConfig:
    """A learned simulator with a step count and a device option."""

    steps: int = 10
    device: str = "cpu"


class FakeDevice(FakeLearned):
    """0.25 s per training step and 10 ms per rollout step on 'cpu', a quarter of both on any other device."""

    def __init__(self, cfg: DeviceConfig) -> None:
        super().__init__(cfg)
        self.speed = 1.0 if cfg.device == "cpu" else 0.25
        self.step_seconds = FakeLearned.step_seconds * self.speed

    def fit(self, train, ctx):
        CLOCK.now += 5.0 + 0.25 * self.cfg.steps * self.speed
        return {}


class DeviceFakes:
    @hookimpl
    def clods_bench_simulators(self) -> list[PluginSpec]:
        return [
            PluginSpec("dev", "fake", lambda cfg, ctx: FakeDevice(cfg), DeviceConfig, learned=True),
            PluginSpec("solver", "fake", lambda cfg, ctx: FakeSolver(StepsConfig())),
        ]


def test_bench_sim_times_learned_simulators_on_each_device_with_the_cpu_speed_up() -> None:
    reg = Registry.from_plugin_manager(make_plugin_manager(extra_plugins=[DeviceFakes()], load_entry_points=False))
    console = Console(record=True, width=250)
    out = bench_sim(console, sims=("dev", "solver"), frames=6, resolution=(5, 3), registry=reg, reference="solver",
                    clock=CLOCK, devices=("cpu", "gpu0"))  # fmt: skip
    assert set(out) == {"dev", "dev@gpu0", "solver"}  # the solver has no device option: CPU only
    assert out["dev"].train_s_per_step == pytest.approx(0.25) and out["dev@gpu0"].train_s_per_step == pytest.approx(0.0625)
    assert out["dev@gpu0"].infer_ms_per_step == pytest.approx(2.5)
    row = next(line for line in console.export_text().splitlines() if "dev@gpu0" in line)
    cells = [c.strip() for c in row.split("│")[1:-1]]
    assert cells[4:6] == ["4", "4"]  # train and infer speed-up over the CPU, both 4x


def test_sim_overrides_group_options_by_simulator_and_refuse_other_keys() -> None:
    from clods_bench.benchmark.speed.sim_bench import sim_overrides
    from clods_bench.errors import ClodsError

    got = sim_overrides([("sim_config.mgn.loss", "rollout"), ("sim_config.mgn.rollout_length", 8), ("sim_config.bsms.device", "cuda")])
    assert got == {"mgn": {"loss": "rollout", "rollout_length": 8}, "bsms": {"device": "cuda"}}
    with pytest.raises(ClodsError, match="data.num_train"):
        sim_overrides([("data.num_train", 3)])
