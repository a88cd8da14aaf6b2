"""Registers the built-in scenes through the `clods_bench` entry-point group."""

from __future__ import annotations

from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.datasets.scenes import BUILTIN_SCENES, SceneSpec


@hookimpl
def clods_bench_scenes() -> list[SceneSpec]:
    return list(BUILTIN_SCENES)
