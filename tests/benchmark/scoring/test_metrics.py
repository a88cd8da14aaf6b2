"""Rollout RMSE and the Table 2 columns against hand-computed values."""

from __future__ import annotations

import numpy as np

from clods_bench.benchmark.scoring.metrics import cdg_columns, divergence_step, rmse_per_step


def test_rmse_per_step_known_values() -> None:
    gt = np.zeros((3, 4, 3))
    pred = np.zeros((3, 4, 3))
    pred[1, :, 0] = 2.0  # every node off by 2 in x: mean sq over nodes*coords = 4/3
    pred[2, 0, :] = 1.0  # one node off by 1 in all coords: mean = 3/12
    np.testing.assert_allclose(rmse_per_step(pred, gt), [0.0, np.sqrt(4 / 3), np.sqrt(0.25)])


def test_cdg_columns_paper_definitions() -> None:
    # curve[t] = t: interp frames 2..4 (interp_steps=4), extrap 5..6 (num_steps=7)
    curve = np.arange(7, dtype=float)
    cols = cdg_columns({"viewed": [curve, curve + 1.0]}, interp_steps=4, num_steps=7)
    assert cols["viewed/interp/d_avg"] == np.mean([2, 3, 4, 3, 4, 5])
    assert cols["viewed/interp/d_end"] == 4.5
    assert cols["viewed/interp/avg"] == 0.5 * (3.5 + 4.5)
    assert cols["viewed/extrap/d_avg"] == np.mean([5, 6, 6, 7])
    assert cols["viewed/extrap/d_end"] == 6.5


def test_divergence_step() -> None:
    pred = np.zeros((5, 2, 3))
    assert divergence_step(pred) is None
    pred[3, 1, 2] = np.nan
    pred[4] = np.inf
    assert divergence_step(pred) == 3
