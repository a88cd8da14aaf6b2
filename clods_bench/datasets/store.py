"""The on-disk dataset: a manifest plus one .npz (mesh trajectory) and one frame array per trajectory.

Layout of `root` (schema version 2):
- `manifest.json`: schema version, scene, the data config, cameras, texture, and one entry per
  *complete* trajectory (index, split, seed, file records with sha256 and byte size, array shapes); a mesh file
  (and the render setup) is checked against its sha256 when first read in a process, a frame array's `zarr.json`
  on open and each of its chunks by its own crc32c when decoded;
- `traj_0000.npz`: cells, mesh_pos, node_type, world_pos, dt and `meta` (a JSON string);
- `frames_0000.zarr/`: (T, N, H, W, 3) uint8 multi-view frames, chunked per camera and a few frames,
  compressed and checksummed per chunk (see `frame_store`), read lazily with `frames(index)`;
- `texture.png` (optional);
- `render_setup.npz` instead of frame arrays for a dataset generated with `data.frames=on_demand`: its frames are
  rendered from the meshes when read (`rendered_frames`), byte-identical to stored ones.
A dataset imported from video may have no meshes (manifest `"meshes": false`): its entries then hold frames,
`dt` and `meta` only, and `load_trajectory` refuses with one line saying so (`require_meshes`).
Files are written atomically before their manifest entry, so an interrupted generation leaves
no entry for a half-written trajectory and a later run resumes from `completed_indices()`. The
manifest is re-read and rewritten under a file lock, so parallel workers can each add their own
trajectory. Schema 1 stores (raw `frames_0000.npy`) are refused with a pointer to `clods-bench data convert`.
The manifest itself (reading, checking, file records) is in `store_manifest`.
"""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from clods_bench import integrity
from clods_bench.atomic import atomic_path, file_lock, write_json, write_npz
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.frame_store import FrameArray, LazyFrames, write_frames
from clods_bench.datasets.rasterizer import RasterSettings
from clods_bench.datasets.rendered_frames import RENDER_SETUP, RenderedFrames, read_render_setup, write_render_setup
from clods_bench.datasets.splits import SPLITS
from clods_bench.datasets.store_manifest import (
    MANIFEST,
    SCHEMA_VERSION,
    config_diff,
    digest_record,
    file_record,
    normalise,
    read_manifest,
    remove_stale_temp_files,
)
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError

MANIFEST_LOCK = ".manifest.lock"
TRAJ_FIELDS = ("cells", "mesh_pos", "node_type", "world_pos")
_DTYPES = {"cells": np.int32, "mesh_pos": np.float32, "node_type": np.int32, "world_pos": np.float32}
_LOAD_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, json.JSONDecodeError)
_FRAMES_COUNTED: dict[str, tuple[int, int, int]] = {}
"""Per process: frame-array folders whose byte total `check_files` found right, by the folder's inode and ctime."""


