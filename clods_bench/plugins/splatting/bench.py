"""Benchmark of the splatting backends on a fixed cloth scene: `bench_render(...)` returns a dict for the CLI.

Scene: the FLAGSIMPLE-sized flag (1579 nodes, 3028 faces) with a travelling wave, 5 Gaussians per face
at fixed barycentric points, flat face-anchored covariances (two in-plane axes from the triangle as in
GaMeS / SMGS, zero thickness along the normal), 8 cameras at 128x128 around it. Timed: forward and
forward+backward of `render_gaussians` (projection and compositing included) per backend; peak memory
is the peak rise of the resident set size during one forward+backward in a fresh process (sampled
every millisecond), so allocator caches of earlier runs do not hide it.
"""

from __future__ import annotations

import os
import statistics
import threading
import time
from collections.abc import Callable

import numpy as np
import torch

from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.datasets.meshes import make_flagsimple_mesh
from clods_bench.plugins.splatting.rasterize import RenderOutput, render_gaussians

BARYCENTRICS = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3], [0.45, 0.45, 0.1]])


def face_gaussians(verts: np.ndarray, faces: np.ndarray, bary: np.ndarray = BARYCENTRICS, shrink: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """(F*B,3) means and (F*B,3,3) flat covariances anchored on triangles (GaMeS frame, zero normal scale)."""
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]  # (F,3)
    means = np.einsum("kj,fjd->fkd", bary, np.stack([a, b, c], axis=1)).reshape(-1, 3)
    e1, e2 = b - a, c - a
    r2 = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    r3 = e2 - np.sum(e2 * r2, axis=1, keepdims=True) * r2
    h = np.linalg.norm(r3, axis=1, keepdims=True)
    r3 /= h
    s2, s3 = np.linalg.norm(e1, axis=1) / shrink, h[:, 0] / shrink
    cov = s2[:, None, None] ** 2 * np.einsum("fi,fj->fij", r2, r2) + s3[:, None, None] ** 2 * np.einsum("fi,fj->fij", r3, r3)
    return means, np.repeat(cov, len(bary), axis=0)


def bench_scene(seed: int = 0, size: int = 128, num_cameras: int = 8, dtype: torch.dtype = torch.float32) -> tuple[dict[str, torch.Tensor], list[Camera]]:
    """The fixed benchmark scene: Gaussian tensors (means, covars, opacities, colors) and cameras."""
    mesh = make_flagsimple_mesh()
    v = np.array(mesh.rest_pos, dtype=np.float64)
    v[:, 1] += 0.12 * v[:, 0] * np.sin(3.0 * v[:, 0] + 2.0 * v[:, 2])  # a wave, growing away from the pole
    means, covars = face_gaussians(v, np.asarray(mesh.cells))
    rng = np.random.default_rng(seed)
    G = means.shape[0]
    data = {
        "means": torch.tensor(means, dtype=dtype),
        "covars": torch.tensor(covars, dtype=dtype),
        "opacities": torch.tensor(rng.uniform(0.5, 0.95, G), dtype=dtype),
        "colors": torch.tensor(rng.uniform(0.0, 1.0, (G, 3)), dtype=dtype),
    }
    centre = 0.5 * (v.min(0) + v.max(0))
    return data, camera_rig(num_cameras, centre, 4.5, size, size)


class _PeakRSS:
    """Context manager sampling the resident set size; `.peak` is the rise above the starting level in bytes."""

    def __enter__(self) -> "_PeakRSS":
        self.start = self.peak_abs = _rss()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(0.001):
            self.peak_abs = max(self.peak_abs, _rss())

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.peak_abs = max(self.peak_abs, _rss())
        self.peak = self.peak_abs - self.start


