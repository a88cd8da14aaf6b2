"""Several rows' DVC grids drawn as one labelled figure, read back from the unlabelled grid pictures."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from clods_bench.benchmark.outputs.grid_figure import grid_tiles, labelled_grids
from clods_bench.benchmark.outputs.media import write_image_grid
from clods_bench.errors import ClodsError


def _grid(path: Path, truth: list[np.ndarray], shift: float) -> Path:
    return write_image_grid(path, truth, [np.clip(t + shift, 0, 1) for t in truth])


@pytest.fixture
def truth() -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.random((2, 32, 40, 3)).astype(np.float32) for _ in range(3)]  # 3 frames, 2 views of 32x40 px


def test_tiles_are_cut_back_out_of_a_grid(tmp_path: Path, truth: list[np.ndarray]) -> None:
    tiles = grid_tiles(_grid(tmp_path / "a.png", truth, 0.0), frames=3, views=2)
    k = 4  # write_image_grid scales a 40-px tile to at least 128 px
    assert tiles.shape == (2, 2, 3, 32 * k, 40 * k, 3)
    expected = np.clip(np.rint(np.kron(truth[1][0], np.ones((k, k, 1))) * 255), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(tiles[0, 0, 1], expected)  # view 0, truth row, frame 1
    np.testing.assert_array_equal(tiles[:, 0], tiles[:, 1])  # a perfect prediction


def test_the_labelled_figure_and_its_errors(tmp_path: Path, truth: list[np.ndarray]) -> None:
    grids = {"A": _grid(tmp_path / "a.png", truth, 0.0), "B": _grid(tmp_path / "b.png", truth, 0.2)}
    out = labelled_grids(grids, [76, 88, 100], 2, "title", tmp_path / "out.png")
    assert iio.imread(out).shape[1] > 1000
    with pytest.raises(ClodsError, match="not a grid of 4 rows and 4 columns") as err:
        labelled_grids(grids, [1, 2, 3, 4], 2, "title", tmp_path / "bad.png")
    assert err.value.where == str(grids["A"])
    other = _grid(tmp_path / "c.png", [t[::-1] for t in truth], 0.0)  # the views swapped: other truth
    with pytest.raises(ClodsError, match="truth rows differ from those of 'A'") as err:
        labelled_grids({**grids, "C": other}, [76, 88, 100], 2, "title", tmp_path / "bad.png")
    assert err.value.where == str(other)
    assert not (tmp_path / "bad.png").exists()
