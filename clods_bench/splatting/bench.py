"""Benchmark of the splatting backends on a fixed cloth scene: `bench_render(...)` returns a dict for the CLI.

With gsplat and a CUDA GPU present, the gsplat backend is timed too (inputs already on the GPU, every
call synchronised, peak CUDA memory from torch's allocator) and compared with the cpu backend.

Scene (`flag_scene.bench_scene`): the FLAGSIMPLE-sized flag (1579 nodes, 3028 faces) with a travelling
wave, 5 Gaussians per face at fixed barycentric points with flat GaMeS face-frame covariances (zero
thickness along the normal), 8 cameras at 128x128 around it. Timed: forward and
forward+backward of `render_gaussians` (projection and compositing included) per backend; peak memory
is the peak rise of the resident set size during one forward+backward in a fresh process (sampled
every millisecond), so allocator caches of earlier runs do not hide it.
"""

from __future__ import annotations

import functools
import os
import statistics
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import torch

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError
from clods_bench.splatting.flag_scene import bench_scene
from clods_bench.splatting.rasterize import RenderOutput, render_gaussians

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table

SPEEDUP_TARGET = 30.0  # forward+backward of 'cpu' against 'reference' (10x before)
F32_TOL = 1e-3  # max |float32 render - float64 render| of the same Gaussians
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


