"""Benchmark of the splatting backends on a fixed cloth scene: `bench_render(...)` returns a dict for the CLI.

Scene (`flag_scene.bench_scene`): the FLAGSIMPLE-sized flag (1579 nodes, 3028 faces) with a travelling
wave, 5 Gaussians per face at fixed barycentric points with flat GaMeS face-frame covariances (zero
thickness along the normal), 8 cameras at 128x128 around it. Timed: forward and
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
from typing import TYPE_CHECKING

import torch

from clods_bench.datasets.cameras import Camera
from clods_bench.plugins.splatting.flag_scene import bench_scene
from clods_bench.plugins.splatting.rasterize import RenderOutput, render_gaussians

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table

SPEEDUP_TARGET = 10.0  # forward+backward of 'cpu' against 'reference'
AGREEMENT_TOL = 1e-5  # max |cpu - reference| on images; relative on gradients


class _PeakRSS:
    """Context manager for the peak rise of the resident set size above its starting level, `.peak` in bytes.

    The kernel's high-water mark (getrusage ru_maxrss) is exact when the block sets a new process peak;
    a 1 ms sampler covers blocks whose peak stays below an earlier one.
    """

    def __enter__(self) -> "_PeakRSS":
        self.start = self.peak_abs = _rss()
        self.max_start = _max_rss()
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
        max_end = _max_rss()
        if max_end > self.max_start:  # a new high-water mark was set inside the block
            self.peak_abs = max(self.peak_abs, max_end)
        self.peak = self.peak_abs - self.start


def _rss() -> int:
    """Current resident set size in bytes (Linux /proc; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:  # pragma: no cover
        return 0


def _max_rss() -> int:
    """The process's peak resident set size so far in bytes (getrusage; 0 where unavailable)."""
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux
    except (ImportError, OSError):  # pragma: no cover
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


def bench_render(repeats: int = 3, seed: int = 0, size: int = 128, num_cameras: int = 8, memory: bool = True) -> dict:
    """Time 'cpu' and 'reference' on the fixed flag scene: ms (min and median of `repeats`), speed-ups, peak
    memory (fresh process per backend, skipped with memory=False) and the largest cpu-vs-reference differences."""
    data, cameras = bench_scene(seed, size, num_cameras)
    result: dict = {"gaussians": int(data["means"].shape[0]), "cameras": num_cameras, "image": f"{size}x{size}",
                    "threads": {"torch": torch.get_num_threads(), "cpus": os.cpu_count()}}  # fmt: skip
    outputs = {}
    for backend in ("cpu", "reference"):
        _run(data, cameras, backend, backward=True)  # warm-up (numba compile / cache load)
        fwd = _time(lambda: _run(data, cameras, backend, False), repeats)
        both = _time(lambda: _run(data, cameras, backend, True), repeats)
        outputs[backend] = _run(data, cameras, backend, backward=True)
        result[backend] = {"forward_ms": round(fwd[0], 1), "forward_ms_median": round(fwd[1], 1),
                           "forward_backward_ms": round(both[0], 1), "forward_backward_ms_median": round(both[1], 1),
                           "peak_rss_mb": peak_memory_mb(backend, seed, size, num_cameras) if memory else None}  # fmt: skip
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


def render_table(result: dict) -> Table:
    """A rich table of a `bench_render` result: times per backend, speed-ups against the 10x target, agreement."""
    from rich.table import Table

    def ok(flag: bool) -> str:
        return "[green]yes[/green]" if flag else "[red]NO[/red]"

    title = (f"clods-bench bench render: {result['gaussians']} flat Gaussians on the 1579-node flag, "
             f"{result['cameras']} cameras {result['image']}, {result['threads']['torch']} threads")  # fmt: skip
    table = Table(title=title)
    for col in ("what", "cpu (numba)", "reference (torch)", "reference / cpu", "target", "met"):
        table.add_column(col, justify="right")
    fast, ref = result["cpu"], result["reference"]
    for key, label, speed in (("forward_ms", "forward ms (min)", "speedup_forward"),
                              ("forward_backward_ms", "forward+backward ms (min)", "speedup_forward_backward")):  # fmt: skip
        target = SPEEDUP_TARGET if key == "forward_backward_ms" else None
        table.add_row(label, f"{fast[key]:.1f}", f"{ref[key]:.1f}", f"{result[speed]:.1f}x",
                      "" if target is None else f">= {target:.0f}x", "" if target is None else ok(result[speed] >= target))  # fmt: skip
    table.add_row("forward+backward ms (median)", f"{fast['forward_backward_ms_median']:.1f}",
                  f"{ref['forward_backward_ms_median']:.1f}", "", "", "")  # fmt: skip
    table.add_row("forward+backward ms / view", f"{fast['forward_backward_ms'] / result['cameras']:.1f}",
                  f"{ref['forward_backward_ms'] / result['cameras']:.1f}", "", "", "")  # fmt: skip
    if fast["peak_rss_mb"] is not None:
        table.add_row("peak memory MiB (RSS rise)", f"{fast['peak_rss_mb']:.0f}", f"{ref['peak_rss_mb']:.0f}",
                      f"{ref['peak_rss_mb'] / max(fast['peak_rss_mb'], 1e-9):.1f}x", "", "")  # fmt: skip
    diff = result["max_abs_diff"]
    table.add_row("max |cpu - ref| rgb, alpha", f"{diff['images']:.1e}", "", "", f"<= {AGREEMENT_TOL:.0e}", ok(diff["images"] <= AGREEMENT_TOL))
    table.add_row("max |cpu - ref| depth", f"{diff['depth']:.1e}", "", "", "", "")
    table.add_row("max gradient diff / max |grad|", f"{diff['grads_relative']:.1e}", "", "", f"<= {AGREEMENT_TOL:.0e}",
                  ok(diff["grads_relative"] <= AGREEMENT_TOL))  # fmt: skip
    return table


def print_bench_render(console: Console, repeats: int = 3, size: int = 128, num_cameras: int = 8, memory: bool = True) -> dict:
    """Run `bench_render` with a status line, print its table on `console` and return the result dict."""
    with console.status(f"splatting: {num_cameras} views at {size}x{size}, cpu and reference backends ..."):
        result = bench_render(repeats=repeats, size=size, num_cameras=num_cameras, memory=memory)
    console.print(render_table(result))
    return result


if __name__ == "__main__":  # pragma: no cover
    from rich.console import Console as _Console

    print_bench_render(_Console())
