"""What the command groups share: the consoles, the config options and loading, the plugin registry."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

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

