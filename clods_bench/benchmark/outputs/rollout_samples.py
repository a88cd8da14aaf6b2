"""Rollout samples: one trajectory's rollout and its ground truth, saved per seed for the report's videos and 3D views.

A CDG or stability seed saves `rollout_meshes.npz` (a mesh sample, `mesh_pictures.save_mesh_sample`, so the report
also draws it as a picture) with the trajectory's topology beside the frames: `mesh_pos` and `node_type` give the
scene's rest shape back (edge strain, the cloth/obstacle split), `trajectory` names the rolled-out trajectory
("unviewed/4") so that rows of one table rolled out on the same trajectory are watched together.
"""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clods_bench.benchmark.outputs.mesh_pictures import INFO_PREFIX, load_mesh_sample, save_mesh_sample
from clods_bench.errors import ClodsError

ROLLOUT_FILE = "rollout_meshes.npz"
"""The seed-directory file of a CDG or stability run's rollout sample."""


@dataclass(frozen=True)
class RolloutSample:
    """One saved rollout: predicted frames (T,V,3), the truth over the same frames when known, the topology."""

    path: Path
    cells: np.ndarray
    pred: np.ndarray
    truth: np.ndarray | None
    trajectory: str
    mesh_pos: np.ndarray | None
    node_type: np.ndarray | None
    dt: float
    marks: list[int]
    title: str

    @property
    def num_frames(self) -> int:
        """Frames of the rollout (frames 0 and 1 are the given ones)."""
        return int(self.pred.shape[0])


def save_rollout_sample(path: Path, label: str, pred: np.ndarray, truth: np.ndarray | None, cells: np.ndarray, mesh_pos: np.ndarray,
                        node_type: np.ndarray, dt: float, trajectory: str, marks: Sequence[int] = (), title: str = "") -> Path:  # fmt: skip
    """Write a rollout sample atomically: `pred` (T,V,3), `truth` (T',V,3) with T' >= T or None, and the topology."""
    extra = {"mesh_pos": np.asarray(mesh_pos, np.float32), "node_type": np.asarray(node_type, np.int32).reshape(-1),
             "dt": np.asarray(float(dt)), "trajectory": np.asarray(str(trajectory))}  # fmt: skip
    return save_mesh_sample(path, cells, {label: pred}, truth=None if truth is None else truth[: len(pred)], marks=marks, title=title,
                            extra=extra)  # fmt: skip


def load_rollout_sample(path: Path) -> RolloutSample:
    """The rollout sample at `path`; a file that is not one (unreadable, no frames, shapes that disagree) is a
    ClodsError naming it. A sample written without topology (before it was saved) loads with None in its place."""
    path = Path(path)
    if not path.is_file():
        raise ClodsError("the rollout sample is missing", where=str(path))
    if not zipfile.is_zipfile(path):
        raise ClodsError("not a readable rollout sample (not an .npz archive)", where=str(path))
    try:
        cells, meshes, truth, marks, title = load_mesh_sample(path)
        with np.load(path) as z:
            info = {k[len(INFO_PREFIX) :]: z[k] for k in z.files if k.startswith(INFO_PREFIX)}
    except (OSError, KeyError, ValueError, EOFError) as exc:
        raise ClodsError(f"not a readable rollout sample ({type(exc).__name__}: {exc})", where=str(path)) from None
    if len(meshes) != 1:
        raise ClodsError(f"a rollout sample holds one predicted sequence, this one {len(meshes)}", where=str(path))
    pred = np.asarray(next(iter(meshes.values())), np.float64)
    if pred.ndim != 3 or pred.shape[2] != 3 or pred.shape[0] < 1:
        raise ClodsError(f"predicted frames have shape {pred.shape}, expected (T, V, 3)", where=str(path))
    if truth is not None and (truth.shape[1:] != pred.shape[1:] or len(truth) < len(pred)):
        raise ClodsError(f"truth of shape {truth.shape} does not cover the prediction's {pred.shape}", where=str(path))
    cells = np.asarray(cells, np.int64)
    if cells.ndim != 2 or cells.shape[1] != 3 or (cells.size and (cells.min() < 0 or cells.max() >= pred.shape[1])):
        raise ClodsError(f"cells of shape {cells.shape} do not index the {pred.shape[1]} nodes", where=str(path))
    trajectory = str(info["trajectory"]) if "trajectory" in info else _trajectory_from_title(title)
    return RolloutSample(
        path=path, cells=cells, pred=pred, truth=None if truth is None else np.asarray(truth[: len(pred)], np.float64), trajectory=trajectory,
        mesh_pos=info["mesh_pos"].astype(np.float64) if "mesh_pos" in info else None,
        node_type=info["node_type"].astype(np.int64) if "node_type" in info else None,
        dt=float(info["dt"]) if "dt" in info else 1.0, marks=marks, title=title,
    )  # fmt: skip


def _trajectory_from_title(title: str) -> str:
    """'unviewed/4' from an older CDG sample's title ('mgn: rollout of unviewed trajectory 4, seed 0'); '?' if absent."""
    words = title.replace(",", " ").split()
    for k, word in enumerate(words[:-2]):
        if word in ("viewed", "unviewed") and words[k + 1] == "trajectory" and words[k + 2].isdigit():
            return f"{word}/{words[k + 2]}"
    return "?"
