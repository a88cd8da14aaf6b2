"""Toy videos shared by the video-predictor tests."""

from __future__ import annotations

import numpy as np


def moving_square(frames: int = 14, size: int = 16, side: int = 4, y0: int = 6) -> np.ndarray:
    """(T,H,W,3): a white side x side square on black moving one pixel right per frame."""
    video = np.zeros((frames, size, size, 3), np.float32)
    for t in range(frames):
        video[t, y0 : y0 + side, t : t + side] = 1.0
    return video
