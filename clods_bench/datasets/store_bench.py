"""`clods-bench bench store`: bytes on disk and read speed of the frame store against raw .npy, same run.

Trajectory 0 of a preset's dataset is simulated and rendered exactly as `data generate` would (same scene,
mesh, cameras, texture, seed). With `blocks`, only that many chunk-long runs of consecutive frames, spread
evenly through the trajectory, are rendered (from every camera): each run is exactly one time chunk of the
full trajectory's array, so the full trajectory's size is extrapolated as (mean bytes per chunk) x (chunks).
Both formats are written to a temp directory and read back while still in the page cache, so the read
speeds are decode speeds (what a task sees on a warm machine), not disk speeds. The "on demand" column is a dataset
generated with `data.frames=on_demand`: its bytes are the meshes and the render setup, its reads render the frames
(one camera's frame range through `RenderedFrames`, checked equal to the stored frames; all cameras' frames at the
speed of the generation render above, which runs the same rasterizer calls).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
from rich.console import Console
from rich.table import Table

from clods_bench.atomic import write_npz
from clods_bench.datasets.frame_store import LazyFrames, default_chunk_frames, write_frames
from clods_bench.datasets.rendered_frames import RENDER_SETUP, RenderedFrames, read_render_setup, write_render_setup


def sample_times(num_steps: int, chunk: int, blocks: int | None) -> list[int]:
    """Frames to render: all, or `blocks` chunk-aligned runs of `chunk` frames spread through the trajectory."""
    full_chunks = num_steps // chunk  # runs must be whole chunks of the full array
    if blocks is None or blocks * chunk >= num_steps or full_chunks == 0:
        return list(range(num_steps))
    starts = sorted({int(c) * chunk for c in np.linspace(0, full_chunks - 1, blocks).round()})
    return [s + j for s in starts for j in range(chunk)]


def _timed(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    """Best wall time of `repeats` calls, and the last result."""
    best, out = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_store(cfg: Any, scene: Any, blocks: int | None = None, console: Console | None = None) -> dict[str, Any]:
    """Measure the frame store against raw .npy on trajectory 0 of `cfg.data` (see the module docstring)."""
    from clods_bench.datasets.generate import _setup, render_steps
    from clods_bench.datasets.scenes import simulate_scene

    d = cfg.data
    say = console.print if console is not None else (lambda *a, **k: None)
    setup = _setup(d, scene)
    shape = (d.num_steps, len(setup.cameras), setup.cameras[0].height, setup.cameras[0].width, 3)
    k = default_chunk_frames(shape)
    times = sample_times(d.num_steps, k, blocks)
    say(f"simulating trajectory 0 of preset {cfg.preset} ({d.num_steps} frames) ...")
    t0 = time.perf_counter()
    traj = simulate_scene(scene, setup.mesh, d.num_steps, d.seed)
    sim_s = time.perf_counter() - t0
    say(f"rendering {len(times)} of {d.num_steps} frames x {shape[1]} cameras at {shape[3]}x{shape[2]} ...")
    t0 = time.perf_counter()
    frames = np.stack(list(render_steps(traj.slice(0, d.num_steps), setup.mesh.texture_uv(), setup.texture, setup.cameras,
                                        setup.settings, times=times)))  # fmt: skip
    render_s = time.perf_counter() - t0
    raw = frames.nbytes
    repeats = 1 if raw > (256 << 20) else 3
    with tempfile.TemporaryDirectory(prefix="clods-bench-store-") as tmp:
        npy, arr = Path(tmp) / "frames.npy", Path(tmp) / "frames.zarr"
        npy_write, _ = _timed(lambda: np.save(npy, frames), 1)
        zarr_write, record = _timed(lambda: write_frames(arr, frames, chunk_frames=k), 1)
        lazy = LazyFrames(arr)
        npy_full, got = _timed(lambda: np.load(npy), repeats)
        zarr_full, got2 = _timed(lambda: lazy[:], repeats)
        if not (np.array_equal(got, frames) and np.array_equal(got2, frames)):
            raise AssertionError("a format did not read back the frames it was given")
        span = min(len(times), 4 * k)  # one camera, a frame range of up to 4 chunks
        npy_one, _ = _timed(lambda: np.array(np.load(npy, mmap_mode="r")[:span, 0]), repeats)
        zarr_one, _ = _timed(lambda: lazy[:span, 0], repeats)
        meta_bytes = (arr / "zarr.json").stat().st_size
        # on demand (data.frames=on_demand): the meshes and the render setup on disk, frames rendered when read
        write_npz(Path(tmp) / "traj.npz", **{k: getattr(traj, k) for k in ("cells", "mesh_pos", "node_type", "world_pos")})
        write_render_setup(Path(tmp) / RENDER_SETUP, setup.mesh.texture_uv(), setup.texture, setup.settings)
        demand_bytes = sum((Path(tmp) / f).stat().st_size for f in ("traj.npz", RENDER_SETUP))
        setup_read = read_render_setup(Path(tmp) / RENDER_SETUP)
        sel = [times[j] for j in range(span)]
        demand_one, got3 = _timed(lambda: RenderedFrames(traj, setup.cameras, setup_read, Path(tmp)).read(sel, [0])[:, 0], 1)
        if not np.array_equal(got3, lazy[:span, 0]):
            raise AssertionError("frames rendered on demand differ from the stored ones")
    chunk_bytes = (record["bytes"] - meta_bytes) / record["chunks"]
    full_chunks = -(-d.num_steps // k) * shape[1]
    del frames, got, got2
    images = len(times) * shape[1]
    return {
        "preset": cfg.preset, "shape": list(shape), "chunk_frames": k, "frames_rendered": len(times), "times": times,
        "sim_seconds": sim_s, "render_seconds": render_s, "repeats": repeats,
        "raw_bytes_per_trajectory": int(np.prod(shape)) + 128,
        "stored_bytes_per_trajectory": int(round(chunk_bytes * full_chunks + meta_bytes)),
        "sample_raw_bytes": raw, "sample_stored_bytes": int(record["bytes"]),
        "write_mb_s": {"npy": raw / npy_write / 1e6, "store": raw / zarr_write / 1e6},
        "full_read": {"npy": (raw / npy_full / 1e6, images / npy_full), "store": (raw / zarr_full / 1e6, images / zarr_full)},
        "one_camera_read": {"frames": span, "npy": (span * int(np.prod(shape[2:])) / npy_one / 1e6, span / npy_one),
                            "store": (span * int(np.prod(shape[2:])) / zarr_one / 1e6, span / zarr_one),
                            "on_demand": (span * int(np.prod(shape[2:])) / demand_one / 1e6, span / demand_one)},
        "on_demand_bytes_per_trajectory": int(demand_bytes),
        "on_demand_full_read": (raw / render_s / 1e6, images / render_s),  # the same render_views calls, all cameras a frame
    }  # fmt: skip


def print_bench_store(console: Console, cfg: Any, scene: Any, blocks: int | None = None) -> dict[str, Any]:
    """Run `bench_store` and print its table (store vs raw .npy, ratios) and what exactly was measured."""
    r = bench_store(cfg, scene, blocks, console)
    t, n, h, w, _ = r["shape"]
    subset = r["frames_rendered"] < t
    what = (f"{r['frames_rendered']} of {t} frames ({len(r['times']) // r['chunk_frames']} runs of {r['chunk_frames']}) x {n} cameras, "
            f"bytes extrapolated to all {t}" if subset else f"all {t} frames x {n} cameras")  # fmt: skip
    table = Table(title=f"clods-bench bench store: preset {r['preset']}, trajectory 0, {w}x{h} px, {what}")
    for col in ("what", "raw .npy", "frame store", "store / npy", "on demand", "on demand / npy"):
        table.add_column(col, justify="right")
    rb, sb, db = r["raw_bytes_per_trajectory"], r["stored_bytes_per_trajectory"], r["on_demand_bytes_per_trajectory"]
    table.add_row("bytes per trajectory (frames)", _size(rb), _size(sb), f"{sb / rb:.3f} ({rb / sb:.1f}x smaller)", _size(db) + " (meshes)",
                  f"{db / rb:.5f}")  # fmt: skip
    table.add_row("write MB/s", f"{r['write_mb_s']['npy']:.0f}", f"{r['write_mb_s']['store']:.0f}", f"{r['write_mb_s']['store'] / r['write_mb_s']['npy']:.2f}", "", "")
    for key, label in (("full_read", f"read all {r['frames_rendered']} frames x {n} cameras"),
                       ("one_camera_read", f"read camera 0, frames 0..{r['one_camera_read']['frames'] - 1}")):  # fmt: skip
        (a_mb, a_fps), (b_mb, b_fps) = r[key]["npy"], r[key]["store"]
        c_mb, c_fps = r["on_demand_full_read"] if key == "full_read" else r[key]["on_demand"]
        table.add_row(f"{label}: MB/s", f"{a_mb:.0f}", f"{b_mb:.0f}", f"{b_mb / a_mb:.2f}", f"{c_mb:.1f}", f"{c_mb / a_mb:.4f}")
        table.add_row(f"{label}: images/s", f"{a_fps:.0f}", f"{b_fps:.0f}", f"{b_fps / a_fps:.2f}", f"{c_fps:.1f}", f"{c_fps / a_fps:.4f}")
    console.print(table)
    console.print(f"chunk: {r['chunk_frames']} frames x 1 camera; simulated in {r['sim_seconds']:.1f} s, rendered in "
                  f"{r['render_seconds']:.1f} s; reads: best of {r['repeats']}, files in the page cache (decode speed, not disk)")  # fmt: skip
    return r


def _size(b: float) -> str:
    return f"{b / 1e9:.2f} GB" if b >= 1e9 else f"{b / 1e6:.2f} MB"
