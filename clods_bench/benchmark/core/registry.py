"""The plugin manager and the registry: load plugins from the entry-point group, isolated, and index what they provide.

An installed plugin that fails (import, API version, hook, bad descriptor, a name another plugin has) is reported
once, as a `PluginLoadWarning` naming its distribution, version and entry point, and left out; everything else
works. A command that needs what it would have provided fails with that line. Strict mode (`--strict-plugins`, or
`CLODS_BENCH_STRICT_PLUGINS=1`, as CI sets) turns any failure into an error. Plugins given in code fail loudly.
"""

from __future__ import annotations

import multiprocessing
import os
import warnings
from dataclasses import dataclass, field
from typing import Any, Iterable

import pluggy

from clods_bench.api_version import PluginAPIDeprecationWarning
from clods_bench.benchmark.core.hookspecs import renderers, scenes, simulators, tasks, video_predictors
from clods_bench.benchmark.core.plugin_checks import check_hook_result
from clods_bench.benchmark.core.plugin_loading import (
    ClodsPluginManager,
    PluginFailure,
    PluginNotice,
    PluginSource,
    call_guarded,
    error_line,
    load_entry_points as load_entry_point_plugins,
    register_plugin,
)
from clods_bench.errors import ClodsError, unknown_name

HOOKSPEC_MODULES = (simulators, renderers, scenes, tasks, video_predictors)
KINDS = ("simulator", "renderer", "scene", "task", "video_predictor")
HOOKS = {kind: f"clods_bench_{kind}s" for kind in KINDS}
STRICT_ENV = "CLODS_BENCH_STRICT_PLUGINS"
"""Set to 1 (as `--strict-plugins` and CI do) to make any plugin load failure an error."""


class PluginLoadWarning(UserWarning):
    """An installed plugin failed to load and is left out; the message names it and the error."""


def strict_from_env() -> bool:
    return os.environ.get(STRICT_ENV, "").strip().lower() not in ("", "0", "false", "no")


def make_plugin_manager(extra_plugins: Iterable[Any] = (), load_entry_points: bool = True) -> ClodsPluginManager:
    """A plugin manager with every hookspec added, the entry-point plugins loaded one by one, then `extra_plugins`.

    An entry point that fails is recorded in `pm.failures`; a plugin given in `extra_plugins` that fails (an
    unknown hook, a bad signature) raises a ClodsError at once.
    """
    pm = ClodsPluginManager()
    for module in HOOKSPEC_MODULES:
        pm.add_hookspecs(module)
    if load_entry_points:
        load_entry_point_plugins(pm)
    for plugin in extra_plugins:
        source = PluginSource(pm.get_canonical_name(plugin))
        try:
            register_plugin(pm, plugin, source)
        except (ClodsError, pluggy.PluginValidationError, ValueError) as exc:
            raise ClodsError(str(exc), where=source.describe()) from exc
    return pm


