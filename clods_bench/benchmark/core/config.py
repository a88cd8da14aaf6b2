"""Run configuration: YAML presets mapped to typed dataclasses, with `--set key=value` overrides.

YAML is data only (safe_load). A preset file may carry a one-line `description`; a user
config file may name its base with `preset: NAME`. Unknown keys and wrong types fail
loudly with the file and the dotted field name.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import types
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import yaml

from clods_bench.datasets.textures import texture_file_digest
from clods_bench.errors import ClodsError, closest, unknown_name

CONFIG_VERSION = 1
DATA_GENERATOR_VERSION = 2
"""Bumped whenever the built-in data generation changes what a DataConfig produces (scenes, solver,
renderer): it is part of the dataset identity, so an old dataset is never mistaken for a new one.
2: one mean wind for all flag trajectories, no wind ramp, 1 s warm-up before frame 0."""


@dataclass
class DataConfig:
    """Which data a run uses. Every field but `root` decides the dataset directory."""

    scene: str = "flag"
    """Scene name (a scene plugin): flag, flag-stiff, flag-storm, flag-large-dt, cylinder, or a plugin's own cloth."""
    resolution: list[int] | str = field(default_factory=lambda: [16, 8])
    """Mesh resolution: [nx, ny] nodes for flags ([around, along] for the cylinder) or 'flagsimple' (1579 nodes); a mesh cloth ignores it."""
    num_train: int = 4
    """Training trajectories (paper: 100). The second half is the 'viewed' test group."""
    num_test: int = 2
    """Test trajectories, the 'unviewed' group (paper: 20)."""
    num_steps: int = 41
    """Frames per trajectory including frame 0 (paper / FLAGSIMPLE: 401, t = 0..400)."""
    interp_steps: int = 30
    """Last interpolation frame; frames after it are extrapolation (paper: 300)."""
    num_cameras: int = 6
    """Cameras in the rig; the last `num_views_test` are held out for novel-view synthesis."""
    num_views_test: int = 2
    """Held-out cameras (never used for fitting)."""
    image_size: int = 64
    """Square image side in pixels (paper: 800)."""
    fov_deg: float = 30.0
    """Horizontal field of view of every camera, degrees."""
    camera_radius: float = 4.0
    """Distance of the cameras from the cloth's rest centre, metres."""
    supersample: int = 2
    """Anti-aliasing factor of the ground-truth rasterizer."""
    texture: str = "procedural"
    """A named texture (procedural: multi-scale pattern; stripes: coarse stripes; weave: low-contrast weave) or an
    image file: `file:PATH` or a path ending in .png/.jpg/.jpeg (its content's sha256 joins the dataset identity)."""
    render_frames: bool = True
    """Render multi-view frames (tasks on meshes alone can switch this off)."""
    frames: str = "stored"
    """'stored': frames rendered at generation and kept compressed on disk; 'on_demand': only the meshes and a render
    setup are kept, and the frames a task reads are rendered then (byte-identical; for sizes whose frames do not fit
    on disk, e.g. the paper preset's 3.5 GB per trajectory)."""
    seed: int = 0
    """Base seed: trajectory i is simulated with seed + i."""
    root: str = "data"
    """Directory under which datasets are stored (not part of the dataset identity)."""
    path: str | None = None
    """An existing dataset directory to run on (e.g. made by `data import-video`) instead of the generated one the
    other fields name; nothing is generated, and its manifest supplies num_train, num_test, num_steps, interp_steps,
    num_cameras, num_views_test and image_size (see `resolve_dataset_path`)."""

    def identity(self) -> dict[str, Any]:
        """The fields that decide what data is generated (everything but `root`), and the generator version; `path`
        only when set (an existing dataset is named by where it is; generated ones keep their old identity); for an
        image-file texture, the sha256 of the file's bytes (editing the file gives a new dataset)."""
        d = dataclasses.asdict(self)
        d.pop("root")
        if d["frames"] == "stored":  # the default keeps the identities (and directories) of every earlier dataset
            d.pop("frames")
        if d["path"] is None:
            d.pop("path")
            digest = texture_file_digest(self.texture)  # None for named textures: their identities stay as before
            if digest is not None:
                d["texture_sha256"] = digest
        d["generator_version"] = DATA_GENERATOR_VERSION
        return d

    def dataset_dir(self) -> Path:
        """`path` when set, else `root/<scene>-<hash of identity>`: runs with equal data settings share one dataset."""
        if self.path:
            return Path(self.path)
        digest = hashlib.sha256(json.dumps(self.identity(), sort_keys=True).encode()).hexdigest()[:10]
        return Path(self.root) / f"{self.scene}-{digest}"


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
    cfg.data = resolve_dataset_path(cfg.data)
    return cfg


