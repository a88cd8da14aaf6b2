"""Fit-iteration speed of the mesh renderers at the paper's sizes, CPU against the GPU (gsplat, device cuda).

Scene: the FLAGSIMPLE-size flag (1579 nodes, 3028 faces) bent by a fixed wave, 5 Gaussians per face
(15140), `--views` training cameras of `--size` px (paper: 25 of 30 cameras at 800x800). Targets are the
images of a randomised GaMeS. Timed per renderer and setup: one Adam iteration of `fit` (render all
views, (1-l) L1 + l D-SSIM, backward, step), and one stage-2 step (render, L1, backward to the
vertices), each after a warm-up. Prints ms per iteration and the CPU / GPU ratio measured in this run.

    python examples/gpu/paper_size_fit.py --size 800 --views 25 --iterations 10 [--json rows.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.table import Table

from clods_bench.datasets.meshes import make_flagsimple_mesh
from clods_bench.plugins.renderers.games import GamesConfig, GamesRenderer
from clods_bench.plugins.renderers.smgs import SmgsConfig, SmgsRenderer
from clods_bench.splatting.flag_scene import bench_scene, wavy_flag_vertices

RENDERERS = {"games": (GamesRenderer, GamesConfig), "smgs": (SmgsRenderer, SmgsConfig)}
SETUPS = {"cpu": {"device": "cpu", "backend": "cpu"}, "gpu": {"device": "cuda", "backend": "gsplat"}}


def sync() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def targets(verts: np.ndarray, cells: np.ndarray, mesh_pos: np.ndarray, cameras: list, setup: dict) -> np.ndarray:
    """(1,N,H,W,3) images of a GaMeS with random colours, scales and opacities."""
    r = GamesRenderer(GamesConfig(iterations=0, **setup))
    r.fit(verts[None], cells, mesh_pos, np.ones((1, len(cameras), cameras[0].height, cameras[0].width, 3), np.float32), cameras)
    g = torch.Generator().manual_seed(0)
    for name, p in r.params.items():
        p.copy_({"color": torch.rand(p.shape, generator=g), "log_scale": torch.rand(p.shape, generator=g) - 0.5,
                 "opacity_logit": torch.rand(p.shape, generator=g) * 4}.get(name, p.cpu()).to(p.device))  # fmt: skip
    with torch.no_grad():
        return r.render(torch.tensor(verts, dtype=torch.float32), cameras).cpu().numpy()[None].astype(np.float32)


def time_setup(name: str, setup: dict, verts, cells, mesh_pos, images, cameras, iterations: int) -> dict:
    """ms per fit iteration and per stage-2 step (vertices optimised through the renderer)."""
    cls, cfg = RENDERERS[name]
    cls(cfg(iterations=2, **setup)).fit(verts[None], cells, mesh_pos, images, cameras)  # warm-up: kernels, allocator
    r = cls(cfg(iterations=iterations, **setup))
    sync()
    t0 = time.perf_counter()
    stats = r.fit(verts[None], cells, mesh_pos, images, cameras)
    sync()
    fit_ms = 1e3 * (time.perf_counter() - t0) / max(iterations, 1)
    target = torch.from_numpy(images[0]).to(r.device)
    v = torch.tensor(verts, dtype=torch.float32, device=r.device, requires_grad=True)
    steps = []
    for _ in range(iterations + 1):
        sync()
        t0 = time.perf_counter()
        loss = (r.render(v, cameras) - target).abs().mean()
        loss.backward()
        sync()
        steps.append(1e3 * (time.perf_counter() - t0))
    return {"fit_ms": fit_ms, "stage2_ms": float(np.median(steps[1:])), "loss_final": stats["loss_final"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=800)
    ap.add_argument("--views", type=int, default=25)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--renderers", nargs="+", default=list(RENDERERS), choices=list(RENDERERS))
    ap.add_argument("--setups", nargs="+", default=list(SETUPS), choices=list(SETUPS))
    ap.add_argument("--json", type=Path, help="also write the rows (and the sizes) to this JSON file")
    args = ap.parse_args()
    verts, cells = wavy_flag_vertices()
    mesh_pos = np.asarray(make_flagsimple_mesh().mesh_pos, np.float64)
    _, cameras = bench_scene(0, args.size, args.views)
    images = targets(verts, cells, mesh_pos, cameras, SETUPS[args.setups[-1]])
    console = Console()
    table = Table(title=f"fit speed: flag 1579 nodes, 15140 Gaussians, {args.views} views {args.size}x{args.size}, "
                        f"{torch.get_num_threads()} CPU threads" + (f", {torch.cuda.get_device_name()}" if torch.cuda.is_available() else ""))  # fmt: skip
    for col in ("renderer", "setup", "fit ms / iteration", "stage-2 ms / step", "final loss", "cpu / this (fit)"):
        table.add_column(col, justify="right")
    out = []
    for name in args.renderers:
        rows = {s: time_setup(name, SETUPS[s], verts, cells, mesh_pos, images, cameras, args.iterations) for s in args.setups}
        for s, r in rows.items():
            ratio = f"{rows['cpu']['fit_ms'] / r['fit_ms']:.1f}x" if "cpu" in rows else ""
            table.add_row(name, f"{s} ({SETUPS[s]['backend']})", f"{r['fit_ms']:.1f}", f"{r['stage2_ms']:.1f}", f"{r['loss_final']:.4f}", ratio)
            out.append({"renderer": name, "setup": s, **SETUPS[s], **r})
    console.print(table)
    if args.json is not None:
        sizes = {"views": args.views, "size": args.size, "iterations": args.iterations, "cpu_threads": torch.get_num_threads(),
                 "gpu": torch.cuda.get_device_name() if torch.cuda.is_available() else None}  # fmt: skip
        args.json.write_text(json.dumps({**sizes, "rows": out}, indent=1))


if __name__ == "__main__":
    main()
