"""Speed benchmark of the ground-truth cloth solver on the default flag scene, without or with an obstacle."""

from __future__ import annotations

import time

import numpy as np

from clods_bench.datasets.cloth_solver import ClothSolver
from clods_bench.datasets.obstacles import Obstacle, Sphere
from clods_bench.datasets.scenes import Resolution, draw_wind, get_scene, initial_state


BENCH_OBSTACLE = Sphere(center=(1.5, 0.0, 0.5), radius=0.22)
"""The obstacle of `bench_solver(obstacles=True)`: a ball in the path of the 2 m x 1 m flag, 1.5 m from its pole,
so the fluttering flag keeps hitting it (seed 0: it starts 4 cm from the cloth; 3-4% of the node-steps in contact)."""


def bench_solver(num_steps: int = 400, resolution: Resolution = "flagsimple", seed: int = 0, obstacles: bool = False) -> dict:
    """Time `num_steps` solver steps of the `flag` scene (after one untimed warm-up step for JIT).

    With `obstacles`, the cloth collides with `BENCH_OBSTACLE`; `contacts_per_step` says how many nodes touch it."""
    scene = get_scene("flag")
    mesh = scene.build_mesh(resolution)
    rng = np.random.default_rng(seed)
    x, v, _ = initial_state(scene, mesh, rng)
    params, _ = draw_wind(scene, rng)
    obstacle_list: list[Obstacle] = [BENCH_OBSTACLE] if obstacles else []
    solver = ClothSolver(mesh, params, scene.dt, seed=seed, obstacles=obstacle_list)
    solver.step(x, v, 0.0)  # compile / load the numba kernels outside the timing
    solver.stats.update(cg_iterations=0, steps=0, contacts=0, contact_projections=0)
    start = time.perf_counter()
    t = 0.0
    for _ in range(num_steps):
        x, v = solver.step(x, v, t)
        t += scene.dt
    total = time.perf_counter() - start
    return {
        "scene": scene.name,
        "resolution": resolution if isinstance(resolution, str) else list(resolution),
        "num_nodes": mesh.num_nodes,
        "num_faces": mesh.num_faces,
        "num_steps": int(num_steps),
        "total_seconds": total,
        "seconds_per_step": total / max(num_steps, 1),
        "steps_per_second": num_steps / total if total > 0 else float("inf"),
        "cg_iterations_per_step": solver.stats["cg_iterations"] / max(num_steps, 1),
        "obstacles": len(obstacle_list),
        "contacts_per_step": solver.stats["contacts"] / max(num_steps, 1),
        "contact_projections": int(solver.stats["contact_projections"]),
        "realtime_factor": num_steps * scene.dt / total if total > 0 else float("inf"),  # simulated seconds per wall second
        "finite": bool(np.isfinite(x).all()),
    }
