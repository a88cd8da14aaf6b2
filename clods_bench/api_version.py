"""The plugin API's version, the versions a plugin may declare, and the deprecation schedule (no imports: every layer reads it).

A plugin module declares the API it was written for as `CLODS_BENCH_API = "1.2"`. The API follows semantic
versioning of its own: a minor version adds, a major version changes or removes. This release loads plugins
written for any minor version of its major version up to its own; a form it deprecates keeps working, with a
`PluginAPIDeprecationWarning`, until the next minor release of clods-bench removes it.
"""

from __future__ import annotations

API_VERSION = "1.2"
"""The plugin API of this release (`clods_bench.api` lists it)."""

DECLARATION = "CLODS_BENCH_API"
"""The module attribute a plugin declares its API version with."""

DEPRECATED_SINCE = "0.2.0"
"""The clods-bench release that deprecated the forms still accepted (the pre-1.0 scene form)."""

REMOVED_IN = "0.3.0"
"""The clods-bench release that no longer accepts them."""

MIGRATING = "docs/plugins/migrating.md"
"""The migrating guide; each deprecation message names its section."""


class PluginAPIDeprecationWarning(DeprecationWarning):
    """A plugin uses a form of the API that still works but is removed in `REMOVED_IN`; the message says what to write."""


def parse_api_version(value: object) -> tuple[int, int] | None:
    """(major, minor) of a declared version "MAJOR.MINOR" (a string), or None if it is not one."""
    if not isinstance(value, str):
        return None
    parts = value.strip().split(".")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        return None
    return int(parts[0]), int(parts[1])


def api_version_problem(declared: object) -> str | None:
    """Why a plugin declaring `declared` cannot load here (one line), or None if this release supports it."""
    major, minor = parse_api_version(API_VERSION) or (0, 0)
    offered = f"this release offers plugin API {API_VERSION} (and loads plugins for {major}.0 to {API_VERSION})"
    version = parse_api_version(declared)
    if version is None:
        return f"{DECLARATION} = {declared!r} is not a version like '{API_VERSION}'; {offered}"
    if version[0] != major or version[1] > minor:
        return f"it needs plugin API {version[0]}.{version[1]}; {offered}"
    return None
