"""One labelled figure of several methods' video-prediction grids: rows = the truth and each method, columns = frames.

The DVC task writes `dvc_grid.png` per record (`media.write_image_grid`: per held-out view a truth row above a
prediction row, one column per shown frame, 2-px grey gaps, no text). Side by side those pictures cannot be read
without knowing the layout; this module cuts them into tiles and draws one figure per view with the frame numbers
above the columns and the method names beside the rows. The truth rows of every grid must be the same pictures.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clods_bench.benchmark.outputs.figure_style import FONT_PT, WIDTH_IN, page_style, pyplot, save_png
from clods_bench.errors import ClodsError

GAP = 2
"""Grey pixels between the tiles of a grid (`media.write_image_grid`'s default)."""


def grid_tiles(path: Path, frames: int, views: int, gap: int = GAP) -> np.ndarray:
    """(views, 2, frames, h, w, 3) tiles of a grid PNG: per view (a scored camera) its truth row (0) and prediction row (1)."""
    import imageio.v3 as iio

    try:
        img = iio.imread(path)[..., :3]
    except OSError as exc:
        raise ClodsError(f"cannot read the grid picture: {exc}", where=str(path)) from None
    rows = 2 * views
    th, tw = (img.shape[0] - gap) / rows, (img.shape[1] - gap) / frames
    if th != int(th) or tw != int(tw) or th <= gap or tw <= gap:
        raise ClodsError(f"a {img.shape[1]}x{img.shape[0]} picture is not a grid of {rows} rows and {frames} columns with {gap}-px gaps",
                         where=str(path), hint="give the frames and views the grid was written with")  # fmt: skip
    th, tw = int(th), int(tw)
    tiles = np.stack([np.stack([img[gap + r * th : (r + 1) * th, gap + c * tw : (c + 1) * tw] for c in range(frames)]) for r in range(rows)])
    return tiles.reshape(views, 2, frames, *tiles.shape[2:])


def labelled_grids(grids: dict[str, Path], frames: list[int], views: int, title: str, out: Path) -> Path:
    """Draw the methods' grids (`{label: grid PNG}`) as one figure: rows = the truth, then each method in the given
    order; columns = the frames, the views (cameras) side by side. Returns `out`."""
    if not grids:
        raise ClodsError("no grid pictures given", where=str(out))
    tiles = {label: grid_tiles(path, len(frames), views) for label, path in grids.items()}
    first_label, first = next(iter(tiles.items()))
    for label, t in tiles.items():
        if t.shape != first.shape or not np.array_equal(t[:, 0], first[:, 0]):
            raise ClodsError(f"its truth rows differ from those of '{first_label}': the grids show other frames or views",
                             where=str(grids[label]))  # fmt: skip
    names = ["truth", *tiles]
    n_rows, n_cols = len(names), views * len(frames)
    plt = pyplot()
    with page_style():
        tile_in = min(WIDTH_IN / n_cols, 1.6)
        fig, axes = plt.subplots(n_rows, n_cols, figsize=(tile_in * n_cols + 1.6, tile_in * n_rows + 0.8), squeeze=False,
                                 gridspec_kw={"wspace": 0.04, "hspace": 0.04})  # fmt: skip
        for r, name in enumerate(names):
            for v in range(views):
                for c, frame in enumerate(frames):
                    ax = axes[r][v * len(frames) + c]
                    ax.imshow(first[v, 0, c] if r == 0 else tiles[name][v, 1, c], interpolation="nearest")
                    ax.set_xticks([])
                    ax.set_yticks([])
                    if r == 0:
                        ax.set_title(f"camera {v + 1}: frame {frame}" if views > 1 and c == 0 else f"frame {frame}", fontsize=FONT_PT - 1)
                    if v == 0 and c == 0:
                        ax.set_ylabel(name, rotation=0, ha="right", va="center", fontsize=FONT_PT)
        fig.suptitle(title)
        save_png(fig, out)
        plt.close(fig)
    return out
