"""Registers the built-in renderers through the `clods_bench` entry-point group."""

from __future__ import annotations

from clods_bench.benchmark.descriptors import PluginSpec
from clods_bench.benchmark.hookspecs import hookimpl


@hookimpl
def clods_bench_renderers() -> list[PluginSpec]:
    return []
