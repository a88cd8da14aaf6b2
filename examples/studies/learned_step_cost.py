"""Training-step time of learned simulators at a preset's sizes: the preset's options on its flag, one thread.

Builds each simulator from the preset's `sim_config`, trains it on a simulated flag of the preset's resolution
(batch as the preset says, its warm-up skipped) and reports the median wall time of the optimiser steps after the
first few, in milliseconds, per simulator; simulators are timed in turns so that a busy machine slows all alike.
Run it on two checkouts (PYTHONPATH) to compare a change's cost.

    PYTHONPATH=. python examples/studies/learned_step_cost.py ci mgn bsms dhmp --steps 60 --rounds 3
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.types import Trajectory
from clods_bench.plugins.simulators.learned.trainer import Trainer, TrainingData


def _number(text: str) -> int | float | str:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("preset")
    parser.add_argument("sims", nargs="+")
    parser.add_argument("--steps", type=int, default=60, help="timed optimiser steps per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SIM.FIELD=VALUE",
                        help="override one option of a simulator's preset config, e.g. dhmp.latent_size=56")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = load_config(args.preset, None, [])
    nx, ny = cfg.data.resolution
    mesh = make_flag_mesh(nx, ny)
    frames = ClothSolver(mesh, SolverParams(), 0.02).simulate(mesh.rest_pos, np.zeros_like(mesh.rest_pos), 12)
    traj = Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, frames.astype(np.float32), 0.02)
    overrides: dict[str, dict] = {}
    for item in args.overrides:
        key, value = item.split("=", 1)
        name, field = key.split(".", 1)
        overrides.setdefault(name, {})[field] = _number(value)
    registry = default_registry()
    trainers = {}
    for name in args.sims:
        spec = registry.get("simulator", name)
        options = {**cfg.sim_config.get(name, {}), **overrides.get(name, {}), "warmup_steps": 0, "num_threads": 1}
        config = spec.make_config(options, where=f"sim_config.{name}")
        sim = spec.build(config, SimpleNamespace(scene=SimpleNamespace(name="flag", has_obstacles=False, has_handles=True), seed=0, work_dir=Path("."), progress=False))
        trainer = Trainer(sim.build_model(0), config, TrainingData([traj], sim.cache, 1), seed=0)
        for _ in range(5):
            trainer.train_step()  # first calls: allocation, hierarchy caches
        trainers[name] = (trainer, [])
    for _ in range(args.rounds):
        for name, (trainer, times) in trainers.items():
            for _ in range(args.steps):
                t0 = time.perf_counter()
                trainer.train_step()
                times.append(time.perf_counter() - t0)
    for name, (trainer, times) in trainers.items():
        params = sum(p.numel() for p in trainer.model.parameters())
        print(f"{name:6s} {1000 * statistics.median(times):7.2f} ms per step (median of {len(times)}), {params} parameters, "
              f"batch {trainer.config.batch_size}, mesh {nx}x{ny}")  # fmt: skip


if __name__ == "__main__":
    main()
