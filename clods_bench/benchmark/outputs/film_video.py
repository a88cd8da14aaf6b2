"""Labelled animations of the image tasks (NVS, DVC): the true frames above each method's, view by view, over time.

One animation per group of rows of one table that show the same trajectory, views and frames: a row per source
(ground truth first, then each method, labelled on the left), a column per scored view (labelled on top), and the
frame number in the title bar; every frame of the films becomes one frame of the animation.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from clods_bench.benchmark.outputs.animation_files import CONTROLS_PAD, label_font, write_animation
from clods_bench.benchmark.outputs.films import Film

MIN_TILE = 128
"""Tiles are enlarged (nearest neighbour, by a whole factor) to at least this many pixels a side."""
LABEL_W, TOP_H, GAP = 170, 46, 4


def film_fps(num_frames: int) -> float:
    """10 frames a second for a long film, slower for a few frames (an NVS run at ci scores 2): at least 2 s to watch."""
    return float(min(10.0, max(1.0, num_frames / 2.0)))


def film_video_frames(rows: list[tuple[str, Film]], title: str) -> np.ndarray:
    """(F,H,W,3) uint8: per film frame, the truth row (of the first film) and one row per (label, film) prediction."""
    from PIL import Image, ImageDraw

    first = rows[0][1]
    views, frames, h, w, _ = first.truth.shape
    k = max(1, math.ceil(MIN_TILE / max(h, w)))
    th, tw = h * k, w * k
    sources = [("ground truth", first.truth)] + [(label, film.pred) for label, film in rows]
    width = LABEL_W + views * (tw + GAP) + GAP
    height = TOP_H + len(sources) * (th + GAP) + GAP + CONTROLS_PAD
    base = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(base)
    for v, view in enumerate(first.views):
        draw.text((LABEL_W + v * (tw + GAP) + GAP + 4, TOP_H - 18), f"view {view}", fill=(0, 0, 0), font=label_font(13))
    for r, (label, _) in enumerate(sources):
        y = TOP_H + r * (th + GAP) + GAP
        role = "truth" if r == 0 else "prediction"
        draw.text((6, y + th // 2 - 16), label if len(label) <= 22 else label[:21] + "...", fill=(0, 0, 0), font=label_font(13))
        draw.text((6, y + th // 2 + 2), role, fill=(90, 90, 90), font=label_font(11))
    out = []
    for f in range(frames):
        frame = base.copy()
        draw = ImageDraw.Draw(frame)
        draw.text((6, 4), f"{title}: frame {first.frames[f]} ({f + 1} of {frames} shown)", fill=(0, 0, 0), font=label_font(14))
        for r, (_, video) in enumerate(sources):
            y = TOP_H + r * (th + GAP) + GAP
            for v in range(views):
                tile = np.kron(video[v, f], np.ones((k, k, 1), np.uint8)) if k > 1 else video[v, f]
                frame.paste(Image.fromarray(np.ascontiguousarray(tile)), (LABEL_W + v * (tw + GAP) + GAP, y))
        out.append(np.asarray(frame))
    return np.stack(out)


def write_film_video(stem: Path, rows: list[tuple[str, Film]], title: str, fmt: str | None = None) -> Path:
    """Write the group's animation to `stem`.mp4 (PyAV) or .webp (Pillow); returns the path written."""
    return write_animation(film_video_frames(rows, title), stem, film_fps(len(rows[0][1].frames)), fmt)
