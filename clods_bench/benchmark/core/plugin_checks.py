"""Checks of what a plugin's hooks return: the right descriptor type, usable names, config dataclasses a run can build.

Each problem is one ClodsError naming the hook, the item and the field, raised while the plugin loads, so that the
plugin is left out with that line instead of failing later inside a run.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Iterable, Mapping
from typing import Any

from clods_bench.benchmark.core.descriptors import PluginSpec, TaskSpec
from clods_bench.datasets.scenes import SceneSpec
from clods_bench.errors import ClodsError

DESCRIPTORS: dict[str, type] = {
    "simulator": PluginSpec,
    "renderer": PluginSpec,
    "scene": SceneSpec,
    "task": TaskSpec,
    "video_predictor": PluginSpec,
}
"""The descriptor each kind's hook returns a list of."""
TASK_NEEDS = ("sim", "renderer")


def check_hook_result(kind: str, hook: str, result: Any) -> list[Any]:
    """The items a hook returned, checked: a list (None: nothing) of `DESCRIPTORS[kind]` with distinct, usable names."""
    expected = DESCRIPTORS[kind]
    if result is None:
        return []
    if isinstance(result, (str, bytes, Mapping)) or not isinstance(result, Iterable):
        raise ClodsError(f"hook {hook} returned a {type(result).__name__}, expected a list of {expected.__name__}")
    items = list(result)
    seen: set[str] = set()
    for i, item in enumerate(items):
        if not isinstance(item, expected):
            raise ClodsError(f"hook {hook} returned a {type(item).__name__} at position {i}, expected a {expected.__name__}")
        name = item.name
        if not isinstance(name, str) or not name or any(c.isspace() or c == "." for c in name):
            raise ClodsError(f"hook {hook}: {kind} name {name!r} (position {i}) must be a non-empty string without spaces or dots")
        if name in seen:
            raise ClodsError(f"hook {hook} returns {kind} '{name}' twice")
        seen.add(name)
        if not isinstance(item.description, str):
            raise ClodsError(f"{kind} '{name}': description is a {type(item.description).__name__}, expected a string")
        if isinstance(item, PluginSpec):
            if not callable(item.build):
                raise ClodsError(f"{kind} '{name}': build is a {type(item.build).__name__}, expected a function (config, context) -> object")
            check_config_class(item.config_cls, f"{kind} '{name}'")
            for field in ("label", "variant"):
                value = getattr(item, field)
                if value is not None and (not isinstance(value, str) or not value.strip()):
                    raise ClodsError(f"{kind} '{name}': {field} {value!r} must be a non-empty string or None")
        if isinstance(item, TaskSpec):
            if not callable(item.run):
                raise ClodsError(f"task '{name}': run is a {type(item.run).__name__}, expected a function (context) -> TaskResult")
            bad = [n for n in item.needs if n not in TASK_NEEDS]
            if bad:
                raise ClodsError(f"task '{name}': needs {bad} unknown; a task needs some of {list(TASK_NEEDS)}")
    return items


def check_config_class(cls: Any, what: str, _seen: frozenset[type] = frozenset()) -> None:
    """A plugin's config class must be a dataclass whose every option is a typed field with a default (nested ones too).

    A run that sets no option still builds it, and the YAML loader types each option by its annotation: an
    attribute without one is no dataclass field at all, so setting it would be refused as an unknown key.
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise ClodsError(f"{what}: config_cls is {cls!r}, expected a dataclass")
    name = cls.__name__
    try:
        hints = typing.get_type_hints(cls)
    except Exception as exc:  # a string annotation naming something the module lacks
        raise ClodsError(f"{what}: the annotations of config {name} cannot be resolved ({type(exc).__name__}: {exc})") from None
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for f in fields.values():
        if f.init and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ClodsError(f"{what}: config field {name}.{f.name} has no default (every option needs one: a run that "
                             "sets none still builds the config)")  # fmt: skip
        tp = hints.get(f.name)
        if isinstance(tp, type) and dataclasses.is_dataclass(tp) and tp not in _seen:
            check_config_class(tp, what, _seen | {cls})
    for klass in cls.__mro__[:-1]:
        for attr, value in vars(klass).items():
            if attr.startswith("_") or attr in fields or attr in hints or callable(value):
                continue
            if isinstance(value, (property, classmethod, staticmethod)):
                continue
            raise ClodsError(f"{what}: config attribute {name}.{attr} has no type annotation, so it is no field of the "
                             f"dataclass (write `{attr}: {type(value).__name__} = {value!r}`)")  # fmt: skip
