"""What the command groups share: the consoles, the config options and loading, the plugin registry."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Sequence

from rich.console import Console

console = Console()
err_console = Console(stderr=True, soft_wrap=True)


def add_config_args(p: argparse.ArgumentParser) -> None:
    """The options that make a run config: preset, config file, --set overrides, scene, progress bars."""
    p.add_argument("--preset", default="ci", help="built-in preset: ci, small, paper (default: ci)")
    p.add_argument("--config", type=Path, help="YAML file merged over the preset (may name `preset:`)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="override a config field, e.g. data.num_train=8")
    p.add_argument("--scene", help="scene name (same as --set data.scene=NAME)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


def plugin_registry() -> Any:
    """The installed plugins' registry (loaded once per process)."""
    from clods_bench.benchmark.core.registry import default_registry

    return default_registry()


def run_config(args: argparse.Namespace, **fields: Any) -> Any:
    """The RunConfig the command's options make: preset, config file, `fields` (command options), then --set overrides."""
    from clods_bench.benchmark.core.config import load_config

    overrides = list(args.overrides)
    if getattr(args, "scene", None):
        overrides.insert(0, f"data.scene={args.scene}")
    if getattr(args, "no_progress", False):
        overrides.append("progress=false")
    return load_config(args.preset, args.config, overrides, **fields)



DEVICE_HELP = ("where the run computes: cpu, cuda, cuda:N, or auto (a CUDA GPU when torch sees one); written into every "
               "plugin and stage that can use it (their device option, and backend gsplat for the splatting renderers and "
               "stage 0), except options set with --set; default: the preset's device (cpu)")  # fmt: skip


def add_device_arg(p: argparse.ArgumentParser) -> None:
    """The `--device` option of the commands that run tasks."""
    p.add_argument("--device", help=DEVICE_HELP)


def report_device(requested: str, where: str, configs: Sequence[Any], registry: Any, executor: str = "local") -> None:
    """Before any work: a device that does not exist here is one ClodsError (not checked on Ray, whose workers hold
    the GPUs); then what runs on the device and a note for each plugin or stage it does not reach (`device_switch`)."""
    if requested == "cpu":
        return
    from clods_bench.benchmark.core.device_switch import device_report
    from clods_bench.benchmark.core.resolve import resolve_plugins
    from clods_bench.devices import resolve_device

    resolve_device(requested, where, check=executor != "ray")
    resolved = [resolve_plugins(cfg, registry) for cfg in configs]
    for line in device_report(resolved, registry, explicit=requested != "auto"):
        err_console.print(line, highlight=False, markup=False)
