"""Stage 1 (paper Algorithm S1, 'Gaussian component construction'): fit the mesh-driven renderer on first frames.

With several trajectories, all their first frames train one representation (paper appendix,
'Training details'). The fitted renderer is cached (pickled) under a digest of everything that
decides it, so a resumed or repeated run, and the DVC task, reuse it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from clods_bench import integrity
from clods_bench.atomic import file_lock, write_json
from clods_bench.benchmark.clods.config import ClodsConfig, clods_config
from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.cache_keys import digest
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.interfaces import Renderer
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import torch_threads


def cache_root(ctx: TaskContext, opts: ClodsConfig) -> Path:
    """Directory of the stage 1-2 cache: `task_config.clods.cache_dir` or `<runs_dir>/clods_cache`."""
    return Path(opts.cache_dir) if opts.cache_dir else Path(ctx.config.runs_dir) / "clods_cache"


def extraction_seed(ctx: TaskContext, opts: ClodsConfig) -> int:
    """Seed of stages 1-2: `task_config.clods.extraction_seed`, else the run's seed."""
    return ctx.seed if opts.extraction_seed is None else int(opts.extraction_seed)


def _sha(arr: np.ndarray) -> str:
    a = np.ascontiguousarray(arr)
    return hashlib.sha256(str((a.dtype.str, a.shape)).encode() + a.tobytes()).hexdigest()[:16]


def as_unit_images(images: Any) -> np.ndarray:
    """float32 images in [0,1] from uint8 (0..255) or float arrays."""
    arr = np.asarray(images)
    return arr.astype(np.float32) / 255.0 if arr.dtype == np.uint8 else arr.astype(np.float32)


def fit_stage1_keyed(
    ctx: TaskContext,
    initial: np.ndarray,
    cells: np.ndarray,
    mesh_pos: np.ndarray,
    images: np.ndarray,
    cameras: Sequence[Camera],
) -> tuple[Renderer, dict[str, float], str]:
    """Fit (or load from the cache) the run's renderer on meshes `initial` (B,V,3) and images (B,N,H,W,3); also return its digest."""
    from clods_bench.benchmark.core.builders import build_renderer

    cfg, opts = ctx.config, clods_config(ctx.config)
    if not cfg.renderer:
        raise ClodsError("the CloDS pipeline needs a mesh-driven renderer", where="--renderer", hint="e.g. --renderer smgs")
    seed = extraction_seed(ctx, opts)
    spec = ctx.registry.get("renderer", cfg.renderer)
    rcfg = spec.make_config(cfg.renderer_config.get(cfg.renderer, {}), where=f"renderer_config.{cfg.renderer}")
    unit = as_unit_images(images)
    key = digest({
        "renderer": cfg.renderer, "config": dataclasses.asdict(rcfg) if dataclasses.is_dataclass(rcfg) else repr(rcfg), "seed": seed,
        "verts": _sha(np.asarray(initial, np.float32)), "cells": _sha(np.asarray(cells)), "mesh_pos": _sha(np.asarray(mesh_pos, np.float32)),
        "images": _sha(unit), "cameras": [c.to_dict() for c in cameras],
    })  # fmt: skip
    path = cache_root(ctx, opts) / f"stage1-{key}.pt"
    cost_file = path.with_suffix(".json")  # the fit's recorded cost, so a cached fit still counts in training time
    with file_lock(path.with_suffix(".lock")):  # a parallel job fitting the same renderer: wait, then read its fit
        if path.exists():
            integrity.check_zip(path, "delete it to fit again")  # a fit changed since it was written is never used
            try:
                renderer = torch.load(path, map_location="cpu", weights_only=False)
            except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same clear message
                raise ClodsError(f"unreadable stage-1 cache file ({type(exc).__name__}: {exc})", where=str(path), hint="delete it to fit again") from None
            relocate = getattr(renderer, "relocate", None)  # tensors loaded on the CPU, back to the fit's device
            if callable(relocate):
                relocate()
            try:
                cost = float(json.loads(cost_file.read_text())["seconds"])
            except (OSError, ValueError, KeyError, TypeError):
                cost = float("nan")
            stage_digests.record("renderer fit", renderer)
            return renderer, {"stage1_seconds": 0.0, "stage1_cost_seconds": cost, "stage1_cached": 1.0}, key
        renderer = build_renderer(dataclasses.replace(ctx, seed=seed))
        if getattr(renderer, "per_frame", False):
            raise ClodsError("stage 2 needs a mesh-driven renderer, this one is fitted per frame", where=f"renderer '{cfg.renderer}'", hint="use smgs or games")
        t0 = time.perf_counter()
        with torch_threads(opts.num_threads), plugin_call("renderer", str(cfg.renderer), "fit", renderer):
            stats = renderer.fit(np.asarray(initial, np.float32), cells, mesh_pos, unit, list(cameras)) or {}
        seconds = time.perf_counter() - t0
        integrity.save_torch(renderer, path)
        write_json(cost_file, {"seconds": seconds})
        out = {"stage1_seconds": seconds, "stage1_cost_seconds": seconds, "stage1_cached": 0.0}
        out.update({f"stage1/{k}": float(v) for k, v in stats.items()})
        stage_digests.record("renderer fit", renderer)
        return renderer, out, key


def fit_stage1(
    ctx: TaskContext,
    trajectories: Sequence[Trajectory],
    frames_images: Any,
    cameras: Sequence[Camera],
    initial_meshes: np.ndarray | None = None,
) -> tuple[Renderer, dict[str, float]]:
    """Stage 1: one renderer fitted on the first frames `frames_images` (B,N,H,W,3, uint8 or [0,1]) of B trajectories.

    The meshes are the trajectories' frame 0, or `initial_meshes` (B,V,3) (e.g. with the robustness noise).
    Returns the renderer and {'stage1_seconds', 'stage1_cached', 'stage1/<fit statistic>'}.
    """
    if not trajectories:
        raise ClodsError("no trajectories to fit the renderer on", where="clods stage 1")
    first = trajectories[0]
    verts = np.stack([t.world_pos[0] for t in trajectories]) if initial_meshes is None else np.asarray(initial_meshes)
    renderer, stats, _ = fit_stage1_keyed(ctx, verts, first.cells, first.mesh_pos, frames_images, cameras)
    return renderer, stats
