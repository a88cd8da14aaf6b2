"""The dataset store's manifest (`manifest.json`) and file records: reading and checking a manifest, the differences
between two, the sha256 records of the files, and the temp files an interrupted writer leaves (see `store`)."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from clods_bench.atomic import _jsonable
from clods_bench.errors import ClodsError

SCHEMA_VERSION = 2
MANIFEST = "manifest.json"


def normalise(obj: Any) -> Any:
    """What `obj` looks like after a JSON round trip (so configs compare equal to the stored ones)."""
    return json.loads(json.dumps(_jsonable(obj), sort_keys=True))


def config_diff(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
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


def read_manifest(root: Path) -> dict[str, Any]:
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
    check_manifest(manifest, str(path))
    return manifest


def check_manifest(m: Any, where: str) -> None:
    """A ClodsError naming `where` unless `m` is a manifest of this schema (schema 1 is named, with its converter)."""
    if not isinstance(m, dict):
        raise ClodsError(f"expected a JSON object, got {type(m).__name__}", where=where)
    version = m.get("schema_version")
    if version == 1:
        root = Path(where).parent
        raise ClodsError(f"dataset stored in schema version 1 (one raw .npy of frames per trajectory); this clods-bench reads "
                         f"version {SCHEMA_VERSION} (chunked, compressed frames)", where=where,
                         hint=f"convert it in place, nothing is regenerated: clods-bench data convert {root}")  # fmt: skip
    if version != SCHEMA_VERSION:
        raise ClodsError(f"manifest schema version {version!r}, this clods-bench reads version {SCHEMA_VERSION}",
                         where=f"{where}.schema_version", hint="regenerate the dataset (new directory or --force)")
    for key, kind in (("scene", str), ("config", dict), ("cameras", list), ("trajectories", list)):
        if not isinstance(m.get(key), kind):
            raise ClodsError(f"missing or not a {kind.__name__}", where=f"{where}.{key}")
    for n, e in enumerate(m["trajectories"]):
        if not isinstance(e, dict) or not all(k in e for k in ("index", "split", "files", "shapes", "complete")):
            raise ClodsError("entry lacks index/split/files/shapes/complete", where=f"{where}.trajectories[{n}]")
        if ("traj" not in e["files"] and m.get("meshes", True) is not False) or not all(k in f for f in e["files"].values() for k in ("name", "sha256", "bytes")):
            raise ClodsError("file records need name, sha256 and bytes", where=f"{where}.trajectories[{n}].files")


def sha256_of(path: Path) -> str:
    """Hex SHA-256 of a file's bytes, read in 4 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


def digest_record(path: Path) -> dict[str, Any]:
    """A file's sha256 and byte size."""
    return {"sha256": sha256_of(path), "bytes": path.stat().st_size}


def file_record(path: Path) -> dict[str, Any]:
    """A file's manifest record: name, sha256 and byte size."""
    return {"name": path.name, **digest_record(path)}


def remove_stale_temp_files(root: Path) -> None:
    """Delete temp files and frame directories an interrupted writer left behind ('.<target>.*.tmp*')."""
    if root.is_dir():
        for p in root.iterdir():
            if p.name.startswith((".traj_", ".frames_", f".{MANIFEST}.", ".texture")) and ".tmp" in p.name:
                if p.is_dir():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink(missing_ok=True)
