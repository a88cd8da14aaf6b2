"""Four tiny fits, one per model family, whose bits show whether two machines compute alike.

Each family trains for a few steps on synthetic data (no dataset, no solver) and is reduced to one SHA-256 of what it
learned: a graph net (MGN), a convolutional video predictor (SimVP), a splatting renderer fit (GaMeS on the CPU
splatting backend), and stage-2 mesh extraction through that renderer. In deterministic mode the four digests are the
same on every x86-64 CPU with AVX2 (`tests/test_deterministic_mode.py` holds them against committed values); on
the host's own paths they move with the CPU. `clods-bench numerics --probe` prints them.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from clods_bench.benchmark.core import stage_digests

FAMILIES = ("graph net", "video predictor", "renderer fit", "extraction")


def _flag(nx: int = 6, ny: int = 4, frames: int = 10) -> Any:
    """A small flag trajectory: the rest mesh swaying and rippling analytically (pole nodes kept still)."""
    from clods_bench.datasets.meshes import make_flag_mesh
    from clods_bench.datasets.types import NORMAL, Trajectory

    mesh = make_flag_mesh(nx, ny, 1.0, 0.5)
    rest = np.asarray(mesh.rest_pos, np.float64)
    t = np.arange(frames, dtype=np.float64)[:, None] * 0.05
    x = rest[None, :, 0]
    free = (np.asarray(mesh.node_type) == NORMAL)[None, :]
    world = np.repeat(rest[None], frames, axis=0)
    world[..., 1] += free * 0.15 * x * np.sin(3.0 * x - 4.0 * t)
    world[..., 2] -= free * 0.05 * x**2 * (1.0 - np.cos(2.0 * t))
    return Trajectory(mesh.cells.astype(np.int32), mesh.mesh_pos.astype(np.float32), mesh.node_type.astype(np.int32),
                      world.astype(np.float32), 0.02, {"scene": "probe"})  # fmt: skip


def _cameras(size: int = 24) -> list[Any]:
    from clods_bench.datasets.cameras import camera_rig

    return camera_rig(3, np.array([0.5, 0.0, 0.25]), 2.2, size, size)


def _images(views: int, size: int, phase: float) -> np.ndarray:
    """(views, H, W, 3) float32 smooth colour fields in [0, 1] (a target with structure, not noise)."""
    yy, xx = np.meshgrid(np.linspace(0, 1, size), np.linspace(0, 1, size), indexing="ij")
    out = np.empty((views, size, size, 3), np.float32)
    for v in range(views):
        for c in range(3):
            out[v, :, :, c] = 0.5 + 0.4 * np.sin(3.0 * xx + 2.0 * yy * (c + 1) + v + phase)
    return out


def _build(kind: str, name: str, values: dict[str, Any], work: Path) -> Any:
    from clods_bench.benchmark.core.descriptors import BuildContext
    from clods_bench.benchmark.core.registry import default_registry

    registry = default_registry()
    spec = registry.get(kind, name)
    cfg = spec.make_config(values, where=f"probe {name}")
    return spec.build(cfg, BuildContext(scene=registry.get("scene", "flag"), seed=0, work_dir=work, progress=False))


def _digest(value: Any) -> str:
    with stage_digests.collecting() as d:
        stage_digests.record("fit", value)
    return d.result()["fit"]


def graph_net(work: Path) -> str:
    """MGN, latent 16, 2 message-passing steps, 12 optimiser steps on the synthetic flag."""
    from clods_bench.benchmark.core.interfaces import FitContext

    sim = _build("simulator", "mgn", {"latent_size": 16, "message_passing_steps": 2, "train_steps": 15, "warmup_steps": 3,
                                       "batch_size": 2, "learning_rate": 1e-3, "checkpoint_every": 1000}, work)  # fmt: skip
    sim.fit([_flag()], FitContext(work_dir=work / "mgn", seed=0, progress=False))
    return _digest(sim)


def video_predictor(work: Path) -> str:
    """SimVP, 8/16 channels, 2 blocks, 6 optimiser steps on smooth synthetic videos of 24 px."""
    from clods_bench.benchmark.core.interfaces import FitContext

    pred = _build("video_predictor", "simvp", {"context_frames": 3, "hid_s": 8, "hid_t": 16, "enc_layers": 2, "trans_layers": 2,
                                                "groups": 2, "train_steps": 6, "batch_size": 2, "checkpoint_every": 1000}, work)  # fmt: skip
    videos = [np.stack([_images(1, 24, 0.3 * k + v)[0] for k in range(8)]) for v in range(3)]
    pred.fit(videos, FitContext(work_dir=work / "simvp", seed=0, progress=False))
    return _digest(pred)


def _renderer(work: Path) -> tuple[Any, Any, list[Any]]:
    traj, cams = _flag(), _cameras()
    renderer = _build("renderer", "games", {"gaussians_per_face": 2, "iterations": 8}, work)
    renderer.fit(traj.world_pos[:1], traj.cells, traj.mesh_pos, _images(len(cams), 24, 0.0)[None], cams)
    return renderer, traj, cams


def renderer_fit(work: Path) -> str:
    """GaMeS, 2 Gaussians per face, 8 iterations on one frame of 3 synthetic views (CPU splatting backend)."""
    renderer, _, _ = _renderer(work)
    return _digest(renderer)


def extraction(work: Path) -> str:
    """Stage 2: two frames' vertex offsets optimised through the GaMeS renderer above (4 iterations each)."""
    import dataclasses

    import torch

    from clods_bench.benchmark.clods.config import ClodsConfig
    from clods_bench.benchmark.clods.extract import extract_trajectory

    renderer, traj, cams = _renderer(work)
    with torch.no_grad():
        frames = [renderer.render(torch.from_numpy(traj.world_pos[t]), cams).numpy() for t in range(3)]
    video = (np.clip(np.stack(frames), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    opts = dataclasses.replace(ClodsConfig(), iterations=4, min_iterations=2)
    ext = extract_trajectory(renderer, cams, video, traj.world_pos[0], traj.cells, traj.node_type, opts)
    return _digest(ext.world_pos)


PROBES: dict[str, Callable[[Path], str]] = {"graph net": graph_net, "video predictor": video_predictor, "renderer fit": renderer_fit,
                                            "extraction": extraction}  # fmt: skip


def probe(families: tuple[str, ...] = FAMILIES) -> dict[str, dict[str, Any]]:
    """{family: {'digest', 'seconds'}} of each family's tiny fit, every one seeded alike, in the exact scope unless
    host paths are asked for."""
    from clods_bench import numerics
    from clods_bench.benchmark.core.determinism import seed_everything

    out = {}
    with numerics.maybe_exact():
        for family in families:
            seed_everything(0)
            t0 = time.perf_counter()
            with tempfile.TemporaryDirectory(prefix="clods-probe-") as tmp:
                digest = PROBES[family](Path(tmp))
            out[family] = {"digest": digest, "seconds": round(time.perf_counter() - t0, 2)}
    return out
