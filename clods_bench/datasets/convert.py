"""`clods-bench data convert`: rewrite a schema-1 dataset (one raw .npy of frames per trajectory) in place
as schema 2 (chunked, compressed, checksummed zarr frames; see `frame_store`). Nothing is regenerated.

The steps, each safe to kill and resume:
1. per trajectory: check the .npy against the sha256 its manifest recorded, write `frames_0000.zarr`
   (temp directory, renamed into place when whole), then decode it and compare with the .npy, chunk by
   chunk; an array already in place from an interrupted run is compared the same way instead of rewritten;
2. replace the manifest by the schema-2 one in one atomic rename: the commit point (before it the old
   manifest and every .npy are untouched, so old and new code see a consistent dataset);
3. delete the .npy files (a rerun on a schema-2 dataset deletes any that a kill left behind).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from clods_bench.atomic import file_lock, write_json
from clods_bench.datasets.frame_store import LazyFrames, frames_record, write_frames
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.store_manifest import MANIFEST, SCHEMA_VERSION, remove_stale_temp_files
from clods_bench.errors import ClodsError

_NPY = re.compile(r"frames_\d{4,}\.npy")


@dataclass(frozen=True)
class Converted:
    """What converting one dataset did: trajectories rewritten, and raw vs stored frame bytes."""

    root: Path
    trajectories: int
    npy_bytes: int
    stored_bytes: int
    already: bool  # the dataset was schema 2 already (only leftover .npy files were removed)


def convert_tree(root: Path) -> list[Converted]:
    """Convert the dataset at `root`, or every dataset directory directly under `root` (a `data.root`)."""
    root = Path(root)
    if (root / MANIFEST).is_file():
        return [convert_dataset(root)]
    if not root.is_dir():
        raise ClodsError("directory not found", where=str(root))
    found = sorted(p for p in root.iterdir() if (p / MANIFEST).is_file())
    if not found:
        raise ClodsError("no dataset here (no manifest.json in it or in its subdirectories)", where=str(root))
    return [convert_dataset(p) for p in found]


def convert_dataset(root: Path) -> Converted:
    """Convert one dataset directory from schema 1 to 2 in place (resumable; see the module docstring)."""
    root = Path(root).resolve()
    with file_lock(root.parent / f".{root.name}.lock"):  # the lock `generate` holds: never convert under a writer
        manifest = _load(root / MANIFEST)
        version = manifest.get("schema_version")
        if version == SCHEMA_VERSION:
            DatasetStore.open(root)  # a readable schema-2 store
            removed = _delete_npy(root, manifest)
            return Converted(root, 0, removed, 0, already=True)
        if version != 1:
            raise ClodsError(f"cannot convert schema version {version!r} (only 1 -> {SCHEMA_VERSION})", where=str(root / MANIFEST))
        remove_stale_temp_files(root)
        new = json.loads(json.dumps(manifest))
        npy_bytes = stored = count = 0
        for entry in new.get("trajectories", []):
            record = entry.get("files", {}).get("frames")
            if record is None or entry.get("complete") is not True:
                continue
            npy = root / record["name"]
            out = root / (npy.stem + ".zarr")
            shape = tuple(entry["shapes"]["frames"])
            source = _source(npy, record, shape)
            if not out.is_dir():
                write_frames(out, (source[t] for t in range(shape[0])), shape)
            _compare(source, out, shape)
            entry["files"]["frames"] = frames_record(out, shape)
            npy_bytes += int(record["bytes"])
            stored += int(entry["files"]["frames"]["bytes"])
            count += 1
        new["schema_version"] = SCHEMA_VERSION
        write_json(root / MANIFEST, new)  # the commit point
        DatasetStore.open(root)
        _delete_npy(root, new)
        return Converted(root, count, npy_bytes, stored, already=False)


def _load(path: Path) -> dict[str, Any]:
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ClodsError(f"cannot read manifest: {exc}", where=str(path)) from None
    if not isinstance(manifest, dict):
        raise ClodsError("manifest is not a JSON object", where=str(path))
    return manifest


def _source(npy: Path, record: dict[str, Any], shape: tuple[int, ...]) -> np.ndarray:
    """The schema-1 frames, memory-mapped, after checking size and sha256 against the old manifest."""
    if not npy.is_file():
        raise ClodsError("frames file missing: cannot convert this trajectory", where=str(npy),
                         hint="if a convert deleted it, the manifest was already committed; else regenerate the dataset")  # fmt: skip
    if npy.stat().st_size != record["bytes"] or _sha256(npy) != record["sha256"]:
        raise ClodsError("frames file differs from its manifest record (damaged): refusing to convert it", where=str(npy))
    frames = np.load(npy, mmap_mode="r", allow_pickle=False)
    if frames.shape != shape or frames.dtype != np.uint8:
        raise ClodsError(f"frames {frames.shape} {frames.dtype}, manifest says {shape} uint8", where=str(npy))
    return frames


def _compare(source: np.ndarray, out: Path, shape: tuple[int, ...]) -> None:
    """The written array decodes to exactly the .npy's frames (a time chunk at a time, to bound memory)."""
    lazy = LazyFrames(out)
    if lazy.shape != shape:
        raise ClodsError(f"converted array has shape {lazy.shape}, expected {shape}", where=str(out))
    k = lazy.chunk_frames
    for t0 in range(0, shape[0], k):
        if not np.array_equal(lazy[t0 : t0 + k], source[t0 : t0 + k]):
            raise ClodsError(f"converted frames {t0}..{min(t0 + k, shape[0]) - 1} differ from the .npy", where=str(out),
                             hint="delete this .zarr directory and run the conversion again")  # fmt: skip


def _delete_npy(root: Path, manifest: dict[str, Any]) -> int:
    """Remove frames_XXXX.npy files whose trajectory now has a .zarr array in the manifest; their total bytes."""
    converted = {Path(e["files"]["frames"]["name"]).stem for e in manifest.get("trajectories", []) if "frames" in e.get("files", {})}
    removed = 0
    for p in root.iterdir():
        if _NPY.fullmatch(p.name) and p.stem in converted:
            removed += p.stat().st_size
            p.unlink()
    return removed


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()
