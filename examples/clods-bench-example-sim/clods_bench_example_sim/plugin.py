"""The entry-point module: one hook returning the plugin descriptor (name, description, factory, config class)."""

from __future__ import annotations

from clods_bench.api import PluginSpec, hookimpl

from clods_bench_example_sim.simulator import DampedVelocity, DampedVelocityConfig

CLODS_BENCH_API = "1.1"  # the plugin API this package is written for (clods_bench.api)


@hookimpl
def clods_bench_simulators() -> list[PluginSpec]:
    return [
        PluginSpec(
            name="damped-velocity",
            description="Example plugin: constant velocity with a damping factor (clods-bench-example-sim).",
            build=lambda cfg, ctx: DampedVelocity(cfg),
            config_cls=DampedVelocityConfig,
        )
    ]
