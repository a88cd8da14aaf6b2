"""Hook specification: benchmark tasks (cdg, nvs, dvc, ...)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

from clods_bench.benchmark.core.hookspecs import hookspec

if TYPE_CHECKING:
    from clods_bench.benchmark.core.descriptors import TaskSpec


@hookspec
def clods_bench_tasks() -> Sequence["TaskSpec"]:
    """Return the tasks this plugin provides.

    `TaskSpec.run(context)` runs one seed of the task and returns its metrics;
    `TaskSpec.needs` says which plugin kinds the task requires ('sim', 'renderer').
    """
