"""Hook specification: renderer plugins."""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

from clods_bench.benchmark.core.hookspecs import hookspec

if TYPE_CHECKING:
    from clods_bench.benchmark.core.descriptors import PluginSpec


@hookspec
def clods_bench_renderers() -> Sequence["PluginSpec"]:
    """Return the renderers this plugin provides.

    Each `PluginSpec.build(config, context)` must return an object satisfying
    `clods_bench.benchmark.core.interfaces.Renderer`. All implementations are called
    and their lists concatenated; a name provided twice is an error.
    """
