"""Time each numba kernel of the cpu splatting backend on the `bench render` scene (or a smaller one).

`clods-bench bench render` times a whole forward+backward against the torch reference; this prints where that time
goes: each kernel called by `fast_cpu` (projection, sort and binning, visit bounds, compositing forward and
backward, gradient reduction, projection backward) wrapped with a timer, min and median over the renders, and
their sum against the whole render (the rest is numpy/torch glue and the benchmark's loss).

    python examples/studies/splat_phases.py [renders] [size] [views]    # default 20 renders, 128 px, 8 views
"""

from __future__ import annotations

import collections
import sys
import time
from collections.abc import Callable

import numpy as np

from clods_bench.splatting import fast_kernels as K, projection_kernels as PK
from clods_bench.splatting.bench import _run, bench_scene

TIMES: dict[str, list[float]] = collections.defaultdict(list)


def timed(name: str, fn: Callable) -> Callable:
    """`fn` recording its wall time (ms) under `name`."""

    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        TIMES[name].append(1e3 * (time.perf_counter() - t0))
        return out

    return wrapper


def main(renders: int, size: int, views: int) -> None:
    for mod, names in ((PK, ("project_fwd", "project_bwd")), (K, ("sort_and_bin", "visit_bounds", "raster_fwd", "raster_bwd", "reduce_grads"))):
        for name in names:
            setattr(mod, name, timed(name, getattr(mod, name)))  # fast_cpu calls them through the module
    data, cams = bench_scene(0, size, views)
    for _ in range(3):
        _run(data, cams, "cpu", backward=True)  # compile / load the kernels, warm the allocator
    TIMES.clear()
    total = []
    for _ in range(renders):
        t0 = time.perf_counter()
        _run(data, cams, "cpu", backward=True)
        total.append(1e3 * (time.perf_counter() - t0))
    print(f"{data['means'].shape[0]} Gaussians, {views} views of {size} px, {renders} renders (forward+backward), ms:")
    for name, ts in TIMES.items():
        print(f"  {name:14s} min {min(ts):7.2f}   median {np.median(ts):7.2f}")
    print(f"  kernels (sum of mins) {sum(min(ts) for ts in TIMES.values()):.2f}; whole render min {min(total):.2f}, median {np.median(total):.2f}")


if __name__ == "__main__":
    a = [int(x) for x in sys.argv[1:4]]
    main(*(a + [20, 128, 8][len(a):]))
