"""When learned simulators drift: RMSE, largest edge strain and energy over the frames of long stability rollouts.

Reads the per-frame curves that `clods-bench run stability` stores in each record (`seed_<s>/result.json`: the RMSE
averaged over the rollouts, the largest edge strain and the largest energy ratio over them) from one or more
records folders, and writes `drift.csv` (every row's value at a few frames) and `drift.png` (one panel per curve,
the strain threshold drawn) to the output folder. Rows are named by their record's label, or by `NAME=FOLDER`:

    python examples/studies/rollout_drift.py results/small-partial/2026-12-07-table2-rerun/records \
        "BSMS (MGN cloth frame), gamma 0.1=results/studies/hierarchy_plateau/small/records/bsms_gamma0.1" \
        --out results/studies/hierarchy_plateau/small
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

CURVES = (("rmse", "RMSE to the ground truth (m)"), ("max_strain", "largest edge strain"), ("energy_ratio", "energy / the truth's largest"))
FRAMES = (2, 5, 10, 20, 40, 80, 120, 160, 200)


def read_rows(source: str, seed: int) -> dict[str, dict[str, np.ndarray]]:
    """Every stability record under a folder (`NAME=FOLDER` names a folder holding one): label -> curve -> values."""
    name, _, folder = source.rpartition("=") if "=" in source else ("", "", source)
    rows: dict[str, dict[str, np.ndarray]] = {}
    for record in sorted(Path(folder).glob("**/stability/*/*/record.json")):
        result = record.parent / f"seed_{seed}" / "result.json"
        if not result.exists():
            continue
        label = name or json.loads(record.read_text())["label"]
        curves = json.loads(result.read_text())["curves"]
        rows[label] = {key: np.asarray(curves[key], dtype=float) for key, _ in CURVES}
    if not rows:
        raise SystemExit(f"no stability record with seed {seed} under {folder}")
    if name and len(list(Path(folder).glob("**/stability/*/*/record.json"))) > 1:
        raise SystemExit(f"{source}: a named folder must hold one stability record; {folder} holds several")
    return rows


def write_csv(rows: dict[str, dict[str, np.ndarray]], path: Path) -> None:
    """One line per row and curve: its values at FRAMES (empty past the rollout's end)."""
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["row", "curve", *(f"frame_{i}" for i in FRAMES)])
        for label, curves in rows.items():
            for key, _ in CURVES:
                c = curves[key]
                writer.writerow([label, key, *(f"{c[i]:.4g}" if i < len(c) and np.isfinite(c[i]) else "" for i in FRAMES)])


def plot(rows: dict[str, dict[str, np.ndarray]], strain_threshold: float, title: str, path: Path) -> None:
    """Three panels over the frames, one line per row; the strain panel on a log scale with the threshold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(CURVES), figsize=(15, 4.4), dpi=110)
    for ax, (key, ylabel) in zip(axes, CURVES):
        for label, curves in rows.items():
            c = curves[key]
            ax.plot(np.arange(len(c)), c, label=label, linewidth=1.4)
        if key == "max_strain":
            ax.axhline(strain_threshold, color="black", linestyle=":", linewidth=1, label=f"threshold {strain_threshold:g}")
            ax.set_yscale("log")
        ax.set_xlabel("frame")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    handles, labels = axes[1].get_legend_handles_labels()  # the strain panel also holds the threshold
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), fontsize=9, frameon=False)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.06 * (1 + (len(labels) - 1) // 4), 1, 1))
    fig.savefig(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("records", nargs="+", help="records folders, or NAME=FOLDER for a folder holding one run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--strain-threshold", type=float, default=0.5)
    parser.add_argument("--title", default="Long rollouts (stability task), seed 0")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    rows: dict[str, dict[str, np.ndarray]] = {}
    for source in args.records:
        rows.update(read_rows(source, args.seed))
    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(rows, args.out / "drift.csv")
    plot(rows, args.strain_threshold, args.title, args.out / "drift.png")
    for label, curves in rows.items():
        print(label, *(f"{curves['rmse'][i]:.3f}" for i in FRAMES if i < len(curves["rmse"])), sep="\t")


if __name__ == "__main__":
    sys.exit(main())