@functools.lru_cache(maxsize=4)
def _loss_weights(C: int, H: int, W: int, dtype: torch.dtype, device: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Fixed random weights of rgb, alpha and depth in the benchmark loss: drawn once per shape (the same on every
    device, and the same values in float32 and float64), so drawing them is not timed."""
    g = torch.Generator().manual_seed(1)
    return tuple(torch.rand((C, H, W, k), generator=g).to(device, dtype) for k in (3, 1, 1))  # type: ignore[return-value]


def _run(data: dict[str, torch.Tensor], cameras: list[Camera], backend: str, backward: bool) -> tuple[RenderOutput, list]:
    """One render (and backward of a fixed random loss); returns the output and the input gradients."""
    leaves = {k: t.clone().requires_grad_(True) for k, t in data.items()}
    out = render_gaussians(leaves["means"], leaves["covars"], leaves["opacities"], leaves["colors"], cameras, backend=backend)
    if not backward:
        return out, []
    weights = _loss_weights(*out.alpha.shape[:3], out.rgb.dtype, str(out.rgb.device))
    loss = sum((x * w).sum() for x, w in zip((out.rgb, out.alpha, out.depth), weights))
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
    _loss_weights(len(cameras), cameras[0].height, cameras[0].width, data["means"].dtype, "cpu")  # not part of the peak
    with _PeakRSS() as mem:
        _run(data, cameras, backend, backward=True)
    return round(mem.peak / 2**20, 1)


def peak_memory_mb(backend: str, seed: int = 0, size: int = 128, num_cameras: int = 8) -> float:
    """Peak extra resident memory of one forward+backward, measured in a fresh process (allocator caches
    of earlier runs would otherwise hide it)."""
    import multiprocessing as mp

    with mp.get_context("spawn").Pool(1) as pool:
        return pool.apply(_peak_child, (backend, seed, size, num_cameras))


def _max_diffs(a: tuple[RenderOutput, list], b: tuple[RenderOutput, list]) -> dict:
    """Largest |a - b| on rgb/alpha and depth (on the CPU) and the largest gradient difference relative to max |grad b|."""
    (o_a, g_a), (o_b, g_b) = a, b

    def d(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return (x.detach().cpu().double() - y.detach().cpu().double()).abs()

    img = torch.cat([d(o_a.rgb, o_b.rgb), d(o_a.alpha, o_b.alpha)], dim=-1)
    return {
        "images": float(img.max()),
        "images_mean": float(img.mean()),
        "images_frac_above_1e-3": float((img > 1e-3).double().mean()),
        "depth": float(d(o_a.depth, o_b.depth).max()),
        "grads_relative": max(float(d(x, y).max() / y.detach().abs().max().clamp(min=1e-30)) for x, y in zip(g_a, g_b)),
    }


def bench_gsplat(data: dict[str, torch.Tensor], cameras: list[Camera], repeats: int, cpu: tuple[RenderOutput, list]) -> dict:
    """Time backend 'gsplat' on GPU-resident inputs (each call synchronised) and compare it with the cpu output."""
    dev = torch.device("cuda")
    gdata = {k: v.to(dev) for k, v in data.items()}

    def run(backward: bool) -> tuple[RenderOutput, list]:
        out = _run(gdata, cameras, "gsplat", backward)
        torch.cuda.synchronize(dev)
        return out

    run(True)  # warm-up: kernel load (and gsplat's first-use build)
    fwd = _time(lambda: run(False), repeats)
    torch.cuda.reset_peak_memory_stats(dev)
    base = torch.cuda.memory_allocated(dev)
    both = _time(lambda: run(True), repeats)
    peak = (torch.cuda.max_memory_allocated(dev) - base) / 2**20
    return {"forward_ms": round(fwd[0], 2), "forward_ms_median": round(fwd[1], 2), "forward_backward_ms": round(both[0], 2),
            "forward_backward_ms_median": round(both[1], 2), "peak_cuda_mb": round(peak, 1),
            "device": torch.cuda.get_device_name(dev), "max_abs_diff_vs_cpu": _max_diffs(run(True), cpu)}  # fmt: skip


def float32_vs_float64(data: dict[str, torch.Tensor], cameras: list[Camera]) -> float:
    """Largest |rgb, alpha| difference between the cpu render of the (float32) scene and the float64 render of the same values."""
    a = _run(data, cameras, "cpu", backward=False)[0]
    b = _run({k: v.double() for k, v in data.items()}, cameras, "cpu", backward=False)[0]
    return max(float((a.rgb.detach().double() - b.rgb.detach()).abs().max()), float((a.alpha.detach().double() - b.alpha.detach()).abs().max()))


def bench_render(repeats: int = 3, seed: int = 0, size: int = 128, num_cameras: int = 8, memory: bool = True,
                 gsplat: bool | None = None, reference: bool = True) -> dict:  # fmt: skip
    """Time the splatting backends on the fixed flag scene: ms (min and median of `repeats`), speed-ups, peak
    memory (fresh process per CPU backend, skipped with memory=False) and the largest differences to 'cpu'.

    gsplat: also time backend 'gsplat' (None: when gsplat and CUDA are available; True: required).
    reference: time the plain-torch oracle too (its memory grows with pixels x Gaussians per tile: leave it out
    at large image sizes; the ratios are then taken against 'cpu').
    """
    from clods_bench.splatting.gsplat_backend import INSTALL_HINT, gsplat_available

    available, why = gsplat_available() if gsplat is not False else (False, "not asked for")
    if gsplat and not available:
        raise ClodsError(INSTALL_HINT, where="bench render --gsplat", hint=why)
    data, cameras = bench_scene(seed, size, num_cameras)
    result: dict = {"gaussians": int(data["means"].shape[0]), "cameras": num_cameras, "image": f"{size}x{size}",
                    "threads": {"torch": torch.get_num_threads(), "cpus": os.cpu_count()}}  # fmt: skip
    outputs = {}
    for backend in ("cpu", "reference") if reference else ("cpu",):
        _run(data, cameras, backend, backward=True)  # warm-up (numba compile / cache load)
        fwd = _time(lambda: _run(data, cameras, backend, False), repeats)
        both = _time(lambda: _run(data, cameras, backend, True), repeats)
        outputs[backend] = _run(data, cameras, backend, backward=True)
        result[backend] = {"forward_ms": round(fwd[0], 1), "forward_ms_median": round(fwd[1], 1),
                           "forward_backward_ms": round(both[0], 1), "forward_backward_ms_median": round(both[1], 1),
                           "peak_rss_mb": peak_memory_mb(backend, seed, size, num_cameras) if memory else None}  # fmt: skip
    fast = result["cpu"]
    if reference:
        ref = result["reference"]
        result["speedup_forward"] = round(ref["forward_ms"] / fast["forward_ms"], 1)
        result["speedup_forward_backward"] = round(ref["forward_backward_ms"] / fast["forward_backward_ms"], 1)
        # against the reference in float64 on the same values: in float32 the reference rounds depths to float32
        # before sorting (near-tied Gaussians swap), the cpu backend keeps float64 from input to pixels
        exact = _run({k: v.double() for k, v in data.items()}, cameras, "reference", backward=True)
        result["max_abs_diff"] = _max_diffs(outputs["cpu"], exact)
    result["mean_alpha"] = round(float(outputs["cpu"][0].alpha.detach().mean()), 3)
    result["float32_vs_float64"] = float32_vs_float64(data, cameras)
    if available:
        result["gsplat"] = bench_gsplat(data, cameras, repeats, outputs["cpu"])
    else:
        result["gsplat_skipped"] = why
    return result


def render_table(result: dict) -> Table:
    """A rich table of a `bench_render` result: times per backend, speed-ups against the speed-up target, agreement."""
    from rich.table import Table

    def ok(flag: bool) -> str:
        return "[green]yes[/green]" if flag else "[red]NO[/red]"

    title = (f"clods-bench bench render: {result['gaussians']} flat Gaussians on the 1579-node flag, "
             f"{result['cameras']} cameras {result['image']}, {result['threads']['torch']} threads")  # fmt: skip
    fast, ref, gs = result["cpu"], result.get("reference"), result.get("gsplat")
    table = Table(title=title)
    cols = ["what", "cpu (numba)"] + (["reference (torch)"] if ref else []) + ([f"gsplat ({gs['device']})"] if gs else [])
    cols += (["reference / cpu"] if ref else []) + (["cpu / gsplat"] if gs else []) + (["target", "met"] if ref else [])
    for col in cols:
        table.add_column(col, justify="right")

    def row(label: str, values: list[str], ratios: list[str] = (), check: tuple[str, str] = ("", "")) -> None:
        ratios = list(ratios) + [""] * ((ref is not None) + (gs is not None) - len(ratios))
        table.add_row(label, *values, *ratios, *(check if ref else ()))

    def times(key: str, digits: int = 1) -> list[str]:
        return [f"{b[key]:.{digits}f}" for b in (fast, ref, gs) if b]

    def ratios(key: str) -> list[str]:
        return ([f"{ref[key] / fast[key]:.1f}x"] if ref else []) + ([f"{fast[key] / gs[key]:.1f}x"] if gs else [])

    row("forward ms (min)", times("forward_ms"), ratios("forward_ms"))
    target = result.get("speedup_forward_backward", 0.0) >= SPEEDUP_TARGET
    row("forward+backward ms (min)", times("forward_backward_ms"), ratios("forward_backward_ms"),
        (f">= {SPEEDUP_TARGET:.0f}x", ok(target)))  # fmt: skip
    row("forward+backward ms (median)", times("forward_backward_ms_median"))
    row("forward+backward ms / view", [f"{b['forward_backward_ms'] / result['cameras']:.2f}" for b in (fast, ref, gs) if b])
    if fast["peak_rss_mb"] is not None:
        mem = [f"{b['peak_rss_mb']:.0f}" for b in (fast, ref) if b] + ([f"{gs['peak_cuda_mb']:.0f} (CUDA)"] if gs else [])
        row("peak memory MiB (RSS rise)", mem, [f"{ref['peak_rss_mb'] / max(fast['peak_rss_mb'], 1e-9):.1f}x"] if ref else [])
    blank = [""] * ((ref is not None) + (gs is not None))
    if ref:
        diff = result["max_abs_diff"]
        row("max |cpu - ref (float64)| rgb, alpha", [f"{diff['images']:.1e}", *blank], [],
            (f"<= {AGREEMENT_TOL:.0e}", ok(diff["images"] <= AGREEMENT_TOL)))  # fmt: skip
        row("max |cpu - ref (float64)| depth", [f"{diff['depth']:.1e}", *blank])
        row("max gradient diff / max |grad|", [f"{diff['grads_relative']:.1e}", *blank], [],
            (f"<= {AGREEMENT_TOL:.0e}", ok(diff["grads_relative"] <= AGREEMENT_TOL)))  # fmt: skip
    if "float32_vs_float64" in result:
        f32 = result["float32_vs_float64"]
        row("max |float32 - float64| cpu rgb, alpha", [f"{f32:.1e}", *blank], [], (f"<= {F32_TOL:.0e}", ok(f32 <= F32_TOL)))
    if gs:
        d = gs["max_abs_diff_vs_cpu"]
        pad = [""] * (ref is not None)
        row("max |gsplat - cpu| rgb, alpha", ["", *pad, f"{d['images']:.1e}"])
        row("mean |gsplat - cpu| rgb, alpha", ["", *pad, f"{d['images_mean']:.1e}"])
        row("share of values off by > 1e-3", ["", *pad, f"{100 * d['images_frac_above_1e-3']:.4f}%"])
        row("max |gsplat - cpu| depth", ["", *pad, f"{d['depth']:.1e}"])
        row("gsplat gradient diff / max |grad cpu|", ["", *pad, f"{d['grads_relative']:.1e}"])
    return table


def print_bench_render(console: Console, repeats: int = 3, size: int = 128, num_cameras: int = 8, memory: bool = True,
                       gsplat: bool | None = None, reference: bool = True) -> dict:  # fmt: skip
    """Run `bench_render` with a status line, print its table on `console` and return the result dict."""
    backends = "cpu" + (", reference" if reference else "") + (", gsplat" if gsplat is not False else "")
    with console.status(f"splatting: {num_cameras} views at {size}x{size}, backends {backends} ..."):
        result = bench_render(repeats=repeats, size=size, num_cameras=num_cameras, memory=memory, gsplat=gsplat,
                              reference=reference)  # fmt: skip
    console.print(render_table(result))
    if "gsplat" in result:
        console.print("backend gsplat: the float64 projection of the cpu backends on the GPU, then gsplat's float32 "
                      "binning and compositing kernels (README: 'On a GPU').")  # fmt: skip
    if "gsplat_skipped" in result:
        console.print(f"gsplat backend not timed: {result['gsplat_skipped']}")
    return result


if __name__ == "__main__":  # pragma: no cover
    from rich.console import Console as _Console

    print_bench_render(_Console())
