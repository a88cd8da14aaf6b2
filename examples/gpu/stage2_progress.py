"""How far stage 2 got: frames extracted, fit seconds per frame and iterations, read from the extraction cache.

Stage 2 rewrites `<runs>/clods_cache/<key>/traj_<i>.partial.npz` after every frame (and `traj_<i>.npz` when a video is
done), with each frame's fit seconds and iterations, so a run stopped by a time limit still tells its per-frame
cost. `paper_trajectory.sh` prints this when it exits, finished or not. With `--data` (the dataset folder the run
read) it also prints the extraction error E-GT (per-coordinate RMSE to the true mesh of trajectory i, m, as `run
extract` reports it) every `--every` frames, so a stopped run shows where the fit lost the cloth.

    python examples/gpu/stage2_progress.py paper-trajectory/runs
    python examples/gpu/stage2_progress.py paper-trajectory/runs --data paper-trajectory/data/flag-<hash>
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def progress(runs: Path) -> list[str]:
    """One line per extraction cache file under `runs`: frames, fit seconds (sum, per frame) and mean iterations."""
    lines = []
    for path in cache_files(runs):
        with np.load(path) as z:
            seconds, iterations = z["seconds"][1:], z["iterations"][1:]  # frame 0 is the initial mesh, not fitted
        state = "partial" if path.name.endswith(".partial.npz") else "done"
        per = seconds.mean() if seconds.size else float("nan")
        its = iterations.mean() if iterations.size else float("nan")
        lines.append(f"stage 2 {state}: {path.parent.name}/{path.name}: {seconds.size} frames fitted, {seconds.sum():.1f} s of fitting, "
                     f"{1000 * per:.1f} ms and {its:.1f} iterations per frame (fit only; reads not included)")  # fmt: skip
    return lines or [f"stage 2: no extraction cache under {runs}"]


def cache_files(runs: Path) -> list[Path]:
    """Every extraction cache file (finished or partial) under `runs`."""
    return sorted(runs.glob("**/clods_cache/*/traj_*.npz"))


def egt_curves(runs: Path, data: Path, every: int) -> list[str]:
    """E-GT of each cached extraction against the dataset's true meshes (the cache's traj_<i> is trajectory i)."""
    from clods_bench.benchmark.scoring.metrics import rmse_per_step
    from clods_bench.datasets.obstacle_nodes import cloth_nodes
    from clods_bench.datasets.store import DatasetStore

    store, lines = DatasetStore.open(data), []
    for path in cache_files(runs):
        index = int(path.name.split("_")[1].split(".")[0])
        truth = store.load_trajectory(index)
        with np.load(path) as z:
            world = z["world_pos"]
        egt = rmse_per_step(world, truth.world_pos[: world.shape[0]], cloth_nodes(truth.node_type))
        shown = " ".join(f"{t}:{egt[t]:.4f}" for t in range(0, egt.size, every))
        lines.append(f"E-GT (m) {path.parent.name}/{path.name}, frame:value every {every}: {shown}")
        lines.append(f"  mean over frames 1-{egt.size - 1}: {egt[1:].mean():.4f}, largest {egt.max():.4f} at frame {int(egt.argmax())}, "
                     f"last {egt[-1]:.4f}")  # fmt: skip
    return lines


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", type=Path, nargs="?", default=Path("paper-trajectory/runs"), help="the run's runs_dir")
    p.add_argument("--data", type=Path, help="the dataset folder the run read: also print E-GT curves")
    p.add_argument("--every", type=int, default=10, help="print E-GT every N frames")
    args = p.parse_args()
    print("\n".join(progress(args.runs)))
    if args.data is not None:
        print("\n".join(egt_curves(args.runs, args.data, max(args.every, 1))))
