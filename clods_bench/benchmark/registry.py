"""The plugin manager: load plugins from the entry-point group and index what they provide."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

import pluggy

from clods_bench.benchmark.hookspecs import ENTRY_POINT_GROUP, PROJECT, renderers, scenes, simulators, tasks, video_predictors
from clods_bench.errors import ClodsError, unknown_name

HOOKSPEC_MODULES = (simulators, renderers, scenes, tasks, video_predictors)
KINDS = ("simulator", "renderer", "scene", "task", "video_predictor")


def make_plugin_manager(extra_plugins: Iterable[Any] = (), load_entry_points: bool = True) -> pluggy.PluginManager:
    """A plugin manager with every hookspec added and the entry-point plugins loaded.

    `check_pending()` is called so that a misspelled hook name fails here, loudly.
    """
    pm = pluggy.PluginManager(PROJECT)
    for module in HOOKSPEC_MODULES:
        pm.add_hookspecs(module)
    if load_entry_points:
        pm.load_setuptools_entrypoints(ENTRY_POINT_GROUP)
    for plugin in extra_plugins:
        pm.register(plugin)
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        raise ClodsError(f"plugin defines an unknown hook: {exc}", where=str(exc.plugin)) from exc
    return pm


@dataclass
class Registry:
    """Everything the loaded plugins provide, by kind and name."""

    simulators: dict[str, Any] = field(default_factory=dict)
    renderers: dict[str, Any] = field(default_factory=dict)
    scenes: dict[str, Any] = field(default_factory=dict)
    tasks: dict[str, Any] = field(default_factory=dict)
    video_predictors: dict[str, Any] = field(default_factory=dict)
    origins: dict[tuple[str, str], str] = field(default_factory=dict)

    @classmethod
    def from_plugin_manager(cls, pm: pluggy.PluginManager) -> "Registry":
        """Collect every hook's results; the same name from two plugins is an error."""
        reg = cls()
        hooks = {
            "simulator": (pm.hook.clods_bench_simulators, reg.simulators),
            "renderer": (pm.hook.clods_bench_renderers, reg.renderers),
            "scene": (pm.hook.clods_bench_scenes, reg.scenes),
            "task": (pm.hook.clods_bench_tasks, reg.tasks),
            "video_predictor": (pm.hook.clods_bench_video_predictors, reg.video_predictors),
        }
        for kind, (hook, table) in hooks.items():
            for impl in hook.get_hookimpls():
                origin = pm.get_name(impl.plugin) or repr(impl.plugin)
                for item in impl.function() or ():
                    if item.name in table:
                        raise ClodsError(
                            f"{kind} '{item.name}' is provided twice: by {reg.origins[(kind, item.name)]} and by {origin}",
                            where="plugins",
                        )
                    table[item.name] = item
                    reg.origins[(kind, item.name)] = origin
        return reg

    def get(self, kind: str, name: str) -> Any:
        """The plugin of `kind` called `name`, or a ClodsError suggesting the closest name."""
        table = self._table(kind)
        if name not in table:
            raise unknown_name(kind, name, list(table))
        return table[name]

    def names(self, kind: str) -> list[str]:
        return sorted(self._table(kind))

    def _table(self, kind: str) -> dict[str, Any]:
        tables = {
            "simulator": self.simulators,
            "renderer": self.renderers,
            "scene": self.scenes,
            "task": self.tasks,
            "video_predictor": self.video_predictors,
        }
        if kind not in tables:
            raise unknown_name("plugin kind", kind, list(tables))
        return tables[kind]


_DEFAULT: Registry | None = None


def default_registry(refresh: bool = False) -> Registry:
    """The registry of the installed plugins (entry points), built once per process."""
    global _DEFAULT
    if _DEFAULT is None or refresh:
        _DEFAULT = Registry.from_plugin_manager(make_plugin_manager())
    return _DEFAULT
