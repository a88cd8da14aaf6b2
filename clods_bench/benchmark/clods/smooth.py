"""Optional temporal smoothing of the extracted meshes before stage 3 (`task_config.clods.smooth_window`).

Stage 2 fits each frame on its own, so the extracted positions carry frame-to-frame noise that second differences
amplify: at `ci` the extracted meshes' accelerations are off by 2.3x the true accelerations' RMS, and stage 3 learns
exactly those accelerations (MGN predicts x_{t+1} - 2 x_t + x_{t-1}). A Savitzky-Golay filter (a least-squares
polynomial of degree `smooth_order` over a sliding window of `smooth_window` frames) removes most of that noise and
leaves smooth motion alone. Frame 0 (the given initial mesh) and the nodes whose motion is prescribed (handles) are
kept as extracted. It is not in the paper; off by default. Measured at `ci` it does not improve CloDS** (the noise
is zero-mean and averages out in training; README "The CloDS pipeline", the paragraph on fast motion).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from clods_bench.datasets.types import NORMAL, Trajectory
from clods_bench.errors import ClodsError

WHERE = "task_config.clods.smooth_window"


def savgol_positions(world_pos: np.ndarray, free: np.ndarray, window: int, order: int) -> np.ndarray:
    """(T,V,3) positions with the `free` nodes' tracks filtered in time (frame 0 and the other nodes unchanged)."""
    from scipy.signal import savgol_filter

    x = np.asarray(world_pos, dtype=np.float64)
    if window > x.shape[0]:
        raise ClodsError(f"a window of {window} frames is longer than the {x.shape[0]} extracted frames", where=WHERE,
                         hint="use a smaller odd window or 0 (off)")  # fmt: skip
    out = x.copy()
    out[:, free] = savgol_filter(x[:, free], window, order, axis=0, mode="interp")
    out[0] = x[0]
    return out.astype(np.asarray(world_pos).dtype, copy=False)


def smooth_meshes(meshes: Sequence[Trajectory], window: int, order: int) -> list[Trajectory]:
    """The extracted trajectories with their free nodes smoothed in time; `window` 0 returns them unchanged."""
    if window == 0:
        return list(meshes)
    smoothed = []
    for m in meshes:
        free = np.asarray(m.node_type) == NORMAL
        meta = {**m.meta, "smoothing": f"savgol window {window} order {order}"}
        smoothed.append(replace(m, world_pos=savgol_positions(m.world_pos, free, window, order), meta=meta))
    return smoothed


def smoothing_tag(window: int, order: int) -> str:
    """What the stage-3 fit key adds for smoothed meshes ('' when off, so keys of unsmoothed fits stay as they were)."""
    return f"+savgol{window}.{order}" if window else ""