# The data fields an existing dataset (`data.path`) fixes: what its manifest records wins over the preset.
PATH_FIELDS = ("num_train", "num_test", "num_steps", "interp_steps", "num_cameras", "num_views_test", "image_size")


def resolve_dataset_path(d: DataConfig) -> DataConfig:
    """`d` with the sizes of the dataset at `d.path` (from its manifest) when `path` is set, else `d` unchanged.

    The tasks read the split sizes from the data config; for a dataset that was not generated from this config
    (an imported capture) they must come from the dataset itself. A generated dataset's manifest records every
    DataConfig field; an imported one records these sizes (see `datasets.video_import`).
    """
    if not d.path:
        return d
    from clods_bench.datasets.store import DatasetStore

    root = Path(d.path)
    if not (root / "manifest.json").is_file():
        raise ClodsError("no dataset here (manifest.json missing)", where=f"data.path={d.path}",
                         hint="import one with `clods-bench data import-video`, or generate one")  # fmt: skip
    stored = DatasetStore.open(root).config
    missing = [k for k in PATH_FIELDS if not isinstance(stored.get(k), int) or isinstance(stored.get(k), bool)]
    if missing:
        raise ClodsError(f"the dataset's manifest config lacks {missing}", where=str(root / "manifest.json"))
    return dataclasses.replace(d, path=str(root.resolve()), **{k: int(stored[k]) for k in PATH_FIELDS})


def data_with_overrides(d: DataConfig, overrides: Any, where: str) -> DataConfig:
    """`d` with the fields in `overrides` replaced, typed like the data section: another dataset of the same run.

    `root` cannot be replaced (every dataset of a run lives under `data.root`); `path` applies only when named
    (otherwise the result is the generated dataset the other fields name), and then supplies the split sizes.
    Errors name `<where>.<field>`.
    """
    if not isinstance(overrides, dict):
        raise ClodsError(f"must be a mapping of data options (e.g. {{scene: cylinder}}), got {type(overrides).__name__}", where=where)
    hints = typing.get_type_hints(DataConfig)
    names = [f.name for f in dataclasses.fields(DataConfig) if f.name != "root"]
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        if key == "root":
            raise ClodsError("the data root cannot differ: every dataset of a run is stored under data.root", where=f"{where}.root")
        if key not in names:
            best = closest(str(key), names)
            raise ClodsError(f"'{key}' is not a data option", where=f"{where}.{key}",
                             hint=f"did you mean '{best}'?" if best else f"data options: {', '.join(names)}")  # fmt: skip
        changes[key] = _coerce(hints[key], value, f"{where}.{key}", str(key))
    changes.setdefault("path", None)
    try:
        return resolve_dataset_path(dataclasses.replace(d, **changes))
    except ClodsError as exc:
        raise ClodsError(exc.what if exc.where is None else f"{exc.where}: {exc.what}", where=f"{where}.path", hint=exc.hint) from None


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


# ---------------------------------------------------------------- typed loading


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
            hint = f"did you mean '{prefix}{best}'?" if best else f"known: {', '.join(names)}"
            raise ClodsError(f"unknown config key '{dotted}'", where=where, hint=hint)
        kwargs[key] = _coerce(hints[key], value, where, dotted)
    return cls(**kwargs)


def _coerce(tp: Any, value: Any, where: str, dotted: str) -> Any:
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
                return _coerce(option, value, where, dotted)
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
        return [_coerce(args[0], v, where, f"{dotted}[{i}]") for i, v in enumerate(value)] if args else list(value)
    if origin is dict:
        if not isinstance(value, dict):
            raise _type_error(dotted, value, "a mapping", where)
        return {k: _coerce(args[1], v, where, f"{dotted}.{k}") for k, v in value.items()} if args else dict(value)
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