class DatasetStore:
    """One dataset directory: read trajectories and frames, or append them during generation."""

    def __init__(self, root: Path, manifest: dict[str, Any] | None = None) -> None:
        """Open the store at `root` (same as `DatasetStore.open`); `manifest` is for create()."""
        self.root = Path(root)
        self._manifest = manifest if manifest is not None else read_manifest(self.root)
        self._entries: dict[int, dict[str, Any]] = {int(e["index"]): e for e in self._manifest["trajectories"]}
        self._render_setup: tuple | None = None  # read once per store when frames are rendered on demand

    # ----------------------------------------------------------- create / open

    @classmethod
    def create(cls, root: Path, scene: str, config: dict[str, Any], cameras: list[Camera], force: bool = False,
               meshes: bool = True) -> "DatasetStore":  # fmt: skip
        """A new store at `root`, or the existing one (to resume) if it was made with the same config.

        `meshes=False`: a dataset of videos alone (trajectories written with `write_video_trajectory`)."""
        root = Path(root)
        manifest = {
            "schema_version": SCHEMA_VERSION,
            "scene": scene,
            "config": normalise(config),
            "cameras": normalise([c.to_dict() for c in cameras]),
            "texture": None,
            "trajectories": [],
        }
        if not meshes:  # only written when false: generated manifests stay as they were
            manifest["meshes"] = False
        if (root / MANIFEST).exists():
            try:
                store = cls.open(root)
            except ClodsError:
                if not force:
                    raise
                store = None  # unreadable manifest: --force starts over
            if store is not None:
                diff = config_diff(store._manifest, manifest)
                if not diff:
                    remove_stale_temp_files(root)
                    return store
                if not force:
                    raise ClodsError(
                        "dataset exists with a different config: " + "; ".join(diff),
                        where=str(root / MANIFEST),
                        hint="use a different dataset directory, or --force to regenerate it",
                    )
                store._delete_files()
        remove_stale_temp_files(root)
        write_json(root / MANIFEST, manifest)
        return cls(root, manifest)

    @classmethod
    def open(cls, root: Path) -> "DatasetStore":
        """Open an existing store; clear errors for a missing, malformed or foreign manifest."""
        return cls(Path(root))

    # ------------------------------------------------------------------ write

    def write_trajectory(self, index: int, split: str, seed: int, traj: Trajectory,
                         frames: np.ndarray | Iterable[np.ndarray] | None) -> None:  # fmt: skip
        """Write one trajectory's files atomically, then record its entry in the manifest.

        `frames`: (T, N, H, W, 3) uint8, or an iterable of the T time steps' (N, H, W, 3) images (streamed
        to disk a chunk at a time, so a large trajectory never has to be in memory whole).
        """
        if split not in SPLITS:
            raise ClodsError(f"unknown split '{split}', expected one of {SPLITS}", where=f"trajectory {index}")
        if index < 0:
            raise ClodsError(f"trajectory index must be >= 0, got {index}", where=f"trajectory {index}")
        traj.validate(where=f"trajectory {index}")
        arrays = {k: np.ascontiguousarray(getattr(traj, k), dtype=_DTYPES[k]) for k in TRAJ_FIELDS}
        if isinstance(frames, np.ndarray):
            self._check_frames(index, frames, traj.num_steps)
        if index in self._entries:  # drop the old entry first: its files are about to change
            self._update_manifest(lambda: self._entries.pop(index, None))
        traj_name = f"traj_{index:04d}.npz"
        write_npz(self.root / traj_name, dt=np.float64(traj.dt), meta=np.str_(json.dumps(normalise(traj.meta))), **arrays)
        files = {"traj": file_record(self.root / traj_name)}
        shapes = {k: list(v.shape) for k, v in arrays.items()}
        if frames is not None:
            shape = self._frames_shape(traj.num_steps)
            files["frames"] = write_frames(self.root / f"frames_{index:04d}.zarr", frames, shape)
            shapes["frames"] = list(shape)
        entry = {"index": index, "split": split, "seed": int(seed), "files": files, "shapes": shapes, "complete": True}
        self._update_manifest(lambda: self._entries.__setitem__(index, entry))

    def write_video_trajectory(self, index: int, split: str, seed: int, frames: np.ndarray | Iterable[np.ndarray],
                               num_steps: int, dt: float, meta: dict[str, Any] | None = None) -> None:  # fmt: skip
        """Write one trajectory of a dataset without meshes: its `num_steps` frames (as in `write_trajectory`), `dt`, `meta`."""
        if self.has_meshes:
            raise ClodsError("this dataset stores meshes: write trajectories with write_trajectory", where=str(self.root / MANIFEST))
        if split not in SPLITS:
            raise ClodsError(f"unknown split '{split}', expected one of {SPLITS}", where=f"trajectory {index}")
        if index < 0 or num_steps < 2 or not (np.isfinite(dt) and dt > 0):
            raise ClodsError(f"need index >= 0, num_steps >= 2 and dt > 0, got {index}, {num_steps}, {dt}", where=f"trajectory {index}")
        if isinstance(frames, np.ndarray):
            self._check_frames(index, frames, num_steps)
        if index in self._entries:
            self._update_manifest(lambda: self._entries.pop(index, None))
        shape = self._frames_shape(num_steps)
        files = {"frames": write_frames(self.root / f"frames_{index:04d}.zarr", frames, shape)}
        entry = {"index": index, "split": split, "seed": int(seed), "files": files, "shapes": {"frames": list(shape)},
                 "dt": float(dt), "meta": normalise(meta or {}), "complete": True}  # fmt: skip
        self._update_manifest(lambda: self._entries.__setitem__(index, entry))

    def write_texture(self, data: bytes, name: str = "texture.png") -> None:
        """Store the texture image file (already encoded bytes) and record it in the manifest."""
        with atomic_path(self.root / name) as tmp:
            tmp.write_bytes(data)
        record = {"name": name, **digest_record(self.root / name)}
        self._update_manifest(lambda: self._manifest.__setitem__("texture", record))

    # ------------------------------------------------------------------- read

    def load_trajectory(self, index: int, verify: bool = False) -> Trajectory:
        """The mesh trajectory `index`, checked against the manifest and validated (ClodsError naming the file)."""
        entry = self._entry(index)
        if "traj" not in entry["files"]:
            self.require_meshes(f"reading trajectory {index}'s mesh")
        path = self._checked_file(entry["files"]["traj"], verify)
        try:
            with np.load(path, allow_pickle=False) as npz:
                missing = [k for k in (*TRAJ_FIELDS, "dt", "meta") if k not in npz.files]
                if missing:
                    raise ClodsError(f"missing arrays {missing}", where=str(path))
                arrays = {k: npz[k] for k in TRAJ_FIELDS}
                dt = float(npz["dt"])
                meta = json.loads(str(npz["meta"]))
        except ClodsError:
            raise
        except _LOAD_ERRORS as exc:
            raise ClodsError(f"cannot read trajectory file: {type(exc).__name__}: {exc}", where=str(path)) from None
        for key, arr in arrays.items():
            expected = tuple(entry["shapes"][key])
            if arr.shape != expected:
                raise ClodsError(f"shape {arr.shape}, manifest says {expected}", where=f"{path}.{key}")
        traj = Trajectory(dt=dt, meta=meta, **arrays)
        traj.validate(where=str(path))
        return traj

    def frames(self, index: int) -> FrameArray:
        """Frames (T, N, H, W, 3) uint8 of trajectory `index`, read lazily: `frames(i)[t0:t1, views]` decodes only those
        chunks, or, for a dataset generated with `data.frames=on_demand`, renders only those views from the meshes."""
        entry = self._entry(index)
        if "frames" not in entry["files"] and self._manifest.get("render_setup"):
            return self._rendered_frames(index)
        if "frames" not in entry["files"]:
            raise ClodsError(f"trajectory {index} was stored without frames", where=str(self.root / MANIFEST),
                             hint="regenerate the dataset with render_frames on")
        record = entry["files"]["frames"]
        frames = LazyFrames(self.root / record["name"], record)
        expected = tuple(entry["shapes"]["frames"])
        if frames.shape != expected:
            raise ClodsError(f"frames {frames.shape}, manifest says {expected}", where=str(frames.path))
        return frames

    @property
    def frames_on_demand(self) -> bool:
        """True for a dataset generated with `data.frames=on_demand` (meshes and a render setup, no stored frames)."""
        return bool(self._manifest.get("render_setup"))

    def write_render_setup(self, uv: np.ndarray, texture: np.ndarray, settings: RasterSettings) -> None:
        """Store what rendering the frames on demand needs (`rendered_frames.RENDER_SETUP`) and record it."""
        path = self.root / RENDER_SETUP
        write_render_setup(path, uv, texture, settings)
        record = file_record(path)
        self._update_manifest(lambda: self._manifest.__setitem__("render_setup", record))

    def _rendered_frames(self, index: int) -> FrameArray:
        if self._render_setup is None:
            path = self._checked_file(self._manifest["render_setup"], verify=False)
            self._render_setup = read_render_setup(path)
        return RenderedFrames(self.load_trajectory(index), self.cameras(), self._render_setup, self.root / RENDER_SETUP)

    def load_frames(self, index: int, mmap: bool = True, verify: bool = False) -> np.ndarray:
        """All frames (T, N, H, W, 3) uint8 of trajectory `index`, decoded into memory (`mmap` is ignored since
        schema 2: the frames are compressed; use `frames(index)` to read only some views or frames)."""
        frames = self.frames(index)
        if verify:
            frames.verify()
        return frames.read(slice(None), slice(None))

    def verify(self) -> None:
        """Check every file (size, sha256, shapes, values); one ClodsError listing all problems."""
        problems: list[str] = []
        texture = self._manifest.get("texture")
        checks = [lambda: self._checked_file(texture, True)] if texture else []
        if self._manifest.get("render_setup"):
            checks.append(lambda: read_render_setup(self._checked_file(self._manifest["render_setup"], True)))
        for index, entry in sorted(self._entries.items()):
            if "traj" in entry["files"]:
                checks.append(lambda i=index: self.load_trajectory(i, verify=True))
            if "frames" in entry["files"]:
                checks.append(lambda i=index: self._verify_frames(i))
        for check in checks:
            try:
                check()
            except ClodsError as exc:
                problems.append(exc.message)
        if problems:
            raise ClodsError(f"{len(problems)} problem(s): " + "; ".join(problems), where=str(self.root))

    # ------------------------------------------------------------------ query

    def cameras(self) -> list[Camera]:
        """The camera rig the frames were rendered with (index n = frames[:, n])."""
        return [Camera.from_dict(d) for d in self._manifest["cameras"]]

    @property
    def has_meshes(self) -> bool:
        """False for a dataset of videos alone (imported without meshes)."""
        return self._manifest.get("meshes", True) is not False

    def require_meshes(self, what: str) -> None:
        """Raise the one-line ClodsError of a dataset without meshes when `what` (a task, a renderer) needs them."""
        if not self.has_meshes:
            raise ClodsError(f"the dataset has no meshes (imported from video), and {what} needs ground-truth meshes",
                             where=str(self.root),
                             hint="without meshes run nvs with a per-frame renderer (gs3d), dvc with a video predictor "
                                  "(copylast, simvp, ...), or CloDS from video alone (initial_mesh, extract, dvc --sim --renderer with "
                                  "task_config.clods.initial_mesh=reconstructed); or re-import with --meshes DIR")  # fmt: skip

    def dt(self, index: int) -> float:
        """Seconds between frames of trajectory `index`."""
        entry = self._entry(index)
        return float(entry["dt"]) if "dt" in entry else self.load_trajectory(index).dt

    def meta(self, index: int) -> dict[str, Any]:
        """The recorded metadata of trajectory `index` (scene, seed, source, ...), with or without meshes."""
        entry = self._entry(index)
        return dict(entry["meta"]) if "meta" in entry else dict(self.load_trajectory(index).meta)

    @property
    def scene(self) -> str:
        return str(self._manifest["scene"])

    @property
    def config(self) -> dict[str, Any]:
        """The data config dict the dataset was generated with."""
        return dict(self._manifest["config"])

    def texture_path(self) -> Path | None:
        """The texture file recorded by write_texture(), else `root/texture.png` if present, else None."""
        texture = self._manifest.get("texture")
        if texture:
            return self.root / texture["name"]
        default = self.root / "texture.png"
        return default if default.is_file() else None

    def file_records(self) -> dict[str, Any]:
        """The manifest's file records (name, sha256, bytes): every complete trajectory's, the render setup's, the texture's."""
        records = {str(i): self._entries[i]["files"] for i in sorted(self.completed_indices())}
        return json.loads(json.dumps({"trajectories": records, "render_setup": self._manifest.get("render_setup"),
                                      "texture": self._manifest.get("texture")}))  # fmt: skip

    def completed_indices(self) -> set[int]:
        """Indices whose files were completely written (what a resumed generation can skip)."""
        return {i for i, e in self._entries.items() if e.get("complete") is True}

    def indices(self, split: str) -> list[int]:
        """Sorted indices of complete trajectories in `split` ('train' or 'test')."""
        if split not in SPLITS:
            raise ClodsError(f"unknown split '{split}', expected one of {SPLITS}", where=str(self.root))
        return sorted(i for i in self.completed_indices() if self._entries[i]["split"] == split)

    def entry(self, index: int) -> dict[str, Any]:
        """A copy of the manifest entry of trajectory `index`."""
        return json.loads(json.dumps(self._entry(index)))

    def __len__(self) -> int:
        return len(self.completed_indices())

    # -------------------------------------------------------------- internals

    def _entry(self, index: int) -> dict[str, Any]:
        entry = self._entries.get(int(index))
        if entry is None or entry.get("complete") is not True:
            raise ClodsError(f"trajectory {index} is not in the dataset (never written or generation interrupted)",
                             where=str(self.root / MANIFEST), hint="re-run generation to complete it")
        return entry

    def regenerate_hint(self) -> str:
        """What to do about a damaged file of this dataset: generate it again (or import it again)."""
        if isinstance(self._manifest.get("config"), dict) and "scene_spec" in self._manifest["config"]:
            return f"delete {self.root} and run again, which regenerates it (or: clods-bench data generate --force with the run's settings)"
        return f"import the dataset again into {self.root}"

    def check_files(self) -> None:
        """Every file of every complete trajectory (and the render setup) against its manifest record: mesh files by
        sha256 (once per process while a file is unchanged on disk), frame arrays by their `zarr.json` sha256 and
        byte total (their chunks carry their own crc32c, checked when decoded)."""
        with integrity.timed("dataset-files"):
            self._check_files()

    def _check_files(self) -> None:
        if self._manifest.get("render_setup"):
            self._checked_file(self._manifest["render_setup"], verify=False)
        for index in sorted(self.completed_indices()):
            files = self._entries[index]["files"]
            if "traj" in files:
                self._checked_file(files["traj"], verify=False)
            if "frames" in files:  # zarr.json by its sha256, the chunks by their byte total (and crc32c when decoded)
                record, folder = files["frames"], self.root / files["frames"]["name"]
                if not (folder / "zarr.json").is_file():
                    raise ClodsError("frame array missing", where=str(folder), hint=self.regenerate_hint())
                integrity.check_sha256(folder / "zarr.json", record["sha256"], self.regenerate_hint(), "the dataset's manifest records for it")
                info = folder.stat()  # a chunk added, removed or renamed in, or another folder here, moves its ctime
                stamp = (info.st_ctime_ns, info.st_ino, record["bytes"])
                if _FRAMES_COUNTED.get(str(folder.resolve())) != stamp:
                    size = sum(p.stat().st_size for p in folder.iterdir() if p.is_file())
                    if size != record["bytes"]:
                        raise ClodsError(f"frame array holds {size} bytes, manifest says {record['bytes']}", where=str(folder), hint=self.regenerate_hint())
                    _FRAMES_COUNTED[str(folder.resolve())] = stamp

    def _checked_file(self, record: dict[str, Any], verify: bool) -> Path:
        """The file of a manifest record, checked: present, its size, and its sha256 (`verify`: hashed now; else once
        per process while the file is unchanged on disk)."""
        path = self.root / record["name"]
        if not path.is_file():
            raise ClodsError("file missing", where=str(path), hint=self.regenerate_hint())
        size = path.stat().st_size
        if size != record["bytes"]:
            raise ClodsError(f"truncated: expected {record['bytes']} bytes, found {size}" if size < record["bytes"]
                             else f"wrong size: expected {record['bytes']} bytes, found {size}", where=str(path), hint=self.regenerate_hint())
        if verify:
            integrity.forget(path)
        integrity.check_sha256(path, record["sha256"], self.regenerate_hint(), recorded="the dataset's manifest records for it")
        return path

    def _check_frames(self, index: int, frames: np.ndarray, num_steps: int) -> None:
        where = f"trajectory {index}.frames"
        cams = self._manifest["cameras"]
        if frames.dtype != np.uint8 or frames.ndim != 5 or frames.shape[-1] != 3:
            raise ClodsError(f"frames {frames.shape} {frames.dtype}, expected (T, N, H, W, 3) uint8", where=where)
        if frames.shape[0] != num_steps:
            raise ClodsError(f"{frames.shape[0]} frames but world_pos has {num_steps}", where=where)
        if frames.shape[1] != len(cams):
            raise ClodsError(f"{frames.shape[1]} views but the dataset has {len(cams)} cameras", where=where)
        for n, cam in enumerate(cams):
            if frames.shape[2:4] != (cam["height"], cam["width"]):
                raise ClodsError(f"image size {frames.shape[2:4]} but camera {n} is {cam['height']}x{cam['width']}", where=where)

    def _verify_frames(self, index: int) -> None:
        """Every chunk of trajectory `index`'s frames decodes and passes its checksum; the byte total matches."""
        frames = self.frames(index)
        frames.verify()
        record = self._entry(index)["files"]["frames"]
        size = sum(p.stat().st_size for p in frames.path.iterdir() if p.is_file())
        if size != record["bytes"]:
            raise ClodsError(f"frame array holds {size} bytes, manifest says {record['bytes']}", where=str(frames.path))

    def _frames_shape(self, num_steps: int) -> tuple[int, ...]:
        cams = self._manifest["cameras"]
        if not cams:
            raise ClodsError("frames given but the dataset has no cameras", where=str(self.root / MANIFEST))
        return (int(num_steps), len(cams), int(cams[0]["height"]), int(cams[0]["width"]), 3)

    def _update_manifest(self, change: Any) -> None:
        """Re-read the manifest under the lock (parallel writers add their own entries), apply `change()`, save."""
        with file_lock(self.root / MANIFEST_LOCK):
            if (self.root / MANIFEST).is_file():
                self._manifest = read_manifest(self.root)
                self._entries = {int(e["index"]): e for e in self._manifest["trajectories"]}
            change()
            self._save_manifest()

    def _save_manifest(self) -> None:
        self._manifest["trajectories"] = [self._entries[i] for i in sorted(self._entries)]
        write_json(self.root / MANIFEST, self._manifest)

    def _delete_files(self) -> None:
        names = [f["name"] for e in self._entries.values() for f in e["files"].values()]
        for key in ("texture", "render_setup"):
            if self._manifest.get(key):
                names.append(self._manifest[key]["name"])
        for name in names:
            path = self.root / name
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink(missing_ok=True)
