"""How far stage 2 got: frames extracted, fit seconds per frame and iterations, read from the extraction cache.

Stage 2 rewrites `<runs>/clods_cache/<key>/traj_<i>.partial.npz` after every frame (and `traj_<i>.npz` when a video is
done), with each frame's fit seconds and iterations, so a run stopped by a time limit still tells its per-frame
cost. `paper_trajectory.sh` prints this when it exits, finished or not.

    python examples/gpu/stage2_progress.py paper-trajectory/runs
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def progress(runs: Path) -> list[str]:
    """One line per extraction cache file under `runs`: frames, fit seconds (sum, per frame) and mean iterations."""
    lines = []
    for path in sorted(runs.glob("**/clods_cache/*/traj_*.npz")):
        with np.load(path) as z:
            seconds, iterations = z["seconds"][1:], z["iterations"][1:]  # frame 0 is the initial mesh, not fitted
        state = "partial" if path.name.endswith(".partial.npz") else "done"
        per = seconds.mean() if seconds.size else float("nan")
        its = iterations.mean() if iterations.size else float("nan")
        lines.append(f"stage 2 {state}: {path.parent.name}/{path.name}: {seconds.size} frames fitted, {seconds.sum():.1f} s of fitting, "
                     f"{1000 * per:.1f} ms and {its:.1f} iterations per frame (fit only; reads not included)")  # fmt: skip
    return lines or [f"stage 2: no extraction cache under {runs}"]


if __name__ == "__main__":
    print("\n".join(progress(Path(sys.argv[1] if len(sys.argv) > 1 else "paper-trajectory/runs"))))
