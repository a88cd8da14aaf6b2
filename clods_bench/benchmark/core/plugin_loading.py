"""Loading plugins one entry point at a time: a plugin that fails is named, with its distribution, version and entry
point, and left out; the others load.

Each entry point is imported, checked against the plugin API version it declares (`CLODS_BENCH_API`) and registered
on its own, with the warnings it raises collected: a `PluginAPIDeprecationWarning` becomes a notice naming the
plugin, any other warning is passed on unchanged. The built-in plugins (the clods-bench distribution's own entry
points) load first, then the others in the order of their distribution names.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib.metadata
import re
import traceback
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable

import pluggy

from clods_bench.api_version import DECLARATION, PluginAPIDeprecationWarning, api_version_problem
from clods_bench.benchmark.core.hookspecs import ENTRY_POINT_GROUP, PROJECT
from clods_bench.errors import ClodsError

DISTRIBUTION = "clods-bench"


def _normalized(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


@dataclass(frozen=True)
class PluginSource:
    """Where a plugin comes from: an entry point of an installed distribution, or code that registered it."""

    name: str
    """The plugin's name in the plugin manager: its entry point's name (`DIST:NAME` when another plugin has that
    name already), or pluggy's for a plugin given in code."""
    distribution: str = ""
    """The distribution that declares the entry point ("" for a plugin given in code)."""
    version: str = ""
    value: str = ""
    """The entry point's target, `module` or `module:attribute`."""
    entry_point: str = ""
    """The entry point's name ("" for a plugin given in code)."""

    @property
    def in_code(self) -> bool:
        return not self.distribution

    @property
    def builtin(self) -> bool:
        return _normalized(self.distribution) == DISTRIBUTION

    def describe(self) -> str:
        """'plugin DIST VERSION (entry point NAME = VALUE)', the way every message names the plugin."""
        if self.in_code:
            return f"plugin {self.name} (registered in code)"
        return f"plugin {self.distribution} {self.version} (entry point {self.entry_point} = {self.value})"


@dataclass(frozen=True)
class PluginFailure:
    """A plugin (or one name of it) left out: why, in one line, and the (kind, name)s it would have provided, if known."""

    source: PluginSource
    error: str
    names: tuple[tuple[str, str], ...] = ()
    partial: bool = False
    """True: the plugin loaded and only `names` are left out (a name two plugins provide)."""
    detail: str = field(default="", repr=False, compare=False)
    """The traceback, for `clods-bench --debug list`."""

    @classmethod
    def from_exception(cls, source: PluginSource, exc: BaseException, names: tuple[tuple[str, str], ...] = ()) -> "PluginFailure":
        return cls(source, error_line(exc), names, detail="".join(traceback.format_exception(exc)))

    @property
    def line(self) -> str:
        return f"{self.source.describe()}: {self.error}" if self.partial else f"{self.source.describe()} failed to load: {self.error}"


@dataclass(frozen=True)
class PluginNotice:
    """A deprecated form a plugin uses: still working, removed in a named release; `message` says what to write."""

    source: PluginSource
    message: str
    location: str

    @property
    def line(self) -> str:
        return f"{self.source.describe()} uses a deprecated form ({self.location}): {self.message}"


class ClodsPluginManager(pluggy.PluginManager):
    """A pluggy manager that remembers where each plugin comes from, which failed and which use deprecated forms."""

    def __init__(self) -> None:
        super().__init__(PROJECT)
        self.sources: dict[str, PluginSource] = {}
        self.failures: list[PluginFailure] = []
        self.notices: list[PluginNotice] = []


def error_line(exc: BaseException) -> str:
    """The line an exception is reported by: the traceback's last line ('Type: message'; a ClodsError's own message),
    cut to the message's first line when it has several."""
    text = exc.message if isinstance(exc, ClodsError) else str(exc)
    first = next((line.strip() for line in text.splitlines() if line.strip()), "")
    if isinstance(exc, ClodsError):
        return first
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def call_guarded(pm: ClodsPluginManager, source: PluginSource, fn: Callable[[], Any]) -> tuple[bool, Any, BaseException | None]:
    """`fn()` on behalf of a plugin: (True, result, None) or (False, None, the exception); its deprecations become notices."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            ok, result, error = True, fn(), None
        except (Exception, SystemExit) as exc:  # a plugin's own failure, whatever it is: reported, never fatal to the others
            ok, result, error = False, None, exc
    for w in caught:
        if issubclass(w.category, PluginAPIDeprecationWarning):
            notice = PluginNotice(source, str(w.message), f"{w.filename}:{w.lineno}")
            if notice not in pm.notices:
                pm.notices.append(notice)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return ok, result, error


def register_plugin(pm: ClodsPluginManager, plugin: Any, source: PluginSource) -> None:
    """Register one plugin after checking its declared API version; an unknown hook name is an error naming it."""
    declared = getattr(plugin, DECLARATION, None)
    problem = None if declared is None else api_version_problem(declared)
    if problem:
        raise ClodsError(problem)
    pm.register(plugin, name=source.name)
    unknown = sorted(hc.name for hc in pm.get_hookcallers(plugin) or () if not hc.has_spec())
    if unknown:
        pm.unregister(plugin)
        known = [name for name in dir(pm.hook) if name.startswith(f"{PROJECT}_")]
        best = difflib.get_close_matches(unknown[0], known, n=1, cutoff=0.5)
        raise ClodsError(f"plugin defines an unknown hook '{unknown[0]}'" + (f" (did you mean '{best[0]}'?)" if best else ""))
    pm.sources[source.name] = source


def _source(ep: importlib.metadata.EntryPoint) -> PluginSource:
    dist = getattr(ep, "dist", None)
    name = dist.metadata["Name"] if dist is not None else "unknown-distribution"
    return PluginSource(ep.name, name or "unknown-distribution", dist.version if dist is not None else "?", ep.value, ep.name)


_IMPORT_NOTICES: dict[PluginSource, list[PluginNotice]] = {}
"""The deprecation notices each entry point's import raised, for registries built again in the same process."""


def installed_entry_points(group: str = ENTRY_POINT_GROUP) -> list[importlib.metadata.EntryPoint]:
    """The entry points of `group` that the installed distributions declare: the one place plugins are discovered.

    Looked up by name at each load, so a test can replace it (say, to see only clods-bench's own entry points and
    those of the plugins it installs, whatever else is installed); users never need to.
    """
    return list(importlib.metadata.entry_points(group=group))


def load_entry_points(pm: ClodsPluginManager, group: str = ENTRY_POINT_GROUP) -> None:
    """Load every entry point of `group` on its own; each one that fails is recorded in `pm.failures` and skipped."""
    sources = sorted(((_source(ep), ep) for ep in installed_entry_points(group)),
                     key=lambda s: (not s[0].builtin, _normalized(s[0].distribution), s[0].name))  # fmt: skip
    for source, ep in sources:
        if pm.has_plugin(source.name):  # two packages' entry points of one name (say, "plugin"): both load
            source = dataclasses.replace(source, name=f"{source.distribution}:{source.name}")
        before = len(pm.notices)
        ok, _, error = call_guarded(pm, source, lambda: register_plugin(pm, ep.load(), source))
        if len(pm.notices) > before:  # raised by the import: a second load in this process finds the module imported
            _IMPORT_NOTICES[source] = pm.notices[before:]
        else:
            pm.notices.extend(_IMPORT_NOTICES.get(source, ()))
        if not ok:
            if pm.has_plugin(source.name):
                pm.unregister(name=source.name)
            pm.failures.append(PluginFailure.from_exception(source, error))

