"""Why the hierarchical simulators (BSMS, DHMP) trained to a plateau: each hypothesis as a CDG run, side by side.

Runs `clods-bench run cdg` once per variant (a variant is a simulator with `--set` overrides), at a preset and seed,
into one runs folder (a finished record is reused, so the study resumes), then writes `variants.csv` (the four Avg.
RMSE columns, the largest edge strain, the final training loss and the fit's seconds per variant) and
`loss_curves.png` (each variant's training loss) to the output folder. The variants file is YAML:

    - {name: bsms_raw, sim: bsms, set: ["sim_config.bsms.position_scale=raw"]}
    - {name: bsms_level, sim: bsms, set: ["sim_config.bsms.position_scale=level"]}

    python examples/studies/hierarchy_plateau.py results/studies/hierarchy_plateau/variants_ci.yaml \
        --preset ci --seed 0 --runs runs/plateau --out results/studies/hierarchy_plateau/ci
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

COLUMNS = ("viewed/interp/avg", "viewed/extrap/avg", "unviewed/interp/avg", "unviewed/extrap/avg", "max_strain")


def run_variant(variant: dict, preset: str, seed: int, runs: Path) -> Path:
    """Run (or resume) one variant; return its runs folder."""
    folder = runs / variant["name"]
    cmd = ["clods-bench", "run", "cdg", "--sim", variant["sim"], "--preset", preset, "--no-progress", "--jobs", "1",
           "--set", f"seeds=[{seed}]", "--set", f"runs_dir={folder}"]  # fmt: skip
    for override in variant.get("set", []):
        cmd += ["--set", override]
    print(" ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return folder


def summarise(variant: dict, folder: Path, seed: int) -> tuple[dict, list[float]]:
    """The variant's row (metrics, final loss, fit seconds) and its loss curve."""
    result = json.loads(next(folder.glob(f"cdg/*/*/seed_{seed}/result.json")).read_text())
    log = next(folder.glob("fit_cache/*/*_train_log.json"), None)
    curve = json.loads(log.read_text())["loss_curve"] if log else []
    row = {"variant": variant["name"], "sim": variant["sim"], "overrides": " ".join(variant.get("set", []))}
    row.update({c: round(float(result["metrics"][c]), 4) for c in COLUMNS})
    row["final_loss"] = round(float(result["timings"].get("fit/final_loss", float("nan"))), 4)  # the last 100 steps
    row["fit_s"] = round(float(result["timings"].get("fit_seconds", float("nan"))), 1)
    return row, curve


def plot(curves: dict[str, list[float]], sims: dict[str, str], path: Path, title: str) -> None:
    """Training loss (a moving average of 9 points) of every variant against the fraction of training done: one
    panel per simulator, MGN's variants drawn in every panel as the reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [s for s in dict.fromkeys(sims.values()) if s not in ("mgn", "frozen")] or ["mgn"]
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4.6), dpi=110, squeeze=False, sharey=True)
    for ax, sim in zip(axes[0], panels):
        ax.set_prop_cycle(color=plt.cm.tab20.colors)
        for name, curve in curves.items():
            if not curve or sims[name] not in (sim, "mgn"):
                continue
            smooth = np.convolve(curve, np.ones(9) / 9, mode="valid")
            x = (np.arange(len(smooth)) + 5) / len(curve)
            style = {"color": "black", "linestyle": "--"} if sims[name] == "mgn" else {}
            ax.plot(x, smooth, label=name, linewidth=1.3, **style)
        ax.set_yscale("log")
        ax.set_xlabel("fraction of the training steps")
        ax.set_title(sim.upper())
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right", ncol=2 if len(ax.lines) > 8 else 1)
    axes[0][0].set_ylabel("training loss (normalised, log scale)")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variants", type=Path, help="YAML list of {name, sim, set}")
    parser.add_argument("--preset", default="ci")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--runs", type=Path, default=Path("runs/plateau"))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    variants = yaml.safe_load(args.variants.read_text())
    args.out.mkdir(parents=True, exist_ok=True)
    rows, curves = [], {}
    for variant in variants:
        folder = run_variant(variant, args.preset, args.seed, args.runs)
        row, curve = summarise(variant, folder, args.seed)
        rows.append(row)
        curves[variant["name"]] = curve
    with open(args.out / "variants.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    sims = {v["name"]: v["sim"] for v in variants}
    plot(curves, sims, args.out / "loss_curves.png", f"Training loss, preset {args.preset}, seed {args.seed} (a velocity output's loss is in other units)")
    for row in rows:
        print(*(row[k] for k in ("variant", *COLUMNS, "final_loss")), sep="\t")


if __name__ == "__main__":
    sys.exit(main())
