"""Position, velocity and acceleration error of stage-2 extractions against the true meshes.

E-GT scores positions only, but stage 3 trains a simulator on the extracted meshes' accelerations (MGN predicts
x_{t+1} - 2 x_t + x_{t-1}): a setting that lowers E-GT while making the meshes jitter from frame to frame gives it
worse training data. This prints, for every extraction cache under the given runs folders (finished or partial
`clods_cache/<key>/traj_<i>.npz`, trajectory i of the dataset), the per-coordinate RMSE of positions, of first
differences (velocity per frame) and of second differences (acceleration per frame^2), with the true
accelerations' RMS for scale, over the first `--frames` frames (all by default).

    python examples/studies/extraction_derivatives.py data/flag-1ecc5d22ea runs-old runs-new
    python examples/studies/extraction_derivatives.py data/flag-1ecc5d22ea runs-old --smooth 5:3 --smooth 7:2

`--smooth W:O` (repeatable) also scores each extraction after the Savitzky-Golay filter stage 3 applies with
`task_config.clods.smooth_window=W`, `smooth_order=O` (`clods_bench.benchmark.clods.smooth`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from clods_bench.benchmark.clods.smooth import savgol_positions
from clods_bench.datasets.obstacle_nodes import cloth_nodes
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import NORMAL


def rms(a: np.ndarray) -> float:
    """Root mean square of every entry."""
    return float(np.sqrt(np.mean(np.square(a))))


def derivative_errors(extracted: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Per-coordinate RMSE of positions, first and second time differences (T,V,3 each), and the truth's accel RMS."""
    x, t = np.asarray(extracted, np.float64), np.asarray(truth, np.float64)
    ax, at = np.diff(x, 2, axis=0), np.diff(t, 2, axis=0)
    return {
        "pos": rms(x - t),
        "vel": rms(np.diff(x, axis=0) - np.diff(t, axis=0)),
        "acc": rms(ax - at),
        "true_acc": rms(at),
        # least-squares gain of the extracted accelerations on the true ones: below 1, the extraction damps the motion
        # (a bias a learner inherits); the rest of the error is noise, which averages out in a regression
        "acc_gain": float(np.sum(ax * at) / max(np.sum(at * at), 1e-30)),
    }


def settings(key: Path) -> str:
    """The stage-2 step and early-stop rule a cache was made with, from its meta.json (the cache key's identity)."""
    try:
        clods = json.loads((key / "meta.json").read_text())["identity"]["clods"]
    except (OSError, KeyError, ValueError):
        return "settings unknown"
    return f"learning_rate {clods.get('learning_rate')}, stop_requires_progress {clods.get('stop_requires_progress', False)}"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset", type=Path, help="the dataset folder the extractions read")
    p.add_argument("runs", type=Path, nargs="+", help="runs folders (or clods_cache folders) holding extraction caches")
    p.add_argument("--frames", type=int, default=None, help="score only the first N frames of each trajectory")
    p.add_argument("--smooth", action="append", default=[], metavar="W:O", help="also score after smoothing (window W, order O)")
    args = p.parse_args()
    filters = [(0, 0)] + [tuple(int(v) for v in spec.split(":")) for spec in args.smooth]
    store = DatasetStore.open(args.dataset)
    for runs in args.runs:
        for key in sorted({f.parent for f in runs.glob("**/traj_*.npz")}):
            for window, order in filters:
                scores = []
                for f in sorted(key.glob("traj_*.npz")):
                    truth = store.load_trajectory(int(f.name.split("_")[1][:4]))
                    with np.load(f) as z:
                        world = z["world_pos"]
                    n = min(len(world), args.frames or len(world))
                    if window:
                        world = savgol_positions(world[:n], np.asarray(truth.node_type) == NORMAL, window, order)
                    nodes = cloth_nodes(truth.node_type)
                    x, t = world[:n], truth.world_pos[:n]
                    if nodes is not None:
                        x, t = x[:, nodes], t[:, nodes]
                    scores.append(derivative_errors(x, t))
                mean = {k: float(np.mean([s[k] for s in scores])) for k in scores[0]}
                how = f", smoothed {window}:{order}" if window else ""
                print(f"{key} ({settings(key)}{how}): {len(scores)} trajectories, {n} frames: position {mean['pos']:.4f} m, velocity {mean['vel']:.4f} m/frame, "
                      f"acceleration {mean['acc']:.4f} m/frame^2 (true accelerations: RMS {mean['true_acc']:.4f}; gain on them {mean['acc_gain']:.3f})")  # fmt: skip


if __name__ == "__main__":
    main()
