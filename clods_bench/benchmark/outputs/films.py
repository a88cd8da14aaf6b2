"""Films: the true and predicted frames of one trajectory an image task scored (NVS, DVC), saved per seed.

`seed_N/<name>_frames.npz` holds `truth` and `pred` (N views, F frames, H, W, 3) as uint8, the dataset views and
frame indices they show, the trajectory ("traj 0", "extrapolation traj 0") and a title. The report lays the films
of one table's rows that show the same trajectory side by side in one animation (`film_video`).
"""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clods_bench.atomic import write_npz
from clods_bench.errors import ClodsError

FILM_SUFFIX = "_frames.npz"
"""Seed-directory files ending so are films."""


@dataclass(frozen=True)
class Film:
    """Frames of one trajectory: truth and prediction (N,F,H,W,3) uint8 over `views` and `frames`."""

    path: Path
    truth: np.ndarray
    pred: np.ndarray
    views: list[int]
    frames: list[int]
    trajectory: str
    title: str


def to_uint8(images: np.ndarray) -> np.ndarray:
    """Float images in [0, 1] (or uint8) as uint8, rounded and clipped."""
    arr = np.asarray(images)
    if arr.dtype == np.uint8:
        return arr
    return np.clip(np.rint(np.nan_to_num(arr.astype(np.float64), nan=0.0) * 255.0), 0, 255).astype(np.uint8)


def save_film(path: Path, truth: np.ndarray, pred: np.ndarray, views: Sequence[int], frames: Sequence[int], trajectory: str,
              title: str = "") -> Path:  # fmt: skip
    """Write a film atomically; `truth` and `pred` are (N,F,H,W,3) in [0, 1] (or uint8) over `views` and `frames`; more
    frames than `film_cap` allows are thinned evenly."""
    truth, pred = np.asarray(truth), np.asarray(pred)
    if truth.shape != pred.shape or truth.ndim != 5 or truth.shape[-1] != 3 or truth.shape[:2] != (len(views), len(frames)):
        raise ClodsError(f"truth {truth.shape} and prediction {pred.shape} must both be ({len(views)} views, {len(frames)} frames, H, W, 3)",
                         where=str(path))  # fmt: skip
    keep = film_frame_picks(len(frames), film_cap(*truth.shape[0:1], *truth.shape[2:4]))
    truth, pred, frames = to_uint8(truth[:, keep]), to_uint8(pred[:, keep]), [list(frames)[k] for k in keep]
    write_npz(path, truth=truth, pred=pred, views=np.asarray(list(views), np.int64), frames=np.asarray(list(frames), np.int64),
              trajectory=np.asarray(str(trajectory)), title=np.asarray(str(title)))  # fmt: skip
    return path


def load_film(path: Path) -> Film:
    """The film at `path`; one that cannot be read or whose arrays disagree is a ClodsError naming the file."""
    path = Path(path)
    if not zipfile.is_zipfile(path):
        raise ClodsError("not a readable film (not an .npz archive)", where=str(path))
    try:
        with np.load(path) as z:
            film = Film(path, z["truth"], z["pred"], [int(v) for v in z["views"]], [int(f) for f in z["frames"]], str(z["trajectory"]), str(z["title"]))
    except (OSError, KeyError, ValueError, EOFError) as exc:
        raise ClodsError(f"not a readable film ({type(exc).__name__}: {exc})", where=str(path)) from None
    shape = film.truth.shape
    if film.pred.shape != shape or len(shape) != 5 or shape[:2] != (len(film.views), len(film.frames)) or film.truth.dtype != np.uint8:
        raise ClodsError(f"truth {shape} and prediction {film.pred.shape} do not match {len(film.views)} views x {len(film.frames)} frames",
                         where=str(path))  # fmt: skip
    return film


FILM_MAX_FRAMES = 60
"""At most this many frames per film (evenly spread over the scored ones)."""
FILM_MAX_BYTES = 16 * 2**20
"""...and at most about this many bytes of uint8 frames, truth and prediction together."""


def film_cap(views: int, height: int, width: int) -> int:
    """Frames a film of `views` views at height x width keeps: FILM_MAX_FRAMES, fewer when they would pass FILM_MAX_BYTES
    (at least 2, the first and the last scored frame)."""
    per_frame = 2 * max(views, 1) * height * width * 3
    return max(2, min(FILM_MAX_FRAMES, FILM_MAX_BYTES // max(per_frame, 1)))


def film_frame_picks(num_frames: int, cap: int) -> list[int]:
    """Up to `cap` positions of `num_frames`, evenly spread, first and last kept (films of long runs stay small)."""
    if num_frames <= cap:
        return list(range(num_frames))
    return sorted({int(round(x)) for x in np.linspace(0, num_frames - 1, cap)})
