"""Training curves of learned simulators: the stability task's scores of each weight snapshot, as CSV and a plot.

A stability run with `task_config.stability.curve_every` scores the simulator's snapshots with the same
long rollouts as its final model (`extra.training_curve` of each seed). This module gathers them per
(scene, preset) so that a preset's training length can be read off measured convergence, not guessed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from clods_bench.atomic import write_text
from clods_bench.benchmark.outputs.figure_style import WIDTH_IN, page_style, pyplot, save_png, value_axis
from clods_bench.benchmark.running.records import iter_records, load_seed_result

CURVE_COLUMNS = ["label", "seed", "step", "train_loss", "rmse", "max_strain", "diverged_fraction", "first_divergence"]


def training_curve_rows(runs_dir: Path) -> dict[tuple[str, str], pd.DataFrame]:
    """Per (scene, preset), one row per (record label, seed, snapshot step) of the stability records with curves."""
    rows: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for rdir, rec in iter_records(Path(runs_dir), "stability"):
        for seed in rec.get("seeds", []):
            result = load_seed_result(rdir, int(seed)) or {}
            curve = (result.get("extra") or {}).get("training_curve")
            if not curve:
                continue
            for k, step in enumerate(curve["step"]):
                row = {"label": rec["label"], "seed": int(seed), "step": int(step)}
                row.update({c: _num(curve.get(c, [None] * (k + 1))[k]) for c in CURVE_COLUMNS[3:]})
                rows.setdefault((rec["scene"], rec["preset"]), []).append(row)
    return {key: pd.DataFrame(r, columns=CURVE_COLUMNS) for key, r in rows.items()}


def _num(value: Any) -> float:
    return float("nan") if value is None else float(value)


def plot_training_curves(frame: pd.DataFrame, strain_threshold: float, title: str, path: Path) -> None:
    """Three panels against training step: training loss, long-rollout RMSE, largest edge strain (threshold dashed);
    one legend for the three, below them."""
    plt = pyplot()
    from matplotlib.ticker import FuncFormatter

    with page_style():
        fig, axes = plt.subplots(1, 3, figsize=(WIDTH_IN * 1.2, 4.2), layout="constrained")
        panels = (("train_loss", "training loss (normalised)"), ("rmse", "rollout RMSE (m), 2x horizon"), ("max_strain", "largest edge strain"))
        for ax, (column, name) in zip(axes, panels):
            for label, part in frame.groupby("label", sort=True):
                mean = part.groupby("step")[column].mean()
                ax.plot(mean.index, mean.values, marker="o", label=label)
            if column == "max_strain":
                ax.axhline(strain_threshold, color="k", ls="--", lw=1, label=f"tear threshold {strain_threshold:g}")
            values = frame[column].to_numpy(np.float64)
            value_axis(ax, "y", np.append(values, strain_threshold) if column == "max_strain" else values)
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v / 1000:g}k" if v else "0"))
            ax.set_xlabel("training step")
            ax.set_title(name)
            ax.grid(True, which="major", alpha=0.35)
        handles, labels = axes[2].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=len(labels))
        fig.suptitle(title)
        save_png(fig, path)
        plt.close(fig)


def write_training_curves(runs_dir: Path, out_dir: Path, strain_threshold: float = 0.5) -> list[Path]:
    """`training_curves_<scene>_<preset>.csv/.png` for every (scene, preset) with curves; returns the files written."""
    written: list[Path] = []
    for (scene, preset), frame in sorted(training_curve_rows(runs_dir).items()):
        frame = frame.sort_values(["label", "seed", "step"])
        csv_path, png_path = Path(out_dir) / f"training_curves_{scene}_{preset}.csv", Path(out_dir) / f"training_curves_{scene}_{preset}.png"
        write_text(csv_path, frame.to_csv(index=False))
        finite = frame.replace([np.inf, -np.inf], np.nan)
        plot_training_curves(finite, strain_threshold, f"training curves ({scene}, preset {preset})", png_path)
        written += [csv_path, png_path]
    return written
