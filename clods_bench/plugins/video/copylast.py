"""Copy-last-frame: every future frame equals the last observed one (the floor any video predictor must beat)."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from clods_bench.benchmark.core.interfaces import FitContext, check_video


class CopyLastPredictor:
    """Predicts frame C-1 of the context for every future frame; nothing to train."""

    def fit(self, videos: Sequence[np.ndarray], ctx: FitContext) -> dict[str, float]:
        """Nothing to learn; the videos are only checked."""
        for i, v in enumerate(videos):
            check_video(v, where=f"copylast.fit: video {i}")
        return {}

    def predict(self, context: np.ndarray, num_frames: int, cameras: Sequence[Any] = ()) -> np.ndarray:
        """(N,num_frames,H,W,3): the last context frame of each view, repeated."""
        ctx = check_video(context, where="copylast.predict: context", ndim=5)
        last = ctx[:, -1:]
        return np.repeat(last, num_frames, axis=1)
