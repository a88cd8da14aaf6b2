"""The on-disk dataset: a manifest plus one .npz (mesh trajectory) and one .npy (frames) per trajectory.

Layout of `root`:
- `manifest.json`: schema version, scene, the data config, cameras, texture, and one entry per
  *complete* trajectory (index, split, seed, file names with sha256 and byte size, array shapes);
- `traj_0000.npz`: cells, mesh_pos, node_type, world_pos, dt and `meta` (a JSON string);
- `frames_0000.npy`: (T, N, H, W, 3) uint8 multi-view frames, memory-mappable;
- `texture.png` (optional).
Files are written atomically before their manifest entry, so an interrupted generation leaves
no entry for a half-written trajectory and a later run resumes from `completed_indices()`.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from clods_bench.atomic import _jsonable, atomic_path, write_json, write_npz
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.splits import SPLITS
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError

SCHEMA_VERSION = 1
MANIFEST = "manifest.json"
TRAJ_FIELDS = ("cells", "mesh_pos", "node_type", "world_pos")
_DTYPES = {"cells": np.int32, "mesh_pos": np.float32, "node_type": np.int32, "world_pos": np.float32}
_LOAD_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, json.JSONDecodeError)


class DatasetStore:
    """One dataset directory: read trajectories and frames, or append them during generation."""

    def __init__(self, root: Path, manifest: dict[str, Any] | None = None) -> None:
        """Open the store at `root` (same as `DatasetStore.open`); `manifest` is for create()."""
        self.root = Path(root)
        self._manifest = manifest if manifest is not None else _read_manifest(self.root)
        self._entries: dict[int, dict[str, Any]] = {int(e["index"]): e for e in self._manifest["trajectories"]}

    # ----------------------------------------------------------- create / open

    @classmethod
    def create(cls, root: Path, scene: str, config: dict[str, Any], cameras: list[Camera], force: bool = False) -> "DatasetStore":
        """A new store at `root`, or the existing one (to resume) if it was made with the same config."""
        root = Path(root)
        manifest = {
            "schema_version": SCHEMA_VERSION,
            "scene": scene,
            "config": _normalise(config),
            "cameras": _normalise([c.to_dict() for c in cameras]),
            "texture": None,
            "trajectories": [],
        }
        if (root / MANIFEST).exists():
            try:
                store = cls.open(root)
            except ClodsError:
                if not force:
                    raise
                store = None  # unreadable manifest: --force starts over
            if store is not None:
                diff = _diff(store._manifest, manifest)
                if not diff:
                    _remove_stale_temp_files(root)
                    return store
                if not force:
                    raise ClodsError(
                        "dataset exists with a different config: " + "; ".join(diff),
                        where=str(root / MANIFEST),
                        hint="use a different dataset directory, or --force to regenerate it",
                    )
                store._delete_files()
        _remove_stale_temp_files(root)
        write_json(root / MANIFEST, manifest)
        return cls(root, manifest)

    @classmethod
    def open(cls, root: Path) -> "DatasetStore":
        """Open an existing store; clear errors for a missing, malformed or foreign manifest."""
        return cls(Path(root))

    # ------------------------------------------------------------------ write

    def write_trajectory(self, index: int, split: str, seed: int, traj: Trajectory, frames: np.ndarray | None) -> None:
        """Write one trajectory's files atomically, then record its entry in the manifest."""
        if split not in SPLITS:
            raise ClodsError(f"unknown split '{split}', expected one of {SPLITS}", where=f"trajectory {index}")
        if index < 0:
            raise ClodsError(f"trajectory index must be >= 0, got {index}", where=f"trajectory {index}")
        traj.validate(where=f"trajectory {index}")
        arrays = {k: np.ascontiguousarray(getattr(traj, k), dtype=_DTYPES[k]) for k in TRAJ_FIELDS}
        if frames is not None:
            self._check_frames(index, frames, traj.num_steps)
        if index in self._entries:  # drop the old entry first: its files are about to change
            del self._entries[index]
            self._save_manifest()
        traj_name = f"traj_{index:04d}.npz"
        write_npz(self.root / traj_name, dt=np.float64(traj.dt), meta=np.str_(json.dumps(_normalise(traj.meta))), **arrays)
        files = {"traj": _file_record(self.root / traj_name)}
        shapes = {k: list(v.shape) for k, v in arrays.items()}
        if frames is not None:
            frames_name = f"frames_{index:04d}.npy"
            files["frames"] = _save_npy(self.root / frames_name, np.ascontiguousarray(frames))
            shapes["frames"] = list(frames.shape)
        self._entries[index] = {"index": index, "split": split, "seed": int(seed), "files": files, "shapes": shapes, "complete": True}
        self._save_manifest()

    def write_texture(self, data: bytes, name: str = "texture.png") -> None:
        """Store the texture image file (already encoded bytes) and record it in the manifest."""
        with atomic_path(self.root / name) as tmp:
            tmp.write_bytes(data)
        self._manifest["texture"] = {"name": name, **_digest_record(self.root / name)}
        self._save_manifest()

    # ------------------------------------------------------------------- read

    def load_trajectory(self, index: int, verify: bool = False) -> Trajectory:
        """The mesh trajectory `index`, checked against the manifest and validated (ClodsError naming the file)."""
        entry = self._entry(index)
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

    def load_frames(self, index: int, mmap: bool = True, verify: bool = False) -> np.ndarray:
        """Frames (T, N, H, W, 3) uint8 of trajectory `index`, memory-mapped read-only by default."""
        entry = self._entry(index)
        if "frames" not in entry["files"]:
            raise ClodsError(f"trajectory {index} was stored without frames", where=str(self.root / MANIFEST),
                             hint="regenerate the dataset with render_frames on")
        path = self._checked_file(entry["files"]["frames"], verify)
        try:
            frames = np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
        except _LOAD_ERRORS as exc:
            raise ClodsError(f"cannot read frames file: {type(exc).__name__}: {exc}", where=str(path)) from None
        expected = tuple(entry["shapes"]["frames"])
        if frames.shape != expected or frames.dtype != np.uint8:
            raise ClodsError(f"frames {frames.shape} {frames.dtype}, manifest says {expected} uint8", where=str(path))
        return frames

    def verify(self) -> None:
        """Check every file (size, sha256, shapes, values); one ClodsError listing all problems."""
        problems: list[str] = []
        texture = self._manifest.get("texture")
        checks = [lambda: self._checked_file(texture, True)] if texture else []
        for index, entry in sorted(self._entries.items()):
            checks.append(lambda i=index: self.load_trajectory(i, verify=True))
            if "frames" in entry["files"]:
                checks.append(lambda i=index: self.load_frames(i, mmap=True, verify=True))
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

    def _checked_file(self, record: dict[str, Any], verify: bool) -> Path:
        path = self.root / record["name"]
        if not path.is_file():
            raise ClodsError("file missing", where=str(path), hint="re-run generation, or regenerate with --force")
        size = path.stat().st_size
        if size != record["bytes"]:
            raise ClodsError(f"truncated: expected {record['bytes']} bytes, found {size}" if size < record["bytes"]
                             else f"wrong size: expected {record['bytes']} bytes, found {size}", where=str(path))
        if verify and _sha256(path) != record["sha256"]:
            raise ClodsError("sha256 mismatch: file content differs from the manifest (corrupted)", where=str(path))
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

    def _save_manifest(self) -> None:
        self._manifest["trajectories"] = [self._entries[i] for i in sorted(self._entries)]
        write_json(self.root / MANIFEST, self._manifest)

    def _delete_files(self) -> None:
        names = [f["name"] for e in self._entries.values() for f in e["files"].values()]
        if self._manifest.get("texture"):
            names.append(self._manifest["texture"]["name"])
        for name in names:
            (self.root / name).unlink(missing_ok=True)