@dataclass
class Registry:
    """Everything the loaded plugins provide, by kind and name, and which plugins failed or use deprecated forms."""

    simulators: dict[str, Any] = field(default_factory=dict)
    renderers: dict[str, Any] = field(default_factory=dict)
    scenes: dict[str, Any] = field(default_factory=dict)
    tasks: dict[str, Any] = field(default_factory=dict)
    video_predictors: dict[str, Any] = field(default_factory=dict)
    origins: dict[tuple[str, str], str] = field(default_factory=dict)
    """(kind, name) -> the providing plugin's name (its entry point's name)."""
    sources: dict[str, PluginSource] = field(default_factory=dict)
    failures: list[PluginFailure] = field(default_factory=list)
    notices: list[PluginNotice] = field(default_factory=list)

    @classmethod
    def from_plugin_manager(cls, pm: pluggy.PluginManager, strict: bool = False) -> "Registry":
        """Call each plugin's hooks on its own and index the results; see the module docstring for failures."""
        reg = cls()
        reg.failures = list(getattr(pm, "failures", []))
        collector = pm if isinstance(pm, ClodsPluginManager) else ClodsPluginManager()  # gathers deprecation notices
        withheld: dict[tuple[str, str], list[PluginSource]] = {}
        for name, plugin in pm.list_name_plugin():
            if plugin is None:
                continue
            source = getattr(pm, "sources", {}).get(name) or PluginSource(name)
            reg.sources[name] = source
            provided: list[tuple[str, str]] = []
            ok, items, error = call_guarded(collector, source, lambda: _plugin_items(pm, plugin, provided))
            if not ok:
                if source.in_code:
                    raise ClodsError(error_line(error), where=source.describe()) from error
                reg.failures.append(PluginFailure.from_exception(source, error, tuple(provided)))
                continue
            for kind, item in items:
                reg._add(kind, item, source, withheld)
        for (kind, name), owners in withheld.items():
            who = " and ".join(s.describe() for s in owners)
            error = f"{kind} '{name}' is provided by {who}: neither is used (uninstall one, or have one renamed)"
            reg.failures.append(PluginFailure(owners[-1], error, ((kind, name),), partial=True))
        reg.notices = list(collector.notices)
        _report(reg)
        if strict:
            reg.raise_if_failed()
        return reg

    def raise_if_failed(self) -> None:
        """Strict mode: one ClodsError naming every plugin failure, if there is any."""
        if self.failures:
            lines = "; ".join(f.line for f in self.failures)
            raise ClodsError(f"{len(self.failures)} plugin problem(s) in strict mode: {lines}", where="plugins",
                             hint=f"strict because of --strict-plugins or {STRICT_ENV}=1")  # fmt: skip

    def _add(self, kind: str, item: Any, source: PluginSource, withheld: dict[tuple[str, str], list[PluginSource]]) -> None:
        """Index one item; a name provided twice goes to a built-in over an installed plugin, else to neither."""
        key, table = (kind, item.name), self._table(kind)
        if key in withheld:
            withheld[key].append(source)
            return
        if item.name not in table:
            table[item.name] = item
            self.origins[key] = source.name
            return
        owner = self.sources[self.origins[key]]
        if source.in_code:
            raise ClodsError(f"{kind} '{item.name}' is provided twice: by {self.origins[key]} and by {source.name}", where="plugins")
        if owner.builtin and not source.builtin:
            self.failures.append(PluginFailure(source, f"its {kind} '{item.name}' is not used: {owner.describe()} provides "
                                                       "one of that name", (key,), partial=True))  # fmt: skip
            return
        del table[item.name], self.origins[key]
        withheld[key] = [owner, source]

    def get(self, kind: str, name: str) -> Any:
        """The plugin of `kind` called `name`; else a ClodsError naming the failed plugin that would provide it, or the
        closest known name."""
        table = self._table(kind)
        if name in table:
            return table[name]
        named = [f for f in self.failures if (kind, name) in f.names]
        if named:
            raise ClodsError(f"{kind} '{name}' is not available: " + "; ".join(f.line for f in named))
        err = unknown_name(kind, name, list(table))
        unnamed = [f for f in self.failures if not f.names and not f.partial]
        if unnamed:
            err = ClodsError(f"{err.what}; a plugin that failed to load may provide it: " + "; ".join(f.line for f in unnamed),
                             hint=err.hint)  # fmt: skip
        raise err

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


def _plugin_items(pm: pluggy.PluginManager, plugin: Any, provided: list[tuple[str, str]]) -> list[tuple[str, Any]]:
    """Every (kind, item) one plugin's hooks return, checked (`plugin_checks`); `provided` collects the names seen."""
    out: list[tuple[str, Any]] = []
    for kind, hook in HOOKS.items():
        for impl in getattr(pm.hook, hook).get_hookimpls():
            if impl.plugin is plugin:
                result = impl.function()
                listed = result if isinstance(result, (list, tuple)) else ()
                provided.extend((kind, i.name) for i in listed if isinstance(getattr(i, "name", None), str))
                out.extend((kind, item) for item in check_hook_result(kind, hook, result))
    return out


def _report(reg: Registry) -> None:
    """Warn once per failure and deprecation, from the main process only (spawned workers load the same plugins)."""
    if multiprocessing.parent_process() is not None:
        return
    for failure in reg.failures:
        warnings.warn(failure.line + ("" if failure.partial else "; clods-bench runs without it"), PluginLoadWarning, stacklevel=3)
    for notice in reg.notices:
        warnings.warn(notice.line, PluginAPIDeprecationWarning, stacklevel=3)


_DEFAULT: Registry | None = None


def default_registry(refresh: bool = False, strict: bool | None = None) -> Registry:
    """The registry of the installed plugins (entry points), built once per process; strict: None reads STRICT_ENV."""
    global _DEFAULT
    strict = strict_from_env() if strict is None else strict
    if _DEFAULT is None or refresh:
        _DEFAULT = Registry.from_plugin_manager(make_plugin_manager())
    if strict:
        _DEFAULT.raise_if_failed()
    return _DEFAULT
