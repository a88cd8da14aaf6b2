"""Mesh pictures: per-node and per-face errors against hand-computed values, sample files, the PNG grid."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from clods_bench.benchmark.outputs.mesh_pictures import (  # fmt: skip
    choose_frames,
    face_errors,
    load_mesh_sample,
    node_errors,
    plot_mesh_sample,
    save_mesh_sample,
)
from clods_bench.errors import ClodsError

CELLS = np.array([[0, 1, 2], [1, 3, 2]])
SQUARE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float64)


def _frames(t: int = 5) -> np.ndarray:
    return np.stack([SQUARE + [0, 0, 0.1 * k] for k in range(t)])  # the square rising 0.1 m per frame


def test_node_and_face_errors_by_hand() -> None:
    truth = _frames(2)
    pred = truth.copy()
    pred[1, 3] += [0.3, 0.4, 0.0]  # node 3 off by 0.5 m at frame 1
    pred[1, 0, 2] = np.nan
    err = node_errors(truth, pred)
    assert err[0].tolist() == [0, 0, 0, 0]
    assert np.isnan(err[1, 0]) and err[1, 1:].tolist() == pytest.approx([0, 0, 0.5])
    faces = face_errors(CELLS, np.nan_to_num(err))
    assert faces[1].tolist() == pytest.approx([0.0, 0.5 / 3])  # face (1,3,2) holds node 3; face (0,1,2) does not


def test_choose_frames() -> None:
    assert choose_frames(81, [30]) == [1, 30, 80]
    assert choose_frames(2) == [1]
    assert choose_frames(1) == [0]
    assert choose_frames(100, [10, 20, 30, 40]) == [1, 10, 20, 99]


def test_round_trip_and_shape_errors(tmp_path: Path) -> None:
    truth = _frames()
    path = save_mesh_sample(tmp_path / "a_meshes.npz", CELLS, {"mgn": truth + 0.01}, truth=truth, marks=[3], title="t")
    cells, meshes, got_truth, marks, title = load_mesh_sample(path)
    assert cells.tolist() == CELLS.tolist() and marks == [3] and title == "t"
    np.testing.assert_allclose(meshes["mgn"], truth + 0.01, rtol=1e-6)
    np.testing.assert_allclose(got_truth, truth, rtol=1e-6)
    with pytest.raises(ClodsError, match="'bad' has shape") as exc:
        save_mesh_sample(tmp_path / "b_meshes.npz", CELLS, {"bad": truth[:, :3]}, truth=truth)
    assert "b_meshes.npz" in str(exc.value)
    assert not (tmp_path / "b_meshes.npz").exists()


def test_picture_is_a_png_grid_with_and_without_truth(tmp_path: Path) -> None:
    truth = _frames()
    pred = truth + np.linspace(0, 0.2, 4)[None, :, None]
    pred[4] = np.nan  # a diverged frame is drawn as text, not a crash
    sample = save_mesh_sample(tmp_path / "r_meshes.npz", CELLS, {"mgn": pred}, truth=truth, marks=[2])
    img = iio.imread(plot_mesh_sample(sample, tmp_path / "r.png"))
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 300 and img.std() > 1  # 3 rows x 2 columns, not blank
    blank = save_mesh_sample(tmp_path / "n_meshes.npz", CELLS, {"extracted": truth})
    assert iio.imread(plot_mesh_sample(blank, tmp_path / "n.png", frames=[0, 4])).shape[0] > 100
