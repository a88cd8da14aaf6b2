"""Resumable training checkpoints, written atomically and checked against the run that loads them.

A checkpoint records the simulator name, the config digest and the digest of the training
meshes' topologies next to the trainer state; loading it into a different simulator, config
or mesh raises ClodsError instead of silently mixing incompatible weights. Each file carries the
SHA-256 of its bytes (`clods_bench.integrity`), checked before it is loaded: changed weights are
one error naming the file, never used.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Iterable

import torch

from clods_bench import integrity
from clods_bench.errors import ClodsError

CHECKPOINT_FORMAT = 1


def mesh_digest(topology_keys: Iterable[str]) -> str:
    """Order-independent digest of the set of mesh topologies a model was trained on."""
    return hashlib.sha256("\n".join(sorted(set(topology_keys))).encode()).hexdigest()[:16]


def save_checkpoint(path: Path, simulator: str, config_digest: str, meshes: str, trainer_state: dict[str, Any], extra: dict[str, Any]) -> None:
    """Write the checkpoint in one atomic rename (a crash leaves the previous one intact)."""
    _write(path, simulator, config_digest, meshes, trainer=trainer_state, extra=extra)


def load_checkpoint(path: Path, simulator: str, config_digest: str, meshes: str) -> dict[str, Any]:
    """The checkpoint's payload, after checking it belongs to this simulator, config and meshes."""
    hint = "delete it to train from scratch (or use another work directory)"
    payload = _read(path, "checkpoint", "trainer", hint)
    if payload["simulator"] != simulator:
        raise ClodsError(
            f"checkpoint was written by simulator '{payload['simulator']}', not '{simulator}'", where=str(path), hint=hint
        )
    if payload["config_digest"] != config_digest:
        raise ClodsError(
            f"checkpoint was trained with another '{simulator}' config (digest {payload['config_digest']}, now {config_digest})",
            where=str(path),
            hint=hint,
        )
    if payload["mesh_digest"] != meshes:
        raise ClodsError(
            f"checkpoint was trained on other mesh topologies (digest {payload['mesh_digest']}, now {meshes})",
            where=str(path),
            hint=hint,
        )
    return payload


SNAPSHOT_DIR = "snapshots"


def snapshot_path(work_dir: Path, step: int) -> Path:
    """Where the weights after optimiser step `step` are kept (`snapshots/step_NNNNNNN.pt`)."""
    return Path(work_dir) / SNAPSHOT_DIR / f"step_{int(step):07d}.pt"


def save_snapshot(work_dir: Path, step: int, simulator: str, config_digest: str, meshes: str, model_state: dict[str, Any]) -> Path:
    """Write the model weights (with the normalisers' statistics) after `step`, atomically; returns the path."""
    path = snapshot_path(work_dir, step)
    _write(path, simulator, config_digest, meshes, step=int(step), model=model_state)
    return path


def list_snapshots(work_dir: Path) -> list[tuple[int, Path]]:
    """(step, path) of the snapshots in `work_dir`, by step."""
    folder = Path(work_dir) / SNAPSHOT_DIR
    found = []
    for path in folder.glob("step_*.pt") if folder.is_dir() else []:
        try:
            found.append((int(path.stem.split("_", 1)[1]), path))
        except ValueError:
            continue
    return sorted(found)


def load_snapshot(path: Path, simulator: str, config_digest: str, meshes: str) -> dict[str, Any]:
    """The model weights of a snapshot, after the same checks as `load_checkpoint`."""
    hint = "delete the snapshots folder to take them again"
    payload = _read(path, "snapshot", "model", hint)
    for key, want in (("simulator", simulator), ("config_digest", config_digest), ("mesh_digest", meshes)):
        if payload.get(key) != want:
            raise ClodsError(f"snapshot {key} {payload.get(key)!r} differs from this run's {want!r}", where=str(path), hint=hint)
    return payload["model"]


def _write(path: Path, simulator: str, config_digest: str, meshes: str, **content: Any) -> None:
    """Save a checkpoint or snapshot payload (format, owner, digests and `content`) and its SHA-256 in one atomic rename."""
    payload = {"format": CHECKPOINT_FORMAT, "simulator": simulator, "config_digest": config_digest, "mesh_digest": meshes, **content}
    integrity.save_torch(payload, path)


def _read(path: Path, kind: str, content_key: str, hint: str) -> dict[str, Any]:
    """A payload `_write` saved, holding `content_key`; one ClodsError naming the file if it is unreadable, changed since
    it was written, or foreign."""
    integrity.check_zip(path, hint)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same clear message
        raise ClodsError(f"unreadable {kind} ({type(exc).__name__}: {exc})", where=str(path), hint=hint) from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT or content_key not in payload:
        raise ClodsError(f"not a clods-bench learned-simulator {kind} (format mismatch)", where=str(path), hint=hint)
    return payload