def _rss() -> int:
    """Current resident set size in bytes (Linux /proc; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:  # pragma: no cover
        return 0


def _run(data: dict[str, torch.Tensor], cameras: list[Camera], backend: str, backward: bool) -> tuple[RenderOutput, list]:
    """One render (and backward of a fixed random loss); returns the output and the input gradients."""
    leaves = {k: t.clone().requires_grad_(True) for k, t in data.items()}
    out = render_gaussians(leaves["means"], leaves["covars"], leaves["opacities"], leaves["colors"], cameras, backend=backend)
    if not backward:
        return out, []
    g = torch.Generator().manual_seed(1)
    loss = sum((x * torch.rand(x.shape, generator=g, dtype=x.dtype)).sum() for x in (out.rgb, out.alpha, out.depth))
    loss.backward()
    return out, [leaves[k].grad for k in ("means", "covars", "opacities", "colors")]


def _time(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """(min, median) wall time of `fn` in milliseconds over `repeats` calls."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - t0))
    return min(times), statistics.median(times)


def _peak_child(backend: str, seed: int, size: int, num_cameras: int) -> float:
    """In a fresh process: peak RSS rise (MiB) of one forward+backward after a tiny warm-up render."""
    data, cameras = bench_scene(seed, size, num_cameras)
    small = {k: v[:8] for k, v in data.items()}
    _run(small, cameras[:1], backend, backward=True)  # load kernels, allocate nothing scene-sized
    with _PeakRSS() as mem:
        _run(data, cameras, backend, backward=True)
    return round(mem.peak / 2**20, 1)


def peak_memory_mb(backend: str, seed: int = 0, size: int = 128, num_cameras: int = 8) -> float:
    """Peak extra resident memory of one forward+backward, measured in a fresh process (allocator caches
    of earlier runs would otherwise hide it)."""
    import multiprocessing as mp

    with mp.get_context("spawn").Pool(1) as pool:
        return pool.apply(_peak_child, (backend, seed, size, num_cameras))


def bench_render(repeats: int = 3, seed: int = 0, size: int = 128, num_cameras: int = 8) -> dict:
    """Time 'cpu' and 'reference' on the fixed scene; report ms, speed-up, peak memory and their agreement."""
    data, cameras = bench_scene(seed, size, num_cameras)
    result: dict = {"gaussians": int(data["means"].shape[0]), "cameras": num_cameras, "image": f"{size}x{size}",
                    "threads": {"torch": torch.get_num_threads(), "cpus": os.cpu_count()}}  # fmt: skip
    outputs = {}
    for backend in ("cpu", "reference"):
        _run(data, cameras, backend, backward=True)  # warm-up (numba compile / cache load)
        fwd = _time(lambda: _run(data, cameras, backend, False), repeats)
        both = _time(lambda: _run(data, cameras, backend, True), repeats)
        outputs[backend] = _run(data, cameras, backend, backward=True)
        mem_mb = peak_memory_mb(backend, seed, size, num_cameras)
        result[backend] = {"forward_ms": round(fwd[0], 1), "forward_ms_median": round(fwd[1], 1),
                           "forward_backward_ms": round(both[0], 1), "forward_backward_ms_median": round(both[1], 1),
                           "peak_rss_mb": mem_mb}  # fmt: skip
    ref, fast = result["reference"], result["cpu"]
    result["speedup_forward"] = round(ref["forward_ms"] / fast["forward_ms"], 1)
    result["speedup_forward_backward"] = round(ref["forward_backward_ms"] / fast["forward_backward_ms"], 1)
    (o_f, g_f), (o_r, g_r) = outputs["cpu"], outputs["reference"]
    result["max_abs_diff"] = {
        "images": max(float((getattr(o_f, k) - getattr(o_r, k)).detach().abs().max()) for k in ("rgb", "alpha")),
        "depth": float((o_f.depth - o_r.depth).detach().abs().max()),
        "grads_relative": max(float((a - b).abs().max() / b.abs().max().clamp(min=1e-30)) for a, b in zip(g_f, g_r)),
    }
    result["mean_alpha"] = round(float(o_f.alpha.detach().mean()), 3)
    return result


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(bench_render(), indent=2))
