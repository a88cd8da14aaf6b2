"""Typed loading of configuration mappings (YAML, `--set` overrides) into dataclasses.

Unknown keys and wrong types fail loudly with the dotted field name and where the mapping came from; an int where
a float is expected becomes a float, so a config loaded twice has the same identity. Shared by the data config
(`datasets.data_config`), the run config and the plugins' config classes.
"""

from __future__ import annotations

import dataclasses
import math
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
            known = f"known: {', '.join(names)}" if names else "this configuration takes no keys"
            hint = f"did you mean '{prefix}{best}'?" if best else known
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


# ---------------------------------------------------------------- value checks shared by every config

MAX_STEPS = 100_000_000
"""The largest step count a config may ask for: optimiser steps, fitting iterations, frames per trajectory (10^8, 10x
MeshGraphNets' 10M training steps). A larger count is a typo, or a run that would not end in years; it is rejected
before any work starts."""


def check_count(value: Any, where: str, minimum: int = 1, maximum: int = MAX_STEPS) -> None:
    """Raise ClodsError naming `where` unless `value` is an integer in [minimum, maximum]."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ClodsError(f"must be an integer >= {minimum}, got {value!r}", where=where)
    if value > maximum:
        limit = " (10^8, the largest step count clods-bench accepts)" if maximum == MAX_STEPS else ""
        raise ClodsError(f"must be <= {maximum}{limit}, got {value}", where=where)


def check_number(value: Any, where: str, minimum: float | None = None, inclusive: bool = True, maximum: float | None = None) -> None:
    """Raise ClodsError naming `where` unless `value` is a finite number >= `minimum` (> with `inclusive` off) and
    <= `maximum` (each bound optional)."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and minimum is not None:
        ok = value >= minimum if inclusive else value > minimum
    if ok and maximum is not None:
        ok = value <= maximum
    if not ok:
        bounds = [f"{'>=' if inclusive else '>'} {minimum:g}"] if minimum is not None else []
        bounds += [f"<= {maximum:g}"] if maximum is not None else []
        raise ClodsError(f"must be a finite number{' ' + ' and '.join(bounds) if bounds else ''}, got {value!r}", where=where)


def check_finite_fields(obj: Any, where: str) -> None:
    """Raise ClodsError naming the first field of `obj` (a dataclass or a mapping; nested dataclasses, lists and
    mappings included) that holds a float NaN or infinity: no option of a run is meaningful at NaN, and "no limit"
    is spelt null."""
    for dotted, value in _numbers(obj, where):
        if not math.isfinite(value):
            raise ClodsError(f"must be a finite number, got {value!r}", where=dotted)


def check_config(obj: Any, where: str) -> None:
    """A plugin's loaded config checked before any work: its own `validate(where)` (or `validate()`), when it has
    one, then every number finite (`check_finite_fields`)."""
    validate = getattr(obj, "validate", None)
    if callable(validate):
        import inspect

        try:
            takes_where = "where" in inspect.signature(validate).parameters
        except (TypeError, ValueError):  # a builtin or C-level callable: call it plainly
            takes_where = False
        validate(where=where) if takes_where else validate()
    check_finite_fields(obj, where)


def _numbers(value: Any, dotted: str) -> list[tuple[str, float]]:
    """(dotted path, float) of every float inside `value`: dataclass fields, list items, mapping values."""
    if isinstance(value, float):
        return [(dotted, value)]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return [n for f in dataclasses.fields(value) for n in _numbers(getattr(value, f.name), f"{dotted}.{f.name}")]
    if isinstance(value, (list, tuple)):
        return [n for i, v in enumerate(value) for n in _numbers(v, f"{dotted}[{i}]")]
    if isinstance(value, dict):
        return [n for k, v in value.items() for n in _numbers(v, f"{dotted}.{k}")]
    return []
