"""Which data a run uses (`DataConfig`, the `data` section of a run config) and the identity that names its dataset.

Every field but `root` decides the dataset directory (`root/<scene>-<hash>`), so runs with equal data settings share
one dataset, and a generator change (`DATA_GENERATOR_VERSION`) never reuses an old one. An existing dataset
(`path`, e.g. an imported capture) supplies its own split sizes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clods_bench.datasets.textures import texture_file_digest
from clods_bench.errors import ClodsError, closest
from clods_bench.typed_config import coerce

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
        changes[key] = coerce(hints[key], value, f"{where}.{key}", str(key))
    changes.setdefault("path", None)
    try:
        return resolve_dataset_path(dataclasses.replace(d, **changes))
    except ClodsError as exc:
        raise ClodsError(exc.what if exc.where is None else f"{exc.where}: {exc.what}", where=f"{where}.path", hint=exc.hint) from None
