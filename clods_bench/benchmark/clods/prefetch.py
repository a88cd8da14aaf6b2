"""Read the next video frame while the current one is fitted.

Frames rendered on demand (data.frames=on_demand) cost the CPU rasterizer a read per frame; on a GPU the stage-2 fit
of a frame takes about as long, so reading frame t+1 in a background thread while frame t is fitted hides most of
the read. The frames are the same arrays either way, so the fit does not depend on it.
"""

from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np


def frames_ahead(video: Any, start: int, stop: int, ahead: bool = True) -> Iterator[tuple[int, np.ndarray]]:
    """(t, video[t]) for t in start..stop-1, each read once, in order; with `ahead`, frame t+1 is read in a worker
    thread while the caller works on frame t (at most one frame is held beyond the one yielded)."""
    if not ahead:
        for t in range(start, stop):
            yield t, np.asarray(video[t])
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="clods-frame-read") as pool:
        pending: Future | None = pool.submit(lambda i: np.asarray(video[i]), start) if start < stop else None
        for t in range(start, stop):
            assert pending is not None
            frame = pending.result()  # a read that failed raises here, for the frame it failed on
            pending = pool.submit(lambda i: np.asarray(video[i]), t + 1) if t + 1 < stop else None
            yield t, frame
        # a generator closed early (an error in the caller's loop) leaves at most one read running; the pool's
        # shutdown waits for it, and its result is dropped
