"""Hook markers and the hook specifications of clods-bench, one module per domain.

A plugin is a module (or object) with `@hookimpl` functions; it is found through the
`clods_bench` entry-point group. Built-in plugins are registered exactly that way.
"""

import pluggy

PROJECT = "clods_bench"
ENTRY_POINT_GROUP = "clods_bench"

hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)

__all__ = ["PROJECT", "ENTRY_POINT_GROUP", "hookspec", "hookimpl"]
