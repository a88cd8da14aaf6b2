"""`clods-bench report`: rollout error against inference and training time, with the Pareto front, and error curves.

One point per CDG record (a simulator at one size / label, e.g. MGN with 5/10/15 message-passing
steps via --label, or physics at several dt factors). The headline error is the unviewed
(test-trajectory) extrapolation RMSE d_avg: the frames no simulator trained on, of trajectories
it never saw. A point is on the Pareto front when no other point has both lower-or-equal error
and lower-or-equal time, one of them strictly. Figures per (scene, preset): PNG plus CSV.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from clods_bench.atomic import write_text
from clods_bench.benchmark.outputs.figure_style import FONT_PT, WIDTH_IN, log_ticks, metric_words, page_style, pyplot, save_png, value_axis
from clods_bench.benchmark.outputs.training_curves import write_training_curves
from clods_bench.benchmark.running.records import iter_records, load_seed_result
from clods_bench.errors import ClodsError

HEADLINE = "unviewed/extrap/d_avg"
TIME_AXES = (("infer_ms_per_step", "inference time per rollout step (ms)"), ("fit_seconds", "training time (s)"))
TIME_FLOOR = 1e-3  # log axes: times below this (untrained baselines: fit ~ 0 s) are drawn at the floor


def pareto_front(errors: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(N,) bool: points no other point dominates (error and time both <=, one <); NaN points are never on it."""
    err = np.asarray(errors, np.float64)
    tim = np.asarray(times, np.float64)
    ok = np.isfinite(err) & np.isfinite(tim)
    front = ok.copy()
    for i in np.flatnonzero(ok):
        dominated = ok & (err <= err[i]) & (tim <= tim[i]) & ((err < err[i]) | (tim < tim[i]))
        front[i] = not dominated.any()
    return front


def _mean(section: dict[str, Any], key: str) -> tuple[float, float]:
    v = section.get(key) or {}
    mean, std = v.get("mean"), v.get("std")
    return (float("nan") if mean is None else float(mean), float("nan") if std is None else float(std))


def report_points(records: list[dict[str, Any]], metric: str = HEADLINE) -> pd.DataFrame:
    """One row per record: label, simulator, error (mean, std over seeds), times, Pareto flags per time axis."""
    rows = []
    for rec in records:
        err, err_std = _mean(rec["metrics"], metric)
        row = {"label": rec["label"], "sim": rec.get("sim"), "scene": rec["scene"], "preset": rec["preset"], "metric": metric,
               "rmse": err, "rmse_std": err_std, "seeds": len(rec.get("seeds", []))}  # fmt: skip
        for key, _ in TIME_AXES:
            row[key] = _mean(rec["timings"], key)[0]
        rows.append(row)
    frame = pd.DataFrame(rows)
    for key, _ in TIME_AXES:
        frame[f"pareto_{key}"] = pareto_front(frame["rmse"].to_numpy(), frame[key].to_numpy()) if len(frame) else []
    return frame


def padded_mean(curves: list[np.ndarray]) -> np.ndarray:
    """Element-wise mean of curves of unequal length (missing tail and NaN entries stay NaN: a diverged seed shows as a gap)."""
    n = max(len(c) for c in curves)
    stacked = np.full((len(curves), n), np.nan)
    for i, c in enumerate(curves):
        stacked[i, : len(c)] = c
    return stacked.mean(axis=0)


def _seed_curves(rdir: Path, rec: dict[str, Any], section: str, key: str | None = None) -> dict[str, np.ndarray]:
    """Per name, the mean over the record's finished seeds of `result[section]` (or `result[section][key]`) curves."""
    per_name: dict[str, list[np.ndarray]] = {}
    for seed in rec.get("seeds", []):
        result = load_seed_result(rdir, int(seed)) or {}
        found = result.get(section) or {}
        if key is not None:
            found = found.get(key) or {}
        for name, curve in found.items():
            per_name.setdefault(name, []).append(np.array([np.nan if v is None else v for v in curve], np.float64))
    return {name: padded_mean(curves) for name, curves in per_name.items()}


def mean_curves(rdir: Path, rec: dict[str, Any]) -> dict[str, np.ndarray]:
    """Per group ('viewed', 'unviewed'), the RMSE-per-frame curve averaged over the record's finished seeds."""
    return _seed_curves(rdir, rec, "curves")


def _save_png(fig: Any, path: Path) -> None:
    save_png(fig, path)