# ------------------------------------------------------------------ helpers


def _normalise(obj: Any) -> Any:
    """What `obj` looks like after a JSON round trip (so configs compare equal to the stored ones)."""
    return json.loads(json.dumps(_jsonable(obj), sort_keys=True))


def _diff(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """Human-readable differences in scene, config keys and cameras between two manifests."""
    out = []
    if old["scene"] != new["scene"]:
        out.append(f"scene (existing {old['scene']!r}, requested {new['scene']!r})")
    a, b = old["config"], new["config"]
    for key in sorted(set(a) | set(b)):
        if a.get(key, "<absent>") != b.get(key, "<absent>"):
            out.append(f"{key} (existing {a.get(key, '<absent>')!r}, requested {b.get(key, '<absent>')!r})")
    if len(old["cameras"]) != len(new["cameras"]) or not all(
        np.allclose(np.asarray(c[k], float), np.asarray(d[k], float)) for c, d in zip(old["cameras"], new["cameras"]) for k in c
    ):
        out.append("cameras")
    return out


def _read_manifest(root: Path) -> dict[str, Any]:
    """Load and check `root/manifest.json`, with errors naming the path (and JSON error position)."""
    path = root / MANIFEST
    if not root.is_dir():
        raise ClodsError("dataset directory not found", where=str(root), hint="generate the dataset first")
    if not path.is_file():
        raise ClodsError("dataset manifest not found", where=str(path), hint="generate the dataset first")
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ClodsError(f"malformed JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}", where=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ClodsError(f"cannot read manifest: {exc}", where=str(path)) from None
    _check_manifest(manifest, str(path))
    return manifest


def _check_manifest(m: Any, where: str) -> None:
    if not isinstance(m, dict):
        raise ClodsError(f"expected a JSON object, got {type(m).__name__}", where=where)
    version = m.get("schema_version")
    if version != SCHEMA_VERSION:
        raise ClodsError(f"manifest schema version {version!r}, this clods-bench reads version {SCHEMA_VERSION}",
                         where=f"{where}.schema_version", hint="regenerate the dataset (new directory or --force)")
    for key, kind in (("scene", str), ("config", dict), ("cameras", list), ("trajectories", list)):
        if not isinstance(m.get(key), kind):
            raise ClodsError(f"missing or not a {kind.__name__}", where=f"{where}.{key}")
    for n, e in enumerate(m["trajectories"]):
        if not isinstance(e, dict) or not all(k in e for k in ("index", "split", "files", "shapes", "complete")):
            raise ClodsError("entry lacks index/split/files/shapes/complete", where=f"{where}.trajectories[{n}]")
        if "traj" not in e["files"] or not all(k in f for f in e["files"].values() for k in ("name", "sha256", "bytes")):
            raise ClodsError("file records need name, sha256 and bytes", where=f"{where}.trajectories[{n}].files")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


def _digest_record(path: Path) -> dict[str, Any]:
    return {"sha256": _sha256(path), "bytes": path.stat().st_size}


def _file_record(path: Path) -> dict[str, Any]:
    return {"name": path.name, **_digest_record(path)}


class _HashingWriter:
    """File wrapper that hashes and counts what np.save writes (no second pass over large frames)."""

    def __init__(self, fh: Any) -> None:
        self.fh, self.sha, self.size = fh, hashlib.sha256(), 0

    def write(self, data: bytes) -> int:
        self.sha.update(data)
        self.size += len(data)
        return self.fh.write(data)


def _save_npy(path: Path, arr: np.ndarray) -> dict[str, Any]:
    """np.save atomically, returning the file record (name, sha256, bytes)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            w = _HashingWriter(fh)
            np.lib.format.write_array(w, arr, allow_pickle=False)
    return {"name": path.name, "sha256": w.sha.hexdigest(), "bytes": w.size}


def _remove_stale_temp_files(root: Path) -> None:
    """Delete temp files an interrupted writer left behind (atomic.py names them '.<target>.*.tmp*')."""
    if root.is_dir():
        for p in root.iterdir():
            if p.name.startswith((".traj_", ".frames_", f".{MANIFEST}.", ".texture")) and ".tmp" in p.name:
                p.unlink(missing_ok=True)
