"""Resumable training checkpoints, written atomically and checked against the run that loads them.

A checkpoint records the simulator name, the config digest and the digest of the training
meshes' topologies next to the trainer state; loading it into a different simulator, config
or mesh raises ClodsError instead of silently mixing incompatible weights.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Iterable

import torch

from clods_bench.atomic import atomic_path
from clods_bench.errors import ClodsError

CHECKPOINT_FORMAT = 1


def mesh_digest(topology_keys: Iterable[str]) -> str:
    """Order-independent digest of the set of mesh topologies a model was trained on."""
    return hashlib.sha256("\n".join(sorted(set(topology_keys))).encode()).hexdigest()[:16]


def save_checkpoint(path: Path, simulator: str, config_digest: str, meshes: str, trainer_state: dict[str, Any], extra: dict[str, Any]) -> None:
    """Write the checkpoint in one atomic rename (a crash leaves the previous one intact)."""
    payload = {
        "format": CHECKPOINT_FORMAT,
        "simulator": simulator,
        "config_digest": config_digest,
        "mesh_digest": meshes,
        "trainer": trainer_state,
        "extra": extra,
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_checkpoint(path: Path, simulator: str, config_digest: str, meshes: str) -> dict[str, Any]:
    """The checkpoint's payload, after checking it belongs to this simulator, config and meshes."""
    hint = "delete it (or use another work directory) to train from scratch"
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same clear message
        raise ClodsError(f"unreadable checkpoint ({type(exc).__name__}: {exc})", where=str(path), hint=hint) from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ClodsError("not a clods-bench learned-simulator checkpoint (format mismatch)", where=str(path), hint=hint)
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
