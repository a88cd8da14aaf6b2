"""A data config checked before anything is generated or any folder is created: ranges, finite numbers, step counts
(at most `MAX_STEPS`), and the memory its largest arrays need against the memory the machine has available.

`check_data` is what `generate` and a run's resolve step call, so a bad value costs no simulation. The memory check
is a floor, not a forecast: it counts only arrays that are certainly held whole (every trajectory's `world_pos`,
which a learned simulator trains on in memory; one trajectory's `world_pos` in float64, which the solver fills; one
time step's supersampled colour buffers of every camera, which the ground-truth rasterizer fills); frames are
streamed a chunk at a time and never count whole.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from clods_bench.datasets.data_config import DataConfig
from clods_bench.errors import ClodsError
from clods_bench.typed_config import MAX_STEPS, check_count, check_number

FRAME_MODES = ("stored", "on_demand")
"""`data.frames`: rendered at generation and kept on disk, or rendered when read."""
FLAGSIMPLE_NODES = 1579
"""Nodes of the 'flagsimple' resolution (the FLAGSIMPLE mesh)."""
MAX_IMAGE_SIZE = 16384
"""Largest image side in pixels (20x the paper's 800)."""
MAX_SUPERSAMPLE = 16
"""Largest anti-aliasing factor of the ground-truth rasterizer."""
MAX_SEED = 2**32 - 1
"""Largest seed (numpy's legacy generator, seeded by every run, takes 32 bits)."""
MEMINFO = Path("/proc/meminfo")


def check_data(d: DataConfig, where: str = "data") -> None:
    """Raise ClodsError naming the first field of `d` (as `<where>.<field>`) that cannot make a dataset.

    A dataset given by `data.path` supplies its own sizes (from its manifest) and is never generated: only `frames`
    is checked then."""
    if d.frames not in FRAME_MODES:
        raise ClodsError(f"unknown frames mode {d.frames!r}, expected one of {FRAME_MODES}", where=f"{where}.frames")
    if d.path:
        return
    if d.frames == "on_demand" and not d.render_frames:
        raise ClodsError("frames=on_demand renders frames when read, but render_frames is off", where=f"{where}.frames",
                         hint="leave data.render_frames on, or data.frames=stored")  # fmt: skip
    check_resolution(d.resolution, f"{where}.resolution")
    check_count(d.num_train, f"{where}.num_train", minimum=2, maximum=MAX_STEPS)
    check_count(d.num_test, f"{where}.num_test", minimum=1, maximum=MAX_STEPS)
    check_count(d.num_steps, f"{where}.num_steps", minimum=4)
    if not 2 <= d.interp_steps < d.num_steps - 1:
        raise ClodsError(f"must satisfy 2 <= interp_steps < num_steps - 1 = {d.num_steps - 1}, got {d.interp_steps}", where=f"{where}.interp_steps")
    check_count(d.num_cameras, f"{where}.num_cameras", minimum=1, maximum=sys.maxsize)
    if isinstance(d.num_views_test, bool) or not isinstance(d.num_views_test, int) or not 0 <= d.num_views_test < d.num_cameras:
        raise ClodsError(f"must be an integer in [0, num_cameras={d.num_cameras}), got {d.num_views_test!r}", where=f"{where}.num_views_test")
    check_count(d.image_size, f"{where}.image_size", minimum=1, maximum=MAX_IMAGE_SIZE)
    check_count(d.supersample, f"{where}.supersample", minimum=1, maximum=MAX_SUPERSAMPLE)
    check_number(d.fov_deg, f"{where}.fov_deg", minimum=0, inclusive=False, maximum=179.0)
    check_number(d.camera_radius, f"{where}.camera_radius", minimum=0, inclusive=False)
    check_count(d.seed, f"{where}.seed", minimum=0, maximum=MAX_SEED)


def check_resolution(resolution: Any, where: str) -> None:
    """Raise ClodsError unless `resolution` is 'flagsimple' or two integers >= 2 whose product is a sane node count."""
    if isinstance(resolution, str):
        if resolution != "flagsimple":
            raise ClodsError(f"must be [nx, ny] or 'flagsimple', got '{resolution}'", where=where)
        return
    if len(resolution) != 2 or any(isinstance(n, bool) or not isinstance(n, int) or n < 2 for n in resolution):
        raise ClodsError(f"must be two integers >= 2, got {resolution}", where=where)


@dataclass(frozen=True)
class ArrayNeed:
    """One array a dataset certainly holds whole: its size in bytes and what it is (for messages)."""

    bytes: int
    what: str


def largest_arrays(d: DataConfig, nodes: int) -> list[ArrayNeed]:
    """The arrays of `d` that are held whole at some point, for a cloth of `nodes` nodes, largest first."""
    trajectories = d.num_train + d.num_test
    needs = [
        ArrayNeed(trajectories * d.num_steps * nodes * 3 * 4,
                  f"world_pos of {trajectories} trajectories x {d.num_steps} steps x {nodes} nodes, float32"),
        ArrayNeed(d.num_steps * nodes * 3 * 8, f"world_pos of one trajectory being simulated ({d.num_steps} steps x {nodes} nodes, float64)"),
    ]  # fmt: skip
    if d.render_frames:
        side = d.image_size * d.supersample
        needs.append(ArrayNeed(d.num_cameras * side * side * 4 * 8,
                               f"one time step rendered by {d.num_cameras} cameras at {side}x{side} px (colour and depth, float64)"))  # fmt: skip
    return sorted(needs, key=lambda n: -n.bytes)


def cloth_nodes(d: DataConfig, scene: Any) -> int:
    """Nodes of the cloth `d` makes of `scene` without building it: a mesh cloth's own count, 1579 for 'flagsimple',
    nx * ny for a grid resolution."""
    rest = getattr(getattr(scene, "cloth", None), "rest_pos", None)
    if rest is not None and hasattr(rest, "shape"):
        return int(rest.shape[0])
    if isinstance(d.resolution, str):
        return FLAGSIMPLE_NODES
    return int(d.resolution[0]) * int(d.resolution[1])


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation: MemAvailable of /proc/meminfo, else free physical pages
    (`os.sysconf`); None where neither can be read."""
    try:
        for line in MEMINFO.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


def check_memory(d: DataConfig, scene: Any, where: str = "data") -> None:
    """Raise ClodsError when the largest array `d` must hold is larger than the memory available now (a dataset given
    by `data.path` was written already and is not checked)."""
    if d.path:
        return
    have = available_memory()
    if have is None:
        return
    need = largest_arrays(d, cloth_nodes(d, scene))[0]
    if need.bytes > have:
        raise ClodsError(f"the dataset needs {size_text(need.bytes)} for its {need.what}; {size_text(have)} of memory is available",
                         where=where, hint="lower data.num_steps, data.resolution, data.num_train/num_test or data.image_size")  # fmt: skip


def size_text(n: int) -> str:
    """Bytes in the largest binary unit that keeps the number below 1024: '143 GiB', '8.38 TiB', '12 MiB'."""
    for power, unit in ((50, "PiB"), (40, "TiB"), (30, "GiB"), (20, "MiB")):
        if n >= 2**power:
            return f"{n / 2**power:.3g} {unit}"
    return f"{n / 2**10:.3g} KiB"
