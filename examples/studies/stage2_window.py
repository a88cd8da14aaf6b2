"""Stage 2 on a window of frames of one trajectory, started from the true meshes, to see where and why tracking fails.

The paper trajectory on one H200 (2026-11-27, results/gpu_h200/2026-11-27-paper-trajectory-and-video-bench/) lost
the cloth after frame 222, after the fastest motion of the video. This script fits frames START+1..END of trajectory 0
of a dataset with the stage-1 renderer a
CloDS run cached (`<runs_dir>/clods_cache/stage1-*.pt`), starting from the TRUE meshes of frames START-1 and START
(so drift from earlier frames is ruled out), on the training cameras, and prints each frame's E-GT (the RMS of the
nodes' distances to the true mesh, m: sqrt(3) times the per-coordinate RMSE that `run extract` reports; kept so that
the committed logs stay comparable), iterations and loss. `--set FIELD=VALUE` changes `task_config.clods` fields (iterations, min_iterations,
patience, learning_rate, start, ...) to compare remedies on the same frames.

    clods-bench data generate --preset paper --set data.num_train=2 --set data.num_test=1 --set data.frames=on_demand \\
        --set data.image_size=128 --set data.root=/tmp/egt/data
    clods-bench run extract --renderer smgs --train-subset first_half --preset paper --seeds 0 --set data.num_train=2 \\
        --set data.num_test=1 --set data.frames=on_demand --set data.image_size=128 --set data.root=/tmp/egt/data \\
        --set runs_dir=/tmp/egt/runs     # only its stage 1 is needed: stop it once clods_cache/stage1-*.pt exists
    python examples/studies/stage2_window.py /tmp/egt/data/flag-340dafa69c /tmp/egt/runs/clods_cache 200 216
    python examples/studies/stage2_window.py /tmp/egt/data/flag-340dafa69c /tmp/egt/runs/clods_cache 200 216 --set min_iterations=40
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.clods.extract import MeshPrior, fit_frame, frame_target, renderer_device, start_guess
from clods_bench.datasets.splits import spread
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import NORMAL


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset", type=Path, help="dataset folder (data/<scene>-<hash>)")
    p.add_argument("cache", type=Path, help="clods_cache folder holding one stage1-*.pt fitted on this dataset's trajectory 0")
    p.add_argument("start", type=int, help="the last frame given as truth")
    p.add_argument("end", type=int, help="the last frame fitted")
    p.add_argument("--held-out", type=int, default=5, help="held-out cameras of the rig (the preset's data.num_views_test)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="FIELD=VALUE", help="a task_config.clods field")
    args = p.parse_args()
    if not 1 <= args.start < args.end:
        raise SystemExit(f"need 1 <= start < end, got start {args.start}, end {args.end}")
    cfg = ClodsConfig(**{k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in args.sets)})
    cfg.validate()  # the pipeline's checks of the same fields (a field out of range: one error naming it)
    print({f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.name in ("iterations", "min_iterations", "patience", "learning_rate", "lr_final_factor", "start", "stop_requires_progress")})
    store = DatasetStore.open(args.dataset)
    cams_all = store.cameras()
    held = set(spread(len(cams_all), args.held_out))
    views = [v for v in range(len(cams_all)) if v not in held]
    cams = [cams_all[v] for v in views]
    truth = store.load_trajectory(0)
    stage1 = sorted(glob.glob(str(args.cache / "stage1-*.pt")))
    if len(stage1) != 1:
        raise SystemExit(f"{args.cache}: expected one stage1-*.pt, found {len(stage1)}")
    renderer = torch.load(stage1[0], map_location="cpu", weights_only=False)
    if callable(getattr(renderer, "relocate", None)):  # a renderer fitted on a GPU goes back there, as in stage 2
        renderer.relocate()
    video = store.frames(0).select(slice(0, args.end + 1), views)
    prior = MeshPrior.from_mesh(truth.world_pos[0], truth.cells, truth.node_type)  # rest lengths of frame 0, as stage 2
    free = np.asarray(truth.node_type) == NORMAL
    done = np.asarray(truth.world_pos[args.start - 1 : args.start + 1], np.float32)
    errors = []
    for t in range(args.start + 1, args.end + 1):
        t0 = time.perf_counter()
        target = frame_target(np.asarray(video[t]), renderer_device(renderer))
        fit = fit_frame(renderer, cams, target, torch.from_numpy(start_guess(done, cfg, free)), prior, cfg)
        done = np.concatenate([done, fit.verts[None]])
        errors.append(float(np.sqrt(((fit.verts - truth.world_pos[t]) ** 2).sum(-1).mean())))
        print(f"frame {t}: E-GT {errors[-1]:.4f} m, {fit.iterations} iterations, loss {fit.loss:.5f}, {time.perf_counter() - t0:.1f} s", flush=True)
    print(f"frames {args.start + 1}-{args.end}: mean E-GT {np.mean(errors):.4f} m, last {errors[-1]:.4f} m")


if __name__ == "__main__":
    main()
