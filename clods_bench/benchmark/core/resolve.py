"""What a run config names, checked against the registry in one step, with the options of its plugins filled in.

The plugins a run may name are one table (`PLUGIN_KINDS`): the config field that names the plugin, the section of
options per plugin name, the registry kind and the command-line option. `resolve_plugins` looks up the task, the
scene, the task's extra datasets and every plugin named, loads each plugin's options into its config class once (an
unknown key or a wrong type fails there, naming the section), and returns the config with those options complete.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.registry import Registry
from clods_bench.benchmark.core.run_checks import check_run
from clods_bench.errors import ClodsError


@dataclass(frozen=True)
class PluginKind:
    """One kind of plugin a run names: where the config names it and holds its options, and its registry kind."""

    field: str
    """The RunConfig field naming the plugin (also the name a TaskSpec's `needs` uses)."""
    section: str
    """The RunConfig section of options per plugin name."""
    kind: str
    """The registry kind."""
    option: str
    """The command-line option naming it."""
    what: str
    """'a simulator', ...: for messages."""


PLUGIN_KINDS: tuple[PluginKind, ...] = (
    PluginKind("sim", "sim_config", "simulator", "--sim", "a simulator"),
    PluginKind("renderer", "renderer_config", "renderer", "--renderer", "a renderer"),
    PluginKind("predictor", "video_config", "video_predictor", "--predictor", "a video predictor"),
)


def resolve_plugins(cfg: RunConfig, registry: Registry) -> RunConfig:
    """`cfg` checked (task, scene, seeds, every dataset it reads and the memory their largest arrays need, the plugins
    it needs and names, their options' values: `run_checks`, `PluginSpec.make_config`), its `device` written into the
    options that can take it (`device_switch`), and with the complete options of every plugin it names (its config
    dataclass, defaults filled in); fails before any work.

    What a run saves (config.yaml) and what names its record directory then includes the plugins' defaults: a changed
    default gives a new record instead of silently reusing one made with the old value. Idempotent; plugins the run
    does not name keep their mappings as they are. A plugin named by a task that does not need it (dvc takes --sim
    --renderer or --predictor) is checked all the same; an unknown name fails naming its option (`sim`, ...).
    """
    task = registry.get("task", cfg.task)
    registry.get("scene", cfg.data.scene)
    extra = task_datasets(cfg, registry)  # e.g. CDG's eval_data: its fields and scene
    check_run(cfg, registry, [(cfg.data, "data"), *((d, f"task_config.{cfg.task} (its dataset of scene {d.scene}): data") for d in extra)])
    from clods_bench.benchmark.core.device_switch import apply_device  # (it reads PLUGIN_KINDS from here)

    cfg = apply_device(cfg, registry)  # the run's device into the options of its plugins and stages
    changes: dict[str, dict[str, dict[str, Any]]] = {}
    for kind in PLUGIN_KINDS:
        name = getattr(cfg, kind.field)
        if not name:
            if kind.field in task.needs:
                raise ClodsError(f"task '{cfg.task}' needs {kind.what}", where=kind.option, hint=f"one of {registry.names(kind.kind)}")
            continue
        spec = _named_plugin(registry, kind.kind, name, kind.field)
        mapping = dict(getattr(cfg, kind.section))
        options = spec.make_config(mapping.get(name, {}), where=f"{kind.section}.{name}")
        mapping[name] = _plain(dataclasses.asdict(options))
        changes[kind.section] = mapping
    return dataclasses.replace(cfg, **changes) if changes else cfg


def task_datasets(cfg: RunConfig, registry: Registry) -> list[Any]:
    """The DataConfigs the run's task reads besides `cfg.data` (its TaskSpec's `datasets`; none for most tasks)."""
    extra = getattr(registry.get("task", cfg.task), "datasets", None)
    return list(extra(cfg, registry)) if extra is not None else []


def _named_plugin(registry: Registry, kind: str, name: str, option: str) -> Any:
    """`registry.get(kind, name)`, its unknown-name error naming the run option that gave the name."""
    try:
        return registry.get(kind, name)
    except ClodsError as exc:
        raise ClodsError(exc.what, where=option, hint=exc.hint) from None


def _plain(value: Any) -> Any:
    """Tuples to lists, recursively: what YAML and JSON give back, so a resolved config reloads to itself."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
