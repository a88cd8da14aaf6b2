"""Content digests of a stored dataset, to check that two machines generated the same data.

The manifest's sha256 is over the stored files (a zip with timestamps, compressed chunks): two bit-equal
generations on two hosts give different file hashes. These digests are over the arrays themselves: one for
each trajectory's static arrays (cells, mesh_pos, node_type, dt), one per frame of `world_pos`, and optionally
one over the decoded frames, so a comparison names the first frame at which two hosts' trajectories part.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

import numpy as np

from clods_bench.datasets.frame_store import FrameArray
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError

DIGEST_VERSION = 1
SHORT = 16  # hex characters kept per frame digest
FRAME_BLOCK = 16  # frames of one camera decoded at a time by frames_digest


def _hash_arrays(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for arr in arrays:
        arr = np.ascontiguousarray(arr)
        h.update(f"{arr.dtype.str}{arr.shape}".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def frames_digest(frames: FrameArray, block: int = FRAME_BLOCK) -> str:
    """sha256 of a trajectory's decoded images (T, N, H, W, 3), camera by camera and frame by frame, read
    `block` frames of one camera at a time, so memory stays bounded at the paper's 800 px."""
    h = hashlib.sha256(f"|u1{tuple(frames.shape)}".encode())
    steps, views = frames.shape[0], frames.shape[1]
    for view in range(views):
        for t0 in range(0, steps, block):
            h.update(np.ascontiguousarray(frames.read(slice(t0, min(t0 + block, steps)), [view])).tobytes())
    return h.hexdigest()


def dataset_digest(store: DatasetStore, frames: bool = False) -> dict[str, Any]:
    """Digests of every complete trajectory of `store`: static arrays, each `world_pos` frame, and (with
    `frames`) the decoded images."""
    out: dict[str, Any] = {"version": DIGEST_VERSION, "scene": store.scene, "trajectories": {}}
    for index in sorted(store.completed_indices()):
        entry: dict[str, Any] = {"split": store.entry(index).get("split")}
        if store.has_meshes:
            traj = store.load_trajectory(index)
            entry["static"] = _hash_arrays(traj.cells, traj.mesh_pos, traj.node_type, np.float64(traj.dt))
            entry["world_pos"] = [_hash_arrays(frame)[:SHORT] for frame in traj.world_pos]
        if frames:
            entry["frames"] = frames_digest(store.frames(index))
        out["trajectories"][str(index)] = entry
    return out


def compare_digests(ours: dict[str, Any], theirs: dict[str, Any]) -> list[str]:
    """What differs between two `dataset_digest` results, one line per trajectory (empty: the same data)."""
    problems: list[str] = []
    if ours.get("version") != theirs.get("version"):
        return [f"digest versions differ ({ours.get('version')} and {theirs.get('version')})"]
    if ours.get("scene") != theirs.get("scene"):
        problems.append(f"scene '{ours.get('scene')}' against '{theirs.get('scene')}'")
    a, b = ours["trajectories"], theirs["trajectories"]
    for key in sorted(set(a) | set(b), key=lambda k: (not str(k).isdigit(), int(k) if str(k).isdigit() else 0, str(k))):
        if key not in a or key not in b:
            problems.append(f"trajectory {key}: only in the {'first' if key in a else 'second'} dataset")
            continue
        ta, tb = a[key], b[key]
        if ta.get("static") != tb.get("static"):
            problems.append(f"trajectory {key}: mesh topology, rest shape or dt differ")
        pa, pb = ta.get("world_pos"), tb.get("world_pos")
        if pa is not None and pb is not None:
            differing = [t for t, (x, y) in enumerate(zip(pa, pb)) if x != y]
            if len(pa) != len(pb):
                problems.append(f"trajectory {key}: {len(pa)} frames against {len(pb)}")
            elif differing:
                problems.append(f"trajectory {key}: world_pos differs from frame {differing[0]} on "
                                f"({len(differing)} of {len(pa)} frames)")  # fmt: skip
        if "frames" in ta and "frames" in tb and ta["frames"] != tb["frames"]:
            problems.append(f"trajectory {key}: rendered frames differ")
    return problems


CONTENT_DIGEST_FILE = "content_digest.json"
FRAMES_DIGEST_MAX_BYTES = 2**30
"""Decoded frames larger than this (1 GiB) are left out of `content_digest` (the `paper` preset's 23 GB a
trajectory): the meshes then stand for the dataset."""


def content_digest(store: DatasetStore) -> str:
    """One 16-hex-digit digest of a complete dataset's arrays (meshes, and frames up to FRAMES_DIGEST_MAX_BYTES),
    kept in the dataset folder and trusted only while it matches: the dataset's files are checked against their
    manifest records first (`DatasetStore.check_files`: a changed array is one error naming its file), and the kept
    digest is recomputed when its own content hash fails or the manifest's file records changed since it was made.
    A kept digest written before these checks (no `files` field) is read as before."""
    from clods_bench import integrity
    from clods_bench.atomic import write_json

    store.check_files()
    files = files_fingerprint(store)
    path = store.root / CONTENT_DIGEST_FILE
    try:
        kept = json.loads(path.read_text())
        integrity.check_json(kept, path, "")
        if kept.get("files", files) == files:
            return str(kept["digest"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError, ClodsError):
        pass  # missing, damaged or out of date: computed again from the arrays
    frames = _stored_frames_bytes(store) <= FRAMES_DIGEST_MAX_BYTES
    full = dataset_digest(store, frames=frames)
    short = hashlib.sha256(json.dumps(full, sort_keys=True).encode()).hexdigest()[:SHORT]
    write_json(path, integrity.seal_json({"version": DIGEST_VERSION, "frames": frames, "digest": short, "files": files}))
    return short


def files_fingerprint(store: DatasetStore) -> str:
    """SHA-256 (16 hex digits) of the manifest's file records (`DatasetStore.file_records`): what a kept content digest
    was computed from."""
    text = json.dumps(store.file_records(), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:SHORT]


def _stored_frames_bytes(store: DatasetStore) -> float:
    """Bytes of every complete trajectory's decoded frames (inf when a trajectory has none stored: videos rendered
    on demand, or meshes alone)."""
    total = 0
    for index in store.completed_indices():
        if "frames" not in store.entry(index).get("files", {}):
            return float("inf")
        total += int(np.prod(store.frames(index).shape))
    return total
