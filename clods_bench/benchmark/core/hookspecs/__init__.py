"""Hook markers and the hook specifications of clods-bench, one module per domain.

A plugin is a module (or object) with `@hookimpl` functions; it is found through the
`clods_bench` entry-point group. Built-in plugins are registered exactly that way. The hook
specifications are part of the public, versioned plugin API that `clods_bench.api` lists: each entry
point is loaded on its own, and one that fails is named and left out (`clods_bench.benchmark.core.registry`).
"""

import pluggy

PROJECT = "clods_bench"
ENTRY_POINT_GROUP = "clods_bench"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)

__all__ = ["PROJECT", "ENTRY_POINT_GROUP", "hookspec", "hookimpl"]
