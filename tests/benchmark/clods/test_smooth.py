"""Temporal smoothing of extracted meshes (`task_config.clods.smooth_window`): against a brute-force least-squares
polynomial per window, exact on polynomials, noise cut on accelerations, fixed frame 0 and handles, keys and errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.clods.config import ClodsConfig, clods_config
from clods_bench.benchmark.clods.pipeline import extraction_identity
from clods_bench.benchmark.clods.smooth import savgol_positions, smooth_meshes, smoothing_tag
from clods_bench.benchmark.core.cache_keys import digest
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.datasets.types import HANDLE, NORMAL, Trajectory
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config


def _trajectory(world_pos: np.ndarray, node_type: np.ndarray) -> Trajectory:
    v = world_pos.shape[1]
    return Trajectory(np.array([[0, 1, 2]], np.int32), np.zeros((v, 2), np.float32), node_type.astype(np.int32), world_pos, 0.02, {"scene": "x"})


def test_interior_frames_equal_a_brute_force_polynomial_fit_per_window():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20, 3, 3))
    free = np.array([True, True, False])
    out = savgol_positions(x, free, 7, 2)
    t = np.arange(-3, 4)
    for f in range(3, 17):  # every frame with a full centred window
        for v in (0, 1):
            for c in range(3):
                coeffs = np.polyfit(t, x[f - 3 : f + 4, v, c], 2)
                assert out[f, v, c] == pytest.approx(np.polyval(coeffs, 0.0), abs=1e-12)
    np.testing.assert_array_equal(out[:, 2], x[:, 2])  # a handle moves as extracted
    np.testing.assert_array_equal(out[0], x[0])  # frame 0 is the given initial mesh


def test_quadratic_motion_passes_unchanged_and_noise_on_accelerations_is_cut():
    t = np.arange(41, dtype=np.float64)[:, None, None]
    truth = 0.3 + 0.01 * t - 0.0005 * t**2 + np.zeros((1, 50, 3))  # constant acceleration: a degree-2 track
    np.testing.assert_allclose(savgol_positions(truth, np.ones(50, bool), 7, 2)[1:], truth[1:], atol=1e-12)
    noisy = truth + np.random.default_rng(1).normal(scale=1e-3, size=truth.shape)
    smoothed = savgol_positions(noisy, np.ones(50, bool), 7, 2)
    acc = lambda x: np.sqrt(np.mean((np.diff(x, 2, axis=0) - np.diff(truth, 2, axis=0)) ** 2))  # noqa: E731
    # White noise of sd s gives sqrt(6) s on second differences; in the interior the window-7 quadratic filter's
    # weights (least squares, -2/21 ... 7/21) convolved with [1, -2, 1] give 0.218 of that, the ends a little more.
    ratio = acc(smoothed) / acc(noisy)
    assert 0.18 < ratio < 0.26
    pos = lambda x: np.sqrt(np.mean((x - truth)[1:] ** 2))  # noqa: E731
    assert pos(smoothed) < pos(noisy)


def test_smooth_meshes_keeps_the_trajectory_and_says_what_it_did():
    x = np.random.default_rng(2).normal(size=(9, 3, 3)).astype(np.float32)
    traj = _trajectory(x, np.array([NORMAL, NORMAL, HANDLE]))
    assert smooth_meshes([traj], 0, 2)[0] is traj  # off: the extraction as it was
    (out,) = smooth_meshes([traj], 5, 2)
    assert out.world_pos.dtype == np.float32 and out.world_pos.shape == x.shape and out.cells is traj.cells
    assert out.meta["smoothing"] == "savgol window 5 order 2" and "smoothing" not in traj.meta
    assert not np.allclose(out.world_pos[1:, :2], x[1:, :2])
    with pytest.raises(ClodsError) as err:
        smooth_meshes([traj], 11, 2)
    assert err.value.where == "task_config.clods.smooth_window" and "9 extracted frames" in str(err.value)


@pytest.mark.parametrize("window, order, field", [(4, 2, "smooth_window"), (1, 0, "smooth_window"), (-3, 2, "smooth_window"), (5, 5, "smooth_order"), (5, 0, "smooth_order")])
def test_bad_settings_are_one_error_naming_the_field(window, order, field):
    with pytest.raises(ClodsError) as err:
        ClodsConfig(smooth_window=window, smooth_order=order).validate()
    assert err.value.where == f"task_config.clods.{field}"


def test_smoothing_changes_the_stage3_key_and_not_the_extraction_key():
    key = lambda opts: digest(extraction_identity("abc123", opts, {"scene": "flag", "seed": 0}, 31, [0, 1]))  # noqa: E731
    assert key(ClodsConfig(smooth_window=7, smooth_order=3)) == key(ClodsConfig())  # the same stage-2 meshes
    assert smoothing_tag(0, 2) == "" and smoothing_tag(7, 2) != smoothing_tag(7, 3) != ""


def test_a_cdg_run_with_smoothing_trains_on_smoothed_meshes_and_reports_both_errors(tiny_root: Path, tmp_path: Path):
    fast = ["renderer_config.games.iterations=10", "renderer_config.games.gaussians_per_face=1", "task_config.clods.iterations=3",
            "task_config.clods.min_iterations=3", f"runs_dir={tmp_path}"]  # fmt: skip
    cfg = tiny_config(tiny_root, *fast, "task_config.clods.smooth_window=5", sim="constvel", renderer="games")
    assert clods_config(cfg).smooth_window == 5
    run_task(cfg, default_registry())
    plain = run_task(tiny_config(tiny_root, *fast, sim="constvel", renderer="games"), default_registry())
    timings = json.loads((plain / RECORD_FILE).read_text())["per_seed"]["0"]["timings"]
    assert "fit/egt_smoothed_rmse" not in timings
    smoothed_dir = next(p.parent for p in tmp_path.glob("cdg/*/*/" + RECORD_FILE) if p.parent != plain)
    t = json.loads((smoothed_dir / RECORD_FILE).read_text())["per_seed"]["0"]["timings"]
    assert t["fit/egt_rmse"] == pytest.approx(timings["fit/egt_rmse"])  # stage 2 ran once: the same meshes
    assert np.isfinite(t["fit/egt_smoothed_rmse"]) and t["fit/egt_smoothed_rmse"] != t["fit/egt_rmse"]
    assert len(list(tmp_path.glob("clods_cache/*/traj_*.npz"))) == 2  # one extraction, both rows