def plot_error_vs_time(points: pd.DataFrame, title: str, path: Path) -> None:
    """Two panels (error vs inference time, error vs training time), log time axes, Pareto front joined and ringed;
    the error axis titled in words (`metric_words`)."""
    plt = pyplot()
    metric = str(points["metric"].iloc[0]) if len(points) else HEADLINE
    with page_style():
        fig, axes = plt.subplots(1, 2, figsize=(WIDTH_IN, 4.6), sharey=True, layout="constrained")
        for ax, (key, xlabel) in zip(axes, TIME_AXES):
            ok = np.isfinite(points["rmse"]) & np.isfinite(points[key])
            data = points[ok]
            x = np.maximum(data[key].to_numpy(), TIME_FLOOR)
            y = data["rmse"].to_numpy()
            ax.errorbar(x, y, yerr=np.nan_to_num(data["rmse_std"].to_numpy()), fmt="o", color="tab:blue", capsize=3)
            for xi, yi, label in zip(x, y, data["label"]):
                ax.annotate(str(label), (xi, yi), textcoords="offset points", xytext=(5, 4), fontsize=FONT_PT - 1)
            front = data[data[f"pareto_{key}"].astype(bool)].sort_values(key)
            if len(front):
                fx = np.maximum(front[key].to_numpy(), TIME_FLOOR)
                ax.step(fx, front["rmse"].to_numpy(), where="post", color="tab:red", lw=1.2, label="Pareto front")
                ax.scatter(fx, front["rmse"], s=140, facecolors="none", edgecolors="tab:red")
                ax.legend(loc="best", framealpha=0.9)
            ax.set_xscale("log")
            if len(x):
                log_ticks(ax.xaxis, float(x.min()), float(x.max()))
                ax.margins(x=0.12)
            ax.set_xlabel(xlabel + (f"\n(< {TIME_FLOOR:g} drawn at {TIME_FLOOR:g})" if (data[key] < TIME_FLOOR).any() else ""))
            if ax is axes[0]:
                value_axis(ax, "y", points["rmse"])
                words = metric_words(metric)
                ax.set_ylabel(words.replace(", ", "\n", 1) if words != metric else f"{metric} (m)")
            ax.grid(True, which="major", alpha=0.35)
        fig.suptitle(title)
        _save_png(fig, path)
        plt.close(fig)


def plot_curves(curves: dict[str, dict[str, np.ndarray]], interp: int | None, title: str, path: Path, ylabel: str = "RMSE (m)",
                first_frame: int = 0) -> None:  # fmt: skip
    """Error per frame, one line per label, one panel per group; the interpolation/extrapolation boundary dashed.
    A curve's values start at `first_frame`; frames 0 and 1 (given to a rollout) are left out; log scale for RMSE."""
    plt = pyplot()
    with page_style():
        _plot_curves(plt, curves, interp, title, path, ylabel, first_frame)


def _plot_curves(plt: Any, curves: dict[str, dict[str, np.ndarray]], interp: int | None, title: str, path: Path, ylabel: str,
                 first_frame: int) -> None:  # fmt: skip
    groups = sorted({g for c in curves.values() for g in c}, reverse=True)  # viewed, unviewed (the paper's column order)
    fig, axes = plt.subplots(1, max(len(groups), 1), figsize=(WIDTH_IN, 4.4), squeeze=False, sharey=True, layout="constrained")
    for ax, group in zip(axes[0], groups):
        positive = True
        for label, per_group in sorted(curves.items()):
            if group not in per_group:
                continue
            c = np.asarray(per_group[group], np.float64)
            frames = np.arange(first_frame, first_frame + len(c))
            keep = frames >= 2
            ax.plot(frames[keep], c[keep], label=label)
            positive &= bool(np.all(c[keep][np.isfinite(c[keep])] > 0))
        if interp is not None:
            ax.axvline(interp, color="gray", ls="--", lw=1)
        if positive and ylabel.startswith("RMSE"):
            ax.set_yscale("log")
            lo, hi = ax.get_ylim()
            log_ticks(ax.yaxis, lo, hi)
        ax.set_title(f"{group} trajectories" if group in ("viewed", "unviewed") else group)
        ax.set_xlabel("frame")
        if ax is axes[0][0]:
            ax.set_ylabel(ylabel)
        ax.grid(True, which="major", alpha=0.35)
        ax.legend()
    fig.suptitle(title)
    _save_png(fig, path)
    plt.close(fig)


def accumulation_curves(rdir: Path, rec: dict[str, Any]) -> dict[str, np.ndarray]:
    """A CloDS record's error-accumulation curves ('E-GT', 'P-GT', 'P-E' per frame), averaged over its seeds ({} for others)."""
    return _seed_curves(rdir, rec, "extra", "accumulation")


