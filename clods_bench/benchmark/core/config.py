"""Run configuration: YAML presets mapped to typed dataclasses, with `--set key=value` overrides.

YAML is data only (safe_load). A preset file may carry a one-line `description`; a user
config file may name its base with `preset: NAME`. Unknown keys and wrong types fail
loudly with the file and the dotted field name.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import yaml

from clods_bench.datasets.data_config import DataConfig, resolve_dataset_path
from clods_bench.errors import ClodsError, unknown_name
from clods_bench.typed_config import dataclass_from_dict

CONFIG_VERSION = 1


@dataclass
class RunConfig:
    """One benchmark run: a task, its plugins, the data, seeds and where records go."""

    version: int = CONFIG_VERSION
    """Config schema version."""
    preset: str = "ci"
    """Preset this config was built from."""
    task: str = "cdg"
    """Task name (a task plugin): cdg, ..."""
    sim: str | None = None
    """Simulator plugin name (tasks that need one)."""
    renderer: str | None = None
    """Renderer plugin name (tasks that need one)."""
    predictor: str | None = None
    """Video-predictor plugin name (the dvc task's pixel-space baselines: copylast, simvp, tau, mau, mmvp)."""
    label: str | None = None
    """Row label in tables (default: the simulator/renderer name, with '*' for the first-half subset)."""
    train_subset: Literal["all", "first_half"] = "all"
    """Training trajectories for mesh-supervised simulators: all (MGN) or the first half (MGN*)."""
    seeds: list[int] = field(default_factory=lambda: [0, 1])
    """Seeds of independent repetitions (training initialisation, noise); tables report mean +- std over them."""
    data: DataConfig = field(default_factory=DataConfig)
    """Data settings."""
    sim_config: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Options per simulator name, loaded into that plugin's config dataclass."""
    renderer_config: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Options per renderer name, loaded into that plugin's config dataclass."""
    video_config: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Options per video-predictor name, loaded into that plugin's config dataclass."""
    task_config: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Options per task name, loaded by that task into its config dataclass (e.g. nvs.frame_stride)."""
    runs_dir: str = "runs"
    """Directory of run records."""
    progress: bool = True
    """Show progress bars."""
    device: str = "cpu"
    """Where the run computes: cpu, cuda, cuda:N, or auto (a CUDA GPU when torch sees one, else the CPU); `--device`.
    It is written into the options of every plugin and stage of the run that can use it (`device`, and backend
    'gsplat' for the splatting renderers and stage 0), except fields set by hand (`benchmark/core/device_switch.py`).
    Not part of the record's identity: the plugins' options it reaches are."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# ---------------------------------------------------------------- loading


def preset_names() -> list[str]:
    """Names of the built-in presets (YAML files shipped in clods_bench/benchmark/core/presets)."""
    folder = resources.files("clods_bench.benchmark.core") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def preset_path(name: str) -> Path:
    """The YAML file of a built-in preset; unknown names get a did-you-mean error."""
    if name not in preset_names():
        raise unknown_name("preset", name, preset_names())
    return Path(str(resources.files("clods_bench.benchmark.core") / "presets" / f"{name}.yaml"))


def read_yaml(path: Path) -> dict[str, Any]:
    """Parse a YAML mapping, with a clear error for a missing or malformed file."""
    if not path.is_file():
        raise ClodsError("config file not found", where=str(path))
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        pos = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ClodsError(f"malformed YAML{pos}: {getattr(exc, 'problem', exc)}", where=str(path)) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ClodsError(f"expected a mapping at the top level, got {type(data).__name__}", where=str(path))
    return data


def preset_description(name: str) -> str:
    return str(read_yaml(preset_path(name)).get("description", ""))


def load_config(
    preset: str = "ci",
    config_file: str | Path | None = None,
    overrides: list[str] | tuple[str, ...] = (),
    **fields: Any,
) -> RunConfig:
    """Preset YAML, then a user YAML file, then `fields` (CLI options), then `--set` overrides."""
    merged: dict[str, Any] = {}
    sources: list[str] = []
    user: dict[str, Any] = {}
    if config_file is not None:
        user = read_yaml(Path(config_file))
        preset = user.pop("preset", preset)
    base = read_yaml(preset_path(preset))
    base.pop("description", None)
    _deep_merge(merged, base)
    sources.append(str(preset_path(preset)))
    if user:
        _deep_merge(merged, user)
        sources.append(str(config_file))
    merged["preset"] = preset
    _deep_merge(merged, {k: v for k, v in fields.items() if v is not None})
    for item in overrides:
        key, value = parse_override(item)
        _set_dotted(merged, key, value)
    cfg = dataclass_from_dict(RunConfig, merged, where=" + ".join(sources) + (" + --set" if overrides else ""))
    if not cfg.seeds:  # refused before any work: an empty run would record no seed
        raise ClodsError("is empty: a run needs at least one seed", where="seeds", hint="e.g. --set seeds=[0]")
    cfg.data = resolve_dataset_path(cfg.data)
    return cfg


def parse_override(item: str) -> tuple[str, Any]:
    """'data.num_train=8' -> ('data.num_train', 8); the value is parsed as YAML."""
    if "=" not in item:
        raise ClodsError(f"override '{item}' is not of the form key=value", where="--set")
    key, raw = item.split("=", 1)
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    return key.strip(), value


def save_config(cfg: RunConfig, path: Path) -> None:
    """Write the resolved config as YAML (atomically)."""
    from clods_bench.atomic import write_text

    write_text(path, yaml.safe_dump(cfg.to_dict(), sort_keys=False))


def _deep_merge(dst: dict[str, Any], src: dict[str, Any]) -> None:
    for k, v in src.items():
        if isinstance(v, dict) and isinstance(dst.get(k), dict):
            _deep_merge(dst[k], v)
        else:
            dst[k] = v


def _set_dotted(d: dict[str, Any], key: str, value: Any) -> None:
    parts = key.split(".")
    for p in parts[:-1]:
        d = d.setdefault(p, {})
        if not isinstance(d, dict):
            raise ClodsError(f"'{p}' is not a section, cannot set '{key}'", where="--set")
    d[parts[-1]] = value


