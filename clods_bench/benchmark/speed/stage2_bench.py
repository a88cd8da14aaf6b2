"""`clods-bench bench stage2`: the cost of a CloDS stage-2 iteration (mesh extraction through the renderer).

At a preset's scale (default `ci`: its dataset, training cameras, image size and `task_config.clods`), the
renderer is fitted on frame 0 of training trajectory 0 (a short fit: `fit_iterations`), then stage 2
(`extract.fit_frame`, the code `run extract` runs) recovers frames 1..`frames` once per splatting backend,
each frame starting from the previous recovered meshes as in `extract_trajectory`. Reported per backend: ms
per iteration (render, L1 and edge loss, backward, Adam), iterations and ms per frame, and the time of one
render forward+backward alone; the torch reference backend is the baseline measured in the same run.
Iterations per frame depend on the fit: the extraction task (`run extract`) records the real ones.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from clods_bench.benchmark.clods.config import clods_config
from clods_bench.benchmark.clods.extract import MeshPrior, fit_frame, start_guess
from clods_bench.datasets.types import NORMAL
from clods_bench.numerics.thread_limits import torch_threads

if TYPE_CHECKING:
    from rich.console import Console

STAGE2_TARGET_MS = 5.0  # ms per stage-2 iteration at the ci preset


def _time_render(renderer, verts: torch.Tensor, cams: list, repeats: int) -> float:
    """Minimum ms of one render of `verts` and the backward of its mean to the vertices."""
    best = float("inf")
    for _ in range(repeats):
        x = verts.clone().requires_grad_(True)
        t0 = time.perf_counter()
        renderer.render(x, cams).mean().backward()
        best = min(best, 1e3 * (time.perf_counter() - t0))
    return best


def bench_stage2(preset: str = "ci", renderer_name: str = "smgs", frames: int = 6, fit_iterations: int = 60,
                 backends: tuple[str, ...] = ("cpu", "reference"), data_root: str | None = None) -> dict:  # fmt: skip
    """Time stage 2 on frames 1..`frames` of training trajectory 0 per backend; returns a dict for the CLI."""
    from clods_bench.benchmark.core.builders import build_renderer, split_spec
    from clods_bench.benchmark.core.config import load_config
    from clods_bench.benchmark.core.descriptors import TaskContext
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.benchmark.running.run_data import ensure_dataset

    overrides = [f"renderer_config.{renderer_name}.iterations={fit_iterations}"] + ([f"data.root={data_root}"] if data_root else [])
    cfg = load_config(preset, overrides=overrides, renderer=renderer_name)
    cfg = dataclasses.replace(cfg, progress=False)
    opts = clods_config(cfg)
    registry = default_registry()
    store = ensure_dataset(cfg, registry, progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        ctx = TaskContext(config=cfg, seed=0, work_dir=Path(tmp), registry=registry)
        views = list(split_spec(ctx).train_views)[: opts.num_cameras]
        renderer = build_renderer(ctx)
    cams = [store.cameras()[v] for v in views]
    traj = store.load_trajectory(0)
    video = np.asarray(store.load_frames(0)[: frames + 1, views])
    with torch_threads(opts.num_threads):
        renderer.fit(traj.world_pos[:1].astype(np.float32), traj.cells, traj.mesh_pos, video[:1].astype(np.float32) / 255.0, cams)
        prior = MeshPrior.from_mesh(traj.world_pos[0], traj.cells, traj.node_type)
        free = np.asarray(traj.node_type) == NORMAL
        result: dict = {"preset": preset, "renderer": renderer_name, "gaussians": renderer.num_gaussians, "views": len(cams),
                        "image": f"{cams[0].width}x{cams[0].height}", "vertices": int(traj.world_pos.shape[1]), "frames": frames,
                        "clods": {"iterations": opts.iterations, "min_iterations": opts.min_iterations, "patience": opts.patience,
                                  "start": opts.start}, "threads": torch.get_num_threads()}  # fmt: skip
        for backend in backends:
            renderer.config = dataclasses.replace(renderer.config, backend=backend)
            verts0 = torch.from_numpy(traj.world_pos[0].astype(np.float32))
            render_ms = _time_render(renderer, verts0, cams, repeats=10 if backend == "cpu" else 3)
            done = traj.world_pos[:1].astype(np.float32)
            seconds, iters = [], []
            for t in range(1, frames + 1):
                target = torch.from_numpy(video[t].astype(np.float32) / 255.0)
                start = torch.from_numpy(start_guess(done, opts, free))
                t0 = time.perf_counter()
                fit = fit_frame(renderer, cams, target, start, prior, opts)
                seconds.append(time.perf_counter() - t0)
                iters.append(fit.iterations)
                done = np.concatenate([done, fit.verts[None]])
            result[backend] = {"ms_per_iteration": 1e3 * sum(seconds) / sum(iters), "ms_per_frame": 1e3 * float(np.mean(seconds)),
                               "iterations_per_frame": float(np.mean(iters)), "render_fwd_bwd_ms": render_ms}  # fmt: skip
    return result


def print_bench_stage2(console: Console, **kwargs) -> dict:
    """Run `bench_stage2` with a status line and print its table."""
    from rich.table import Table

    with console.status("stage 2: fitting the renderer, then extracting frames per backend ..."):
        r = bench_stage2(**kwargs)
    backends = [b for b in ("cpu", "reference") if b in r]
    table = Table(title=(f"clods-bench bench stage2: {r['renderer']} at preset {r['preset']}: {r['gaussians']} Gaussians, "
                         f"{r['views']} views {r['image']}, {r['vertices']} vertices, frames 1-{r['frames']}, {r['threads']} threads"))  # fmt: skip
    for col in ["what", *backends] + (["reference / cpu"] if len(backends) == 2 else []) + ["target"]:
        table.add_column(col, justify="right")
    rows = (("ms per iteration", "ms_per_iteration", f"<= {STAGE2_TARGET_MS:.0f} (cpu)"), ("iterations per frame", "iterations_per_frame", ""),
            ("ms per frame", "ms_per_frame", ""), ("render fwd+bwd ms (min)", "render_fwd_bwd_ms", ""))  # fmt: skip
    for label, key, target in rows:
        ratio = [] if len(backends) < 2 else [""] if key == "iterations_per_frame" else [f"{r['reference'][key] / r['cpu'][key]:.1f}x"]
        table.add_row(label, *[f"{r[b][key]:.2f}" for b in backends], *ratio, target)
    console.print(table)
    console.print(f"stage-2 options: {r['clods']} (the renderer fitted {kwargs.get('fit_iterations', 60)} iterations on frame 0; "
                  "`clods-bench run extract` records the iterations of a full run)")  # fmt: skip
    return r
