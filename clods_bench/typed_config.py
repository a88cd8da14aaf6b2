"""Typed loading of configuration mappings (YAML, `--set` overrides) into dataclasses.

Unknown keys and wrong types fail loudly with the dotted field name and where the mapping came from; an int where
a float is expected becomes a float, so a config loaded twice has the same identity. Shared by the data config
(`datasets.data_config`), the run config and the plugins' config classes.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Literal

from clods_bench.errors import ClodsError, closest


def dataclass_from_dict(cls: type, data: dict[str, Any], where: str, prefix: str = "") -> Any:
    """Build dataclass `cls` from a mapping, checking keys and types; errors name `where` and the field."""
    if not isinstance(data, dict):
        raise ClodsError(f"'{prefix or cls.__name__}' must be a mapping, got {type(data).__name__}", where=where)
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        dotted = f"{prefix}{key}"
        if key not in names:
            best = closest(key, names)
            hint = f"did you mean '{prefix}{best}'?" if best else f"known: {', '.join(names)}"
            raise ClodsError(f"unknown config key '{dotted}'", where=where, hint=hint)
        kwargs[key] = coerce(hints[key], value, where, dotted)
    return cls(**kwargs)


def coerce(tp: Any, value: Any, where: str, dotted: str) -> Any:
    """`value` checked against (and converted to) type `tp`: dataclasses, unions, literals, lists, dicts, scalars;
    a mismatch is a ClodsError naming `dotted` and `where`."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if dataclasses.is_dataclass(tp):
        return dataclass_from_dict(tp, value, where, prefix=dotted + ".")
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        errors = []
        for option in args:
            try:
                return coerce(option, value, where, dotted)
            except ClodsError as exc:
                errors.append(exc.what)
        raise ClodsError(f"'{dotted}' = {value!r} matches none of {_type_name(tp)}", where=where)
    if tp is type(None):
        if value is None:
            return None
        raise _type_error(dotted, value, "null", where)
    if origin is Literal:
        if value in args:
            return value
        best = closest(str(value), [str(a) for a in args])
        raise ClodsError(
            f"'{dotted}' = {value!r}, expected one of {list(args)}", where=where, hint=f"did you mean '{best}'?" if best else None
        )
    if origin is list:
        if not isinstance(value, list):
            raise _type_error(dotted, value, _type_name(tp), where)
        return [coerce(args[0], v, where, f"{dotted}[{i}]") for i, v in enumerate(value)] if args else list(value)
    if origin is dict:
        if not isinstance(value, dict):
            raise _type_error(dotted, value, "a mapping", where)
        return {k: coerce(args[1], v, where, f"{dotted}.{k}") for k, v in value.items()} if args else dict(value)
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise _type_error(dotted, value, "true/false", where)
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise _type_error(dotted, value, "an integer", where)
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise _type_error(dotted, value, "a number", where)
    if tp is str:
        if isinstance(value, str):
            return value
        raise _type_error(dotted, value, "a string", where)
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    if origin is tuple:
        if isinstance(value, (list, tuple)):
            return tuple(value)
        raise _type_error(dotted, value, "a list", where)
    raise _type_error(dotted, value, _type_name(tp), where)


def _type_error(dotted: str, value: Any, expected: str, where: str) -> ClodsError:
    return ClodsError(f"'{dotted}' = {value!r} ({type(value).__name__}), expected {expected}", where=where)


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")
