"""Image grids written by the image tasks (NVS, DVC): ground truth above prediction, one column per frame."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from clods_bench.atomic import atomic_path


def write_image_grid(path: Path, gts: list[np.ndarray], preds: list[np.ndarray], min_side: int = 128, gap: int = 2) -> Path:
    """PNG grid: per held-out view a ground-truth row above a rendered row, one column per shown frame."""
    import imageio.v3 as iio

    views, h, w, _ = gts[0].shape
    k = max(1, math.ceil(min_side / max(h, w)))
    tile_h, tile_w = h * k + gap, w * k + gap
    canvas = np.full((2 * views * tile_h + gap, len(gts) * tile_w + gap, 3), 0.5, dtype=np.float32)  # grey gaps
    for c, (gt, pred) in enumerate(zip(gts, preds)):
        for v in range(views):
            for r, img in enumerate((gt[v], pred[v])):
                y, x = gap + (2 * v + r) * tile_h, gap + c * tile_w
                canvas[y : y + h * k, x : x + w * k] = np.kron(img, np.ones((k, k, 1), dtype=np.float32))
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, np.clip(np.rint(canvas * 255.0), 0, 255).astype(np.uint8), extension=".png")
    return path
