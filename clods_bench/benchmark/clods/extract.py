"""Stage 2 (paper eq. 6-7, Algorithm S1): recover the mesh of every frame from the video through the renderer.

For t = 0, 1, ...: start from the mesh of frame t (or extrapolated by its velocity, or a pretrained
simulator's one-step prediction: the predict step of Cloth-Splatting's filter), optimise vertex
offsets with Adam so that the render on the training cameras matches frame t+1 under
L1 + gamma * L_edge, edge lengths held to the initial mesh's. Non-NORMAL (handle) nodes stay at
their initial positions. A frame stops at the iteration cap or when the loss has not improved by
`rel_tolerance` for `patience` iterations (with `stop_requires_progress`, only once some iteration has
beaten the start's loss); the lowest-loss mesh seen is kept.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from rich.progress import Progress
from torch import Tensor

from clods_bench.benchmark.clods.cache import Extracted, ExtractionCache
from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.clods.edge import edge_lengths, edge_loss, mesh_edges
from clods_bench.benchmark.clods.prefetch import frames_ahead
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.datasets.types import NORMAL
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import torch_threads


@dataclass(frozen=True)
class FrameFit:
    """One frame's recovered mesh and its optimisation statistics."""

    verts: np.ndarray  # (V,3) float32
    iterations: int
    loss: float


@dataclass(frozen=True)
class MeshPrior:
    """What stays fixed over a trajectory: topology edges, rest lengths (initial mesh) and the free-node mask."""

    edges: Tensor  # (E,2) int64
    rest_lengths: Tensor  # (E,) float32, first-frame edge lengths (eq. 7's d(x_i0, x_j0))
    free: Tensor  # (V,1) float32: 1 at NORMAL nodes, 0 at handles

    @classmethod
    def from_mesh(cls, initial: np.ndarray, cells: np.ndarray, node_type: np.ndarray) -> "MeshPrior":
        """Edges and lengths of `initial` (V,3); handles are the non-NORMAL nodes of `node_type`."""
        edges = mesh_edges(cells)
        rest = edge_lengths(torch.as_tensor(initial, dtype=torch.float32), edges)
        free = torch.as_tensor(np.asarray(node_type) == NORMAL, dtype=torch.float32)[:, None]
        return cls(edges, rest, free)

    def to(self, device: torch.device) -> "MeshPrior":
        """The same prior with its tensors on `device`."""
        return MeshPrior(self.edges.to(device), self.rest_lengths.to(device), self.free.to(device))


def frame_target(frame: np.ndarray, device: torch.device) -> Tensor:
    """(N,H,W,3) uint8 views of one frame as float32 in [0, 1] on `device`: converted on the host for the CPU (the
    numbers stage 2 always had), moved as uint8 and converted there for a GPU (a quarter of the bytes)."""
    if device.type == "cpu":
        return torch.from_numpy(np.asarray(frame, dtype=np.float32) / 255.0)
    return torch.from_numpy(np.array(frame)).to(device).float() / 255.0


def renderer_device(renderer: Any) -> torch.device:
    """Where `renderer` keeps its fitted tensors (its `device` attribute; the CPU for renderers without one)."""
    device = getattr(renderer, "device", None)
    return device if isinstance(device, torch.device) else torch.device("cpu")


def fit_frame(renderer: Any, cameras: Sequence[Any], target: Tensor, start: Tensor, prior: MeshPrior, cfg: ClodsConfig) -> FrameFit:
    """Optimise offsets of the free nodes of `start` (V,3) so the render matches `target` (N,H,W,3) in [0,1].

    Runs on the renderer's device: on a GPU the target, the offsets, the L1 and the edge loss stay there, so an
    iteration moves no image between host and GPU (at the paper's 25 views of 800 px that round trip, 192 MB each
    way plus an L1 on the CPU, took about 0.26 s of a 0.29 s iteration on an H200)."""
    dev = renderer_device(renderer)
    target, start, prior = target.to(dev), start.to(dev), prior.to(dev)
    offset = torch.zeros_like(start, requires_grad=True)
    opt = torch.optim.Adam([offset], lr=cfg.learning_rate)
    best, best_x, best_seen, stale, it = math.inf, start.detach().clone(), math.inf, 0, 0
    progressed = not cfg.stop_requires_progress  # until an iteration beats the start, `best` is the start's loss
    for it in range(1, cfg.iterations + 1):
        for group in opt.param_groups:
            group["lr"] = cfg.learning_rate * cfg.lr_final_factor ** ((it - 1) / max(cfg.iterations - 1, 1))
        x = start + offset * prior.free
        with plugin_call("renderer", str(getattr(renderer, "name", type(renderer).__name__)), "render", renderer):
            image = renderer.render(x, cameras)
        loss = (image - target).abs().mean()
        if cfg.gamma > 0:
            loss = loss + cfg.gamma * edge_loss(x, prior.edges, prior.rest_lengths)
        value = float(loss.detach())
        if not math.isfinite(value):
            raise ClodsError(f"stage-2 loss became {value} at iteration {it}", where="clods stage 2", hint="lower task_config.clods.learning_rate")
        if value < best_seen:
            best_seen, best_x = value, x.detach().clone()
        if value < best * (1.0 - cfg.rel_tolerance):
            best, stale, progressed = value, 0, progressed or it > 1
        else:
            stale += 1
        if it >= max(cfg.min_iterations, 1) and stale >= cfg.patience and progressed:
            break
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return FrameFit(best_x.cpu().numpy().astype(np.float32), it, best_seen)


