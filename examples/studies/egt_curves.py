"""Plot stage 2's extraction error per frame (E-GT) of several runs, read from their `result.json` records.

A `run extract` or `run cdg` record keeps `extra.egt_curve`: per frame, the per-coordinate RMSE (m) of the extracted
mesh against the true mesh of its first extracted trajectory. This draws the curves of the given records on one
log-scale axis and prints each one's mean, largest value and the frames above a threshold, so two stage-2 settings
can be compared over a whole video (for example the paper trajectory before and after the `paper` preset's settings).

    python examples/studies/egt_curves.py old/result.json:defaults new/result.json:"paper preset" --out egt.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from clods_bench.atomic import atomic_path


def load_curve(path: Path) -> np.ndarray:
    """The E-GT curve (m per frame) of one result.json; a clear error when the record has none."""
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise SystemExit(f"{path}: cannot read a result record ({err})") from err
    curve = record.get("extra", {}).get("egt_curve")
    if not curve:
        raise SystemExit(f"{path}: no extra.egt_curve (not a stage-2 run's record?)")
    return np.asarray(curve, dtype=float)


def summary(curve: np.ndarray, threshold: float) -> str:
    """Mean and largest E-GT over the fitted frames (1..), and how many frames exceed `threshold`."""
    fitted = curve[1:]
    worst = int(np.argmax(fitted)) + 1
    above = int(np.sum(fitted > threshold))
    return (f"{fitted.size} frames: mean {1000 * fitted.mean():.2f} mm, largest {1000 * fitted.max():.2f} mm at frame {worst}, "
            f"{above} frames above {1000 * threshold:.0f} mm")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("records", nargs="+", help="result.json[:label] of each run")
    p.add_argument("--out", type=Path, default=None, help="PNG to draw the curves into")
    p.add_argument("--threshold", type=float, default=0.02, help="E-GT (m) above which a frame counts as lost")
    args = p.parse_args()
    curves = []
    for spec in args.records:
        path, _, label = spec.partition(":")
        curve = load_curve(Path(path))
        curves.append((label or path, curve))
        print(f"{label or path}: {summary(curve, args.threshold)}")
    if args.out is None:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.2))
    for label, curve in curves:
        ax.semilogy(np.arange(1, curve.size), 1000 * curve[1:], label=label, lw=1.2)
    ax.axhline(1000 * args.threshold, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("frame")
    ax.set_ylabel("E-GT (mm, per coordinate)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(args.out) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
