"""Registers the built-in simulators through the `clods_bench` entry-point group."""

from __future__ import annotations

from clods_bench.benchmark.descriptors import PluginSpec
from clods_bench.benchmark.hookspecs import hookimpl
from clods_bench.plugins.simulators.baselines import ConstantVelocity, Frozen


@hookimpl
def clods_bench_simulators() -> list[PluginSpec]:
    return [
        PluginSpec(
            name="constvel",
            description="Constant-velocity baseline: x[t+1] = 2 x[t] - x[t-1], handles kinematic.",
            build=lambda cfg, ctx: ConstantVelocity(),
        ),
        PluginSpec(
            name="frozen",
            description="Frozen-cloth baseline: every free node stays where it is at frame 1.",
            build=lambda cfg, ctx: Frozen(),
        ),
    ]