Predict = Callable[[np.ndarray], np.ndarray]  # meshes so far (k>=2,V,3) -> the next one (V,3)


def start_guess(done: np.ndarray, cfg: ClodsConfig, free: np.ndarray, predict: Predict | None = None) -> np.ndarray:
    """Starting mesh of the next frame from the meshes `done` (k,V,3) so far: the last one, velocity-extrapolated, or
    (start=simulator) `predict(done)`; with one mesh only (frame 1) the last one for 'previous' and 'simulator'."""
    last = done[-1]
    if cfg.start == "simulator":
        if predict is None:
            raise ClodsError("start=simulator needs the pretrained simulator's predict step", where="task_config.clods.start",
                             hint="it runs inside the CloDS pipeline with task_config.clods.variant=finetune")  # fmt: skip
        return predict(done) if done.shape[0] >= 2 else last.copy()
    if cfg.start == "velocity" and done.shape[0] >= 2:
        guess = last.copy()
        guess[free] = 2.0 * last[free] - done[-2][free]
        return guess
    return last.copy()


def extract_trajectory(
    renderer: Any,
    cameras: Sequence[Any],
    video: np.ndarray,
    initial: np.ndarray,
    cells: np.ndarray,
    node_type: np.ndarray,
    cfg: ClodsConfig,
    cache: ExtractionCache | None = None,
    index: int = 0,
    bar: Progress | None = None,
    predict: Predict | None = None,
) -> Extracted:
    """Meshes of frames 0..T-1 of `video` (T,N,H,W,3) uint8 seen by `cameras`, frame 0 being `initial` (V,3);
    `predict` is the start=simulator predict step (see `start_guess`).

    With a cache, a finished trajectory is read back, and a partial one resumes after its last frame;
    the partial file is rewritten after every frame.
    """
    if cache is not None and (done := cache.load(index)) is not None and done.num_frames == video.shape[0]:
        return done
    ext = cache.load(index, partial=True) if cache is not None else None
    if ext is None or ext.num_frames > video.shape[0]:
        ext = Extracted(np.asarray(initial, np.float32)[None], np.zeros(1, np.int64), np.full(1, np.nan), np.zeros(1))
    prior = MeshPrior.from_mesh(ext.world_pos[0], cells, node_type)
    free = np.asarray(node_type) == NORMAL
    job = bar.add_task(f"stage 2: trajectory {index}", total=video.shape[0] - 1, completed=ext.num_frames - 1, info="") if bar else None
    with torch_threads(cfg.num_threads):
        for t, frame in frames_ahead(video, ext.num_frames, video.shape[0], ahead=cfg.read_ahead):
            target = frame_target(frame, renderer_device(renderer))
            t0 = time.perf_counter()  # the frame's cost includes the predict step (start=simulator)
            start = torch.from_numpy(start_guess(ext.world_pos, cfg, free, predict))
            fit = fit_frame(renderer, cameras, target, start, prior, cfg)
            ext = ext.append(fit.verts, fit.iterations, fit.loss, time.perf_counter() - t0)
            if cache is not None:
                cache.save(index, ext, partial=True)
            if bar is not None and job is not None:
                bar.update(job, advance=1, info=f"{fit.iterations} it, loss {fit.loss:.4f}")
    if cache is not None:
        cache.save(index, ext)
    if bar is not None and job is not None:
        bar.remove_task(job)
    return ext


def stage2_stats(extracted: Sequence[Extracted], egt: np.ndarray | None, cached: int) -> dict[str, float]:
    """Stage 2's cost (per frame after frame 0) and extraction error (E-GT (B, frames); None without true meshes)."""
    seconds = np.concatenate([e.seconds[1:] for e in extracted])
    iters = np.concatenate([e.iterations[1:] for e in extracted])
    stats = {
        "stage2_seconds": float(seconds.sum()),
        "stage2_ms_per_frame": 1000.0 * float(seconds.mean()),
        "stage2_iterations_per_frame": float(iters.mean()),
        "stage2_frames": float(seconds.size),
        "stage2_cached_trajectories": float(cached),
    }
    if egt is not None:
        stats.update({"egt_rmse": float(egt[:, 1:].mean()), "egt_end": float(egt[:, -1].mean()), "egt_initial": float(egt[:, 0].mean())})
    return stats
