"""The public plugin API as data: every name of `clods_bench.api` with its signature, dataclass fields and methods,
and the hook specifications. A test compares it with the committed snapshot of `API_VERSION`, so that no change of
the API goes out without a new version, its snapshot and a changelog entry.

`python -m tests.api_surface OUT.json` (from the repository root) writes the snapshot of the installed release.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import sys
from pathlib import Path
from typing import Any

GROWING = ("RunConfig", "DataConfig")
"""Config objects a plugin receives whose fields may be added in any release (a removal or change still counts)."""


def _signature(obj: Any) -> str:
    try:
        return str(inspect.signature(obj))
    except (TypeError, ValueError):  # a builtin without a signature
        return "(...)"


def _members(cls: type) -> dict[str, str]:
    """Public methods and properties, defined on `cls` or a base class of the package, by name."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not klass.__module__.startswith("clods_bench"):
            continue
        for name, value in vars(klass).items():
            if name.startswith("_") and name not in ("__call__",):
                continue
            if isinstance(value, property):
                out[name] = "property"
            elif isinstance(value, (classmethod, staticmethod)):
                out[name] = f"{type(value).__name__}{_signature(value.__func__)}"
            elif inspect.isfunction(value):
                out[name] = f"method{_signature(value)}"
    return out


def describe(obj: Any) -> dict[str, Any]:
    """One public name: its kind, and what a plugin relies on (signature, fields, methods; a constant's value)."""
    if isinstance(obj, type):
        out: dict[str, Any] = {"kind": "class", "bases": [b.__name__ for b in obj.__bases__], "methods": _members(obj)}
        if dataclasses.is_dataclass(obj):
            out["fields"] = {
                f.name: {"type": str(f.type), "required": f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
                for f in dataclasses.fields(obj)
            }  # defaults are behaviour, not interface: a changed default is a changelog entry, not a new API version
        return out
    if inspect.isfunction(obj) or isinstance(obj, type(describe)):
        return {"kind": "function", "signature": _signature(obj)}
    if callable(obj):  # pluggy's marker
        return {"kind": "object", "type": type(obj).__name__}
    return {"kind": "constant", "value": repr(obj)}


def hook_specs() -> dict[str, dict[str, Any]]:
    """Each hook specification: its arguments and pluggy options."""
    from clods_bench.benchmark.core.registry import HOOKSPEC_MODULES

    out = {}
    for module in HOOKSPEC_MODULES:
        for name, fn in vars(module).items():
            opts = getattr(fn, "clods_bench_spec", None)
            if opts is not None:
                out[name] = {"signature": _signature(fn), "firstresult": bool(opts.get("firstresult")), "historic": bool(opts.get("historic"))}
    return out


def api_surface() -> dict[str, Any]:
    """The whole public API: {"version", "names": {name: describe(...)}, "hooks": hook_specs()}."""
    from clods_bench import api

    return {"version": api.API_VERSION, "names": {name: describe(getattr(api, name)) for name in api.__all__}, "hooks": hook_specs()}


def surface_changes(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """What differs between two surfaces, one line per name (fields added to a GROWING config are not a change)."""
    changes = []
    for section in ("names", "hooks"):
        a, b = old.get(section, {}), new.get(section, {})
        for name in sorted(set(a) | set(b)):
            if name not in b:
                changes.append(f"{section}: {name} removed")
            elif name not in a:
                changes.append(f"{section}: {name} added")
            elif name in GROWING and section == "names":
                for part in ("fields", "methods"):
                    lost = {k: v for k, v in a[name].get(part, {}).items() if b[name].get(part, {}).get(k) != v}
                    changes += [f"names: {name}.{k} removed or changed (was {v})" for k, v in lost.items()]
            elif a[name] != b[name]:
                keys = sorted(k for k in set(a[name]) | set(b[name]) if a[name].get(k) != b[name].get(k))
                changes.append(f"{section}: {name} changed ({', '.join(keys)})")
    return changes


if __name__ == "__main__":
    Path(sys.argv[1]).write_text(json.dumps(api_surface(), indent=1, sort_keys=True) + "\n")
