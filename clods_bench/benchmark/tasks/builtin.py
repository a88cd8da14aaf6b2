"""Registers the built-in tasks through the `clods_bench` entry-point group, like any third-party plugin."""

from __future__ import annotations

from clods_bench.benchmark.descriptors import TaskSpec
from clods_bench.benchmark.hookspecs import hookimpl
from clods_bench.benchmark.tasks.cdg import run_cdg


@hookimpl
def clods_bench_tasks() -> list[TaskSpec]:
    return [
        TaskSpec(
            name="cdg",
            description="Cloth dynamics grounding: simulator rollout RMSE, viewed/unviewed x interpolation/extrapolation (Table 2).",
            run=run_cdg,
            needs=("sim",),
        ),
    ]
