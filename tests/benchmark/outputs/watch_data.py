"""Synthetic rollout records for the Watch tests: a small flag, its true motion, a rollout that tears at a known
frame and one that goes non-finite at a known frame, saved as a run would save them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from clods_bench.benchmark.outputs.rollout_samples import ROLLOUT_FILE, save_rollout_sample
from clods_bench.datasets.meshes import make_flag_mesh

FRAMES = 12
TEAR_AT = 6
NAN_AT = 9
MESH = make_flag_mesh(6, 3)


def truth_frames(frames: int = FRAMES) -> np.ndarray:
    """The flag waving gently: a travelling wave in y, small enough that no edge strains by more than a few per cent."""
    rest = MESH.rest_pos.astype(np.float64)
    t = np.arange(frames)[:, None]
    wave = 0.03 * np.sin(2.0 * rest[None, :, 0] - 0.5 * t) * rest[None, :, 0] / 2.0
    out = np.repeat(rest[None], frames, axis=0)
    out[:, :, 1] = wave
    return out


def tearing(frames: int = FRAMES, at: int = TEAR_AT) -> np.ndarray:
    """The truth, then from frame `at` the free end pulled away: edges there stretch to 1.8x (strain 0.8 > 0.5)."""
    out = truth_frames(frames)
    far = MESH.rest_pos[:, 0] > 1.5
    out[at:, far, 0] += 0.8 * 0.4 * (np.arange(frames - at)[:, None] + 1)
    return out


def exploding(frames: int = FRAMES, at: int = NAN_AT) -> np.ndarray:
    """The truth with a small drift (no tear), non-finite from frame `at`."""
    out = truth_frames(frames) + 0.002 * np.arange(frames)[:, None, None]
    out[at:] = np.nan
    return out


def write_record(runs: Path, task: str, label: str, pred: np.ndarray, truth: np.ndarray | None, trajectory: str = "unviewed/4",
                 result: dict[str, Any] | None = None, preset: str = "ci") -> tuple[Path, dict[str, Any]]:  # fmt: skip
    """A record folder with seed 0's rollout sample (and result.json when given); returns (folder, record dict)."""
    rdir = runs / task / label / f"flag-{preset}-0000"
    (rdir / "seed_0").mkdir(parents=True, exist_ok=True)
    save_rollout_sample(rdir / "seed_0" / ROLLOUT_FILE, label, pred, truth, MESH.cells, MESH.mesh_pos, MESH.node_type, 0.02, trajectory,
                        marks=[FRAMES // 2], title=f"{label}: synthetic")  # fmt: skip
    if result is not None:
        (rdir / "seed_0" / "result.json").write_text(json.dumps(result))
    rec = {"task": task, "label": label, "scene": "flag", "preset": preset, "seeds": [0], "metrics": {}, "timings": {}}
    (rdir / "record.json").write_text(json.dumps(rec))
    return rdir, rec
