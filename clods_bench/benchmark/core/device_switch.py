"""The run's one device switch (`--device`, a preset's `device:`): written into the options of every plugin and task
stage of the run that can use it, before anything runs.

A run's device reaches each option section it names (`device_slots`: its simulator's, renderer's and video
predictor's `*_config.<name>`, and the task's `TaskSpec.device_options`, e.g. stage 0's `task_config.clods.stage0`):
a section whose dataclass has a `device` field gets the device, one whose `backend` has a 'gsplat' choice gets
'gsplat'. A field the user set stays as set, and a CPU backend or device set by hand keeps that section on the CPU. A
plugin whose `PluginSpec.devices` leaves the device's kind out keeps running on the CPU. Written into the options,
the device is part of what names the run's record; the run's own `device` field is not (records on the CPU keep
their names and digests).
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from typing import Any, Iterable

from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.registry import Registry
from clods_bench.benchmark.core.resolve import PLUGIN_KINDS
from clods_bench.devices import device_kind, resolve_device
from clods_bench.errors import ClodsError


@dataclass(frozen=True)
class DeviceSlot:
    """One option section of a run that the run's device may reach."""

    section: str
    """Its dotted path in the run config: 'renderer_config.smgs', 'task_config.clods.stage0'."""
    what: str
    """How messages name it: "renderer 'smgs'", 'stage options task_config.clods.stage0'."""
    config_cls: type
    """The dataclass its options load into."""
    devices: tuple[str, ...] | None = None
    """The device kinds it runs on (`PluginSpec.devices`); None: decided by its options."""


def device_slots(cfg: RunConfig, registry: Registry) -> list[DeviceSlot]:
    """The option sections of the plugins `cfg` names and of its task's `device_options`; unknown names are skipped
    (resolving the config names them)."""
    slots = []
    for kind in PLUGIN_KINDS:
        name = getattr(cfg, kind.field)
        if name and name in registry.names(kind.kind):
            spec = registry.get(kind.kind, name)
            slots.append(DeviceSlot(f"{kind.section}.{name}", f"{kind.what.split(' ', 1)[1]} '{name}'", spec.config_cls, getattr(spec, "devices", None)))
    declare = getattr(registry.get("task", cfg.task), "device_options", None) if cfg.task in registry.names("task") else None
    for path, cls in (declare(cfg) if declare is not None else {}).items():
        slots.append(DeviceSlot(f"task_config.{path}", f"task_config.{path}", cls))
    return slots


def apply_device(cfg: RunConfig, registry: Registry) -> RunConfig:
    """`cfg` with 'auto' decided here and its device written into each slot's options that can take it (fields the
    user set win); a device set by hand that a plugin refuses fails here. Idempotent; the CPU changes nothing."""
    device = resolve_device(cfg.device, "device", check=False)
    slots = device_slots(cfg, registry)
    for slot in slots:
        _check_refusal(slot, section_options(cfg, slot.section))
    if device == "cpu":
        return cfg if cfg.device == "cpu" else dataclasses.replace(cfg, device="cpu")
    for slot in slots:
        options = section_options(cfg, slot.section)
        switched = _switched(slot, options, device)
        if switched != options:
            cfg = _with_section(cfg, slot.section, switched)
    return cfg if cfg.device == device else dataclasses.replace(cfg, device=device)


def device_use(cfg: RunConfig, registry: Registry) -> tuple[list[str], list[str]]:
    """For a resolved `cfg`: the slots that run on its device ("renderer 'smgs' (backend gsplat)"), and those that
    stay on the CPU, each with why ("simulator 'physics': it has no device option")."""
    on_device: list[str] = []
    on_cpu: list[str] = []
    if cfg.device == "cpu":
        return on_device, on_cpu
    for slot in device_slots(cfg, registry):
        has_device, gsplat = option_fields(slot.config_cls)
        options = {**_defaults(slot.config_cls), **section_options(cfg, slot.section)}
        if slot.devices is not None and device_kind(cfg.device) not in slot.devices:
            on_cpu.append(f"{slot.what}: it runs on {', '.join(slot.devices)} only (its PluginSpec.devices)")
        elif not has_device and not gsplat:
            on_cpu.append(f"{slot.what}: it has no device option")
        elif gsplat and options.get("backend") == "gsplat":
            where = "" if has_device or cfg.device == "cuda" else ", the current CUDA device (CUDA_VISIBLE_DEVICES chooses it)"
            on_device.append(f"{slot.what} (backend gsplat{where})")  # without a device option: gsplat's own choice
        elif has_device and options.get("device") != "cpu":
            on_device.append(slot.what)
        else:  # options set by hand keep it on the CPU
            kept = [f"{key}={options.get(key)}" for key, has in (("backend", gsplat), ("device", has_device)) if has]
            on_cpu.append(f"{slot.what}: {slot.section} has {', '.join(kept)}")
    return on_device, on_cpu


