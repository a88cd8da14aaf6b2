"""Validation sweep behind SMGS's defaults: GaMeS and SMGS opacity variants on the TRAINING trajectories.

Protocol of Table 3 (fit on frame 0 with the training cameras, drive by the true meshes, score the held-out
cameras at frames 0, 5, 10, 15), but on the training split, so choosing defaults never looks at the test
trajectories that Table 3 scores. Prints held-out PSNR (dB) per frame, the mean, and the mean per trajectory.

    python examples/studies/smgs_opacity_sweep.py data/flag-8dc5cfd642 [variant ...]

Variants: games, smgs (current defaults), smgs-mesh, smgs-old (world_freqs 4, lr_mlp 0.005, no grid: the
defaults before the sweep), smgs-old-lr (those with lr_mlp 0.02).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import torch

from clods_bench.benchmark.scoring.image_metrics import psnr
from clods_bench.datasets.splits import spread
from clods_bench.datasets.store import DatasetStore
from clods_bench.plugins.renderers.games import GamesConfig, GamesRenderer
from clods_bench.plugins.renderers.smgs import SmgsConfig, SmgsRenderer

VARIANTS = {
    "games": lambda: GamesRenderer(GamesConfig(), seed=0),
    "smgs": lambda: SmgsRenderer(SmgsConfig(), seed=0),
    "smgs-mesh": lambda: SmgsRenderer(SmgsConfig(inputs="mesh"), seed=0),
    "smgs-old": lambda: SmgsRenderer(SmgsConfig(world_freqs=4, lr_mlp=0.005, mesh_grid=0), seed=0),
    "smgs-old-lr": lambda: SmgsRenderer(SmgsConfig(world_freqs=4, lr_mlp=0.02, mesh_grid=0), seed=0),
}
FRAMES = (0, 5, 10, 15)
HELD_OUT = 5  # of the 30-camera rig, as Table 3


def main(root: Path, names: list[str]) -> None:
    """Fit each variant on every training trajectory and print its held-out PSNR."""
    torch.set_num_threads(1)
    store = DatasetStore.open(root)
    cams = store.cameras()
    test = spread(len(cams), HELD_OUT)
    train = [c for c in range(len(cams)) if c not in test]
    trajs = store.indices("train")
    print(f"training trajectories {trajs}, held-out cameras {test}, frames {list(FRAMES)}", flush=True)
    for name in names:
        t0, rows = time.perf_counter(), []
        for i in trajs:
            traj, video = store.load_trajectory(i), store.load_frames(i).astype(np.float32) / 255.0
            renderer = VARIANTS[name]()
            renderer.fit(traj.world_pos[0][None], traj.cells, traj.mesh_pos, video[0][train][None], [cams[c] for c in train])
            row = []
            for t in FRAMES:
                with torch.no_grad():
                    out = renderer.render(traj.world_pos[t].astype(np.float32), [cams[c] for c in test]).numpy()
                row.append(np.mean([psnr(np.clip(out[k], 0, 1), video[t][c]) for k, c in enumerate(test)]))
            rows.append(row)
        m = np.mean(rows, axis=0)
        per_traj = " ".join(f"{np.mean(r):.3f}" for r in rows)
        print(f"{name:12s} " + " ".join(f"{v:6.3f}" for v in m) + f"  mean {m.mean():.3f}  per trajectory {per_traj}  ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2:] or list(VARIANTS))
