"""Report: Pareto front against brute force, files written from synthetic records."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from clods_bench.atomic import write_json
from clods_bench.benchmark.outputs.report import HEADLINE, pareto_front, write_report
from clods_bench.errors import ClodsError


def _brute_front(err: list[float], tim: list[float]) -> list[bool]:
    """A point is on the front unless some other point is no worse in both and better in one."""
    out = []
    for i in range(len(err)):
        if not (np.isfinite(err[i]) and np.isfinite(tim[i])):
            out.append(False)
            continue
        beaten = False
        for j in range(len(err)):
            if j != i and np.isfinite(err[j]) and np.isfinite(tim[j]):
                if err[j] <= err[i] and tim[j] <= tim[i] and (err[j] < err[i] or tim[j] < tim[i]):
                    beaten = True
        out.append(not beaten)
    return out


def test_pareto_front_against_brute_force() -> None:
    rng = np.random.default_rng(0)
    for trial in range(200):
        n = int(rng.integers(1, 9))
        err = rng.integers(0, 4, n).astype(float)  # small integer grids: many ties
        tim = rng.integers(0, 4, n).astype(float)
        if trial % 5 == 0:
            err[rng.integers(0, n)] = np.nan
        assert pareto_front(err, tim).tolist() == _brute_front(err.tolist(), tim.tolist())
    # a hand case: (1,3) (2,2) (3,1) form the front, (3,3) is dominated, a duplicate of a front point stays on it
    assert pareto_front(np.array([1, 2, 3, 3, 2.0]), np.array([3, 2, 1, 3, 2.0])).tolist() == [True, True, True, False, True]


def _record(runs: Path, label: str, sim: str, rmse: float, infer_ms: float, fit_s: float, curves: list[list[float]]) -> None:
    rdir = runs / "cdg" / label / "flag-ci-00000000"
    for seed, curve in enumerate(curves):
        write_json(rdir / f"seed_{seed}" / "result.json", {"seed": seed, "metrics": {}, "timings": {}, "curves": {"unviewed": curve, "viewed": curve}})
    write_json(rdir / "record.json", {
        "task": "cdg", "label": label, "sim": sim, "scene": "flag", "preset": "ci", "seeds": list(range(len(curves))),
        "metrics": {HEADLINE: {"mean": rmse, "std": 0.1 * rmse}},
        "timings": {"infer_ms_per_step": {"mean": infer_ms, "std": 0.0}, "fit_seconds": {"mean": fit_s, "std": 0.0}},
        "config": {"data": {"interp_steps": 3, "num_steps": 6}},
    })  # fmt: skip


def test_write_report_from_synthetic_records(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    c = [0.0, 0.0, 0.1, 0.2, 0.3, 0.4]
    _record(runs, "mgn-5", "mgn", 0.05, 20.0, 100.0, [c, [2 * v for v in c]])
    _record(runs, "mgn-15", "mgn", 0.03, 60.0, 300.0, [c])
    _record(runs, "physics-dt2", "physics", 0.04, 80.0, 0.0, [c])
    _record(runs, "constvel", "constvel", 0.30, 0.01, 0.0, [c])
    _record(runs, "slow-bad", "x", 0.50, 100.0, 500.0, [c])
    paths = write_report(runs, tmp_path / "report")
    assert sorted(p.name for p in paths) == sorted(
        ["error_vs_time_flag_ci.csv", "error_vs_time_flag_ci.png", "rollout_rmse_flag_ci.csv", "rollout_rmse_flag_ci.png"]
    )
    for p in paths:
        assert p.is_file() and p.stat().st_size > 0
        if p.suffix == ".png":
            assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    pts = pd.read_csv(tmp_path / "report" / "error_vs_time_flag_ci.csv").set_index("label")
    assert pts.loc["mgn-5", "rmse"] == pytest.approx(0.05) and pts.loc["physics-dt2", "fit_seconds"] == 0.0
    # inference: constvel fastest, mgn-5 then mgn-15 each cheaper-or-better; physics is slower and worse than mgn-15
    for key in ("infer_ms_per_step", "fit_seconds"):
        expected = _brute_front(pts["rmse"].tolist(), pts[key].tolist())
        assert pts[f"pareto_{key}"].tolist() == expected
    assert pts["pareto_infer_ms_per_step"].to_dict() == {"constvel": True, "mgn-15": True, "mgn-5": True, "physics-dt2": False, "slow-bad": False}
    # training: physics (0 s) beats constvel (0 s, worse) and mgn-5; only mgn-15 buys a lower error with training time
    assert pts["pareto_fit_seconds"].to_dict() == {"constvel": False, "mgn-15": True, "mgn-5": False, "physics-dt2": True, "slow-bad": False}
    curves = pd.read_csv(tmp_path / "report" / "rollout_rmse_flag_ci.csv")
    got = curves[(curves["label"] == "mgn-5") & (curves["group"] == "unviewed")]["rmse"].to_numpy()
    np.testing.assert_allclose(got, 1.5 * np.array(c))  # mean over the two seeds' curves


def test_report_without_records_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    with pytest.raises(ClodsError, match="no 'cdg' run records"):
        write_report(tmp_path / "runs", tmp_path / "out")


def test_front_of_all_subsets_is_monotone() -> None:
    """Along the front sorted by time the error strictly falls (else a point would dominate another)."""
    rng = np.random.default_rng(1)
    err, tim = rng.random(12), rng.random(12)
    for subset in itertools.combinations(range(12), 6):
        idx = np.array(subset)
        front = idx[pareto_front(err[idx], tim[idx])]
        order = front[np.argsort(tim[front])]
        assert np.all(np.diff(err[order]) < 0)


def test_error_accumulation_of_clods_rows(tmp_path: Path) -> None:
    """CloDS records carry E-GT / P-GT / P-E curves per seed: the report averages them (a diverged seed's NaN stays a gap)."""
    runs = tmp_path / "runs"
    c = [0.0, 0.0, 0.1, 0.2, 0.3, 0.4]
    _record(runs, "constvel", "constvel", 0.30, 0.01, 0.0, [c])
    _record(runs, "CloDS**", "mgn", 0.05, 5.0, 60.0, [c, c])
    rdir = runs / "cdg" / "CloDS**" / "flag-ci-00000000"
    acc = [{"E-GT": [0.0, 0.01, 0.02], "P-GT": [0.0, 0.02, 0.04], "P-E": [0.0, 0.015, 0.03]},
           {"E-GT": [0.0, 0.03, 0.04], "P-GT": [0.0, 0.04, None], "P-E": [0.0, 0.025, 0.05]}]  # fmt: skip
    for seed, curves in enumerate(acc):
        write_json(rdir / f"seed_{seed}" / "result.json", {"seed": seed, "metrics": {}, "timings": {}, "curves": {"unviewed": c, "viewed": c}, "extra": {"accumulation": curves}})
    paths = write_report(runs, tmp_path / "report")
    assert {"error_accumulation_flag_ci.csv", "error_accumulation_flag_ci.png"} <= {p.name for p in paths}
    got = pd.read_csv(tmp_path / "report" / "error_accumulation_flag_ci.csv")
    assert set(got["label"]) == {"CloDS**"}  # the mesh-supervised row has no such curves
    egt = got[got["curve"] == "E-GT"]["rmse"].to_numpy()
    np.testing.assert_allclose(egt, [0.0, 0.02, 0.03])
    pgt = got[got["curve"] == "P-GT"]["rmse"].to_numpy()
    assert pgt[1] == pytest.approx(0.03) and np.isnan(pgt[2])


def test_training_curves_from_stability_records(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    rdir = runs / "stability" / "mgn" / "flag-small-00000000"
    curves = {0: {"step": [10, 20], "train_loss": [2.0, 1.0], "rmse": [0.4, 0.2], "max_strain": [3.0, 0.4],
                  "diverged_fraction": [1.0, 0.0], "first_divergence": [9.0, None]},
              1: {"step": [10, 20], "train_loss": [4.0, 3.0], "rmse": [0.6, 0.4], "max_strain": [5.0, 0.6],
                  "diverged_fraction": [1.0, 0.5], "first_divergence": [7.0, 30.0]}}  # fmt: skip
    for seed, curve in curves.items():
        write_json(rdir / f"seed_{seed}" / "result.json", {"seed": seed, "metrics": {}, "extra": {"training_curve": curve}})
    write_json(rdir / "record.json", {"task": "stability", "label": "MGN", "sim": "mgn", "scene": "flag", "preset": "small", "seeds": [0, 1]})
    paths = write_report(runs, tmp_path / "report")  # no cdg records: the curves alone make a report
    assert sorted(p.name for p in paths) == ["training_curves_flag_small.csv", "training_curves_flag_small.png"]
    frame = pd.read_csv(tmp_path / "report" / "training_curves_flag_small.csv")
    assert list(frame["seed"]) == [0, 0, 1, 1] and list(frame["step"]) == [10, 20, 10, 20]
    np.testing.assert_allclose(frame.groupby("step")["rmse"].mean().to_numpy(), [0.5, 0.3])
    assert np.isnan(frame["first_divergence"].iloc[1]) and frame["max_strain"].iloc[3] == 0.6