def device_report(configs: Iterable[RunConfig], registry: Registry, explicit: bool) -> list[str]:
    """The lines a command prints about the device of its resolved `configs`, each once: what runs on it, a note per
    plugin or stage that stays on the CPU, and a warning when CUDA was asked for by name (`explicit`, not 'auto')
    and nothing can use it."""
    used: dict[str, dict[str, None]] = {}  # device -> what runs there (an ordered set)
    stays: dict[str, dict[str, None]] = {}  # device -> what it does not reach, with why
    for cfg in configs:
        on_device, on_cpu = device_use(cfg, registry)
        if on_device:
            used.setdefault(cfg.device, {}).update(dict.fromkeys(on_device))
        if on_cpu:
            stays.setdefault(cfg.device, {}).update(dict.fromkeys(on_cpu))
    lines = [f"device {device}: {', '.join(whats)}" for device, whats in used.items()]
    for device, whats in stays.items():
        if explicit and device not in used:
            lines.append(f"warning: device {device} asked for, but nothing in this run can use it; it runs on the CPU ({'; '.join(whats)})")
        else:
            lines.extend(f"note: device {device} does not reach {what}; it runs on the CPU" for what in whats)
    return lines


def option_fields(cls: type) -> tuple[bool, bool]:
    """(whether `cls` has a `device` option, whether it has a `backend` option with a 'gsplat' choice)."""
    if not dataclasses.is_dataclass(cls):
        return False, False
    names = {f.name for f in dataclasses.fields(cls)}
    gsplat = False
    if "backend" in names:
        try:
            gsplat = "gsplat" in typing.get_args(typing.get_type_hints(cls).get("backend"))
        except (NameError, TypeError):  # an annotation that does not resolve: no gsplat choice known
            gsplat = False
    return "device" in names, gsplat


def section_options(cfg: RunConfig, section: str) -> dict[str, Any]:
    """The options at a dotted `section` of `cfg` ('renderer_config.smgs'), as given (empty when absent)."""
    node: Any = getattr(cfg, section.split(".", 1)[0])
    for part in section.split(".")[1:]:
        node = node.get(part, {}) if isinstance(node, dict) else {}
    return dict(node) if isinstance(node, dict) else {}


def _switched(slot: DeviceSlot, options: dict[str, Any], device: str) -> dict[str, Any]:
    """`options` with `device` (and backend 'gsplat') filled in where the slot can take them and the user left them."""
    if slot.devices is not None and device_kind(device) not in slot.devices:
        return options
    has_device, gsplat = option_fields(slot.config_cls)
    out = dict(options)
    if gsplat:
        if out.get("backend", "gsplat") != "gsplat" or (has_device and out.get("device") == "cpu"):
            return options  # a CPU backend or device set by hand keeps the section on the CPU
        out.setdefault("backend", "gsplat")
    if has_device:
        out.setdefault("device", device)
    return out


def _check_refusal(slot: DeviceSlot, options: dict[str, Any]) -> None:
    """A device set by hand on a plugin whose `PluginSpec.devices` leaves its kind out: one ClodsError naming both."""
    given = options.get("device")
    if slot.devices is not None and isinstance(given, str) and device_kind(given) not in slot.devices:
        raise ClodsError(f"{slot.what} runs on {', '.join(slot.devices)} only (its PluginSpec.devices), not on {given}",
                         where=f"{slot.section}.device", hint="leave the option out, or set a device it runs on")  # fmt: skip


def _with_section(cfg: RunConfig, section: str, options: dict[str, Any]) -> RunConfig:
    """`cfg` with the dotted `section` replaced by `options` (the mappings along the path copied, never changed)."""
    top, *path = section.split(".")

    def put(node: Any, parts: list[str]) -> dict[str, Any]:
        node = dict(node) if isinstance(node, dict) else {}
        node[parts[0]] = options if len(parts) == 1 else put(node.get(parts[0]), parts[1:])
        return node

    return dataclasses.replace(cfg, **{top: put(getattr(cfg, top), path)})


def _defaults(cls: type) -> dict[str, Any]:
    """The default values of a config dataclass's fields that have a plain default."""
    if not dataclasses.is_dataclass(cls):
        return {}
    return {f.name: f.default for f in dataclasses.fields(cls) if f.default is not dataclasses.MISSING}
