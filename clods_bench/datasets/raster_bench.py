"""Speed benchmark of the ground-truth rasterizer on a FLAGSIMPLE-sized waving flag."""

from __future__ import annotations

import time

import numpy as np

from clods_bench.datasets.cameras import camera_rig
from clods_bench.datasets.rasterizer import DirectionalLight, RasterSettings, render_threads, render_views
from clods_bench.datasets.textures import procedural_texture


def _bench_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(verts, cells, uv) of a 1579-node / 3028-triangle flag (a 51 x 31 grid if meshes.py is absent)."""
    try:
        from clods_bench.datasets.meshes import make_flagsimple_mesh

        mesh = make_flagsimple_mesh()
        verts, cells, uv = mesh.rest_pos.astype(np.float64), mesh.cells, mesh.texture_uv()
    except ImportError:  # pragma: no cover - fallback while meshes.py does not exist
        xs, ys = np.meshgrid(np.linspace(0, 2, 51), np.linspace(0, 1, 31), indexing="xy")
        verts = np.stack([xs.ravel(), np.zeros(xs.size), ys.ravel()], axis=1)
        n00 = (np.arange(50)[None, :] + 51 * np.arange(30)[:, None]).ravel()
        cells = np.concatenate([np.stack([n00, n00 + 1, n00 + 52], 1), np.stack([n00, n00 + 52, n00 + 51], 1)])
        uv = np.stack([xs.ravel() / 2, ys.ravel()], axis=1)
    verts = verts.copy()
    verts[:, 1] = 0.15 * verts[:, 0] * np.sin(3.0 * verts[:, 0] + 1.0 * verts[:, 2])  # a gentle wave
    return verts, cells, uv


def bench_rasterizer(num_views: int = 8, size: int = 128, supersample: int = 2, repeats: int = 10) -> dict:
    """Milliseconds per view of render_views (after a first, JIT-compiling call, timed separately), in the threads it
    uses by default and, alternated with those calls in the same run, in one thread (the reference for the speed-up)."""
    verts, cells, uv = _bench_mesh()
    centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    cameras = camera_rig(num_views, centre, 3.5, size, size, fov_deg=30.0)
    texture = procedural_texture(512, seed=0)
    settings = RasterSettings(supersample=supersample, light=DirectionalLight((-0.4, 0.3, -1.0)))
    threads = min(render_threads(), num_views)
    t0 = time.perf_counter()
    imgs = render_views(verts, cells, uv, texture, cameras, settings)
    first = time.perf_counter() - t0
    times: dict[int, list[float]] = {threads: [], 1: []}
    for _ in range(repeats):
        for k in times:
            t0 = time.perf_counter()
            render_views(verts, cells, uv, texture, cameras, settings, threads=k)
            times[k].append(time.perf_counter() - t0)
    coverage = float((np.abs(imgs - np.asarray(settings.background, np.float32)).max(axis=-1) > 1e-6).mean())
    ms = {k: 1000.0 * float(np.median(v)) / num_views for k, v in times.items()}
    return {
        "ms_per_view": ms[threads],
        "ms_per_view_min": 1000.0 * float(np.min(times[threads])) / num_views,
        "ms_per_view_one_thread": ms[1],
        "threads": threads,
        "thread_speedup": ms[1] / ms[threads],
        "first_call_s": first,
        "num_views": num_views,
        "size": size,
        "supersample": supersample,
        "num_nodes": int(verts.shape[0]),
        "num_faces": int(cells.shape[0]),
        "coverage": coverage,
    }


if __name__ == "__main__":  # pragma: no cover
    print(bench_rasterizer())