def plot_accumulation(curves: dict[str, dict[str, np.ndarray]], title: str, path: Path) -> None:
    """One panel per CloDS row: extraction vs truth (E-GT), prediction vs truth (P-GT), prediction vs extraction (P-E)."""
    plt = pyplot()
    with page_style():
        _plot_accumulation(plt, curves, title, path)


def _plot_accumulation(plt: Any, curves: dict[str, dict[str, np.ndarray]], title: str, path: Path) -> None:
    labels = sorted(curves)
    fig, axes = plt.subplots(1, len(labels), figsize=(WIDTH_IN, 4.0), squeeze=False, sharey=True, layout="constrained")
    styles = {"E-GT": ("tab:green", "extracted vs truth (E-GT)"), "P-GT": ("tab:blue", "predicted vs truth (P-GT)"),
              "P-E": ("tab:orange", "predicted vs extracted (P-E)")}  # fmt: skip
    for ax, label in zip(axes[0], labels):
        for key, (color, name) in styles.items():
            c = curves[label].get(key)
            if c is not None:
                ax.plot(np.arange(1, len(c)), c[1:], color=color, label=name)
        ax.set_title(label)
        ax.set_xlabel("frame (training videos)")
        ax.grid(True, alpha=0.3)
        if ax is axes[0][0]:
            ax.set_ylabel("RMSE (m)")
            ax.legend()
    fig.suptitle(title)
    _save_png(fig, path)
    plt.close(fig)


def write_report(runs_dir: Path, out_dir: Path, metric: str = HEADLINE) -> list[Path]:
    """Error-vs-time plots (PNG + CSV, Pareto front marked) and RMSE-per-frame curves per (scene, preset) of the CDG records,
    and the training curves of stability records that have them."""
    groups: dict[tuple[str, str], list[tuple[Path, dict[str, Any]]]] = {}
    for rdir, rec in iter_records(Path(runs_dir), "cdg"):
        groups.setdefault((rec["scene"], rec["preset"]), []).append((rdir, rec))
    out_dir = Path(out_dir)
    written: list[Path] = write_training_curves(Path(runs_dir), out_dir)
    if not groups and not written:
        raise ClodsError("no 'cdg' run records found", where=str(runs_dir), hint="run e.g. `clods-bench run cdg --sim constvel` first")
    for (scene, preset), items in sorted(groups.items()):
        items.sort(key=lambda item: item[1]["label"])
        records = [rec for _, rec in items]
        points = report_points(records, metric)
        stem = f"{scene}_{preset}"
        csv_path = out_dir / f"error_vs_time_{stem}.csv"
        write_text(csv_path, points.to_csv(index=False))
        png_path = out_dir / f"error_vs_time_{stem}.png"
        plot_error_vs_time(points, f"Error against run time ({scene}, preset {preset})", png_path)
        curves = {rec["label"]: mean_curves(rdir, rec) for rdir, rec in items}
        long_rows = [
            {"label": label, "group": group, "frame": t, "rmse": float(v)}
            for label, per_group in curves.items()
            for group, curve in per_group.items()
            for t, v in enumerate(curve)
        ]
        curves_csv = out_dir / f"rollout_rmse_{stem}.csv"
        write_text(curves_csv, pd.DataFrame(long_rows, columns=["label", "group", "frame", "rmse"]).to_csv(index=False))
        interp = records[0].get("config", {}).get("data", {}).get("interp_steps")
        curves_png = out_dir / f"rollout_rmse_{stem}.png"
        plot_curves(curves, interp, f"rollout RMSE per frame ({scene}, preset {preset})", curves_png)
        written += [csv_path, png_path, curves_csv, curves_png]
        accumulation = {rec["label"]: c for rdir, rec in items if (c := accumulation_curves(rdir, rec))}
        if accumulation:
            rows = [{"label": label, "curve": key, "frame": t, "rmse": float(v)} for label, per in accumulation.items() for key, c in per.items() for t, v in enumerate(c)]
            acc_csv, acc_png = out_dir / f"error_accumulation_{stem}.csv", out_dir / f"error_accumulation_{stem}.png"
            write_text(acc_csv, pd.DataFrame(rows, columns=["label", "curve", "frame", "rmse"]).to_csv(index=False))
            plot_accumulation(accumulation, f"error accumulation on the training videos ({scene}, preset {preset})", acc_png)
            written += [acc_csv, acc_png]
    return written
