"""Turn run records into the paper's table layout: markdown, LaTeX and CSV (pandas)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd

from clods_bench.atomic import write_text
from clods_bench.benchmark.metrics import GROUPS, PHASES, STATS
from clods_bench.benchmark.records import iter_records
from clods_bench.errors import ClodsError

GROUP_NAMES = {"viewed": "Viewed", "unviewed": "Unviewed"}
PHASE_NAMES = {"interp": "Interpolation", "extrap": "Extrapolation"}


def _stat_names(phase: str, interp: int, last: int) -> dict[str, str]:
    if phase == "interp":
        return {"d_avg": f"d_avg(t<={interp})", "d_end": f"d(t={interp})", "avg": "Avg."}
    return {"d_avg": f"d_avg({interp}<t<={last})", "d_end": f"d(t={last})", "avg": "Avg."}


def fmt_cell(mean: float, std: float, digits: int = 4, diverged: int | None = None) -> str:
    """'0.1293 ± 0.0240', or 'diverged@k' when the value is not finite."""
    if mean is None or not math.isfinite(mean):
        return f"diverged@{diverged}" if diverged is not None else "n/a"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def _first_divergence(rec: dict[str, Any]) -> int | None:
    steps = [s for r in rec.get("per_seed", {}).values() for s in r.get("extra", {}).get("diverged", {}).values()]
    return min(steps) if steps else None


def cdg_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(display frame with 'mean ± std' strings and MultiIndex columns, numeric frame for CSV)."""
    display_rows, numeric_rows, index = [], [], []
    for rec in records:
        data = rec["config"]["data"]
        interp, last = data["interp_steps"], data["num_steps"] - 1
        row, num = {}, {"method": rec["label"], "seeds": len(rec["seeds"])}
        div = _first_divergence(rec)
        for g in GROUPS:
            for p in PHASES:
                names = _stat_names(p, interp, last)
                for s in STATS:
                    m = rec["metrics"].get(f"{g}/{p}/{s}", {"mean": float("nan"), "std": float("nan")})
                    mean = float("nan") if m["mean"] is None else m["mean"]
                    std = float("nan") if m["std"] is None else m["std"]
                    row[(GROUP_NAMES[g], PHASE_NAMES[p], names[s])] = fmt_cell(mean, std, diverged=div)
                    num[f"{g}/{p}/{s}/mean"] = mean
                    num[f"{g}/{p}/{s}/std"] = std
        t = rec["timings"]
        infer = t.get("infer_ms_per_step", {}).get("mean", float("nan"))
        fit = t.get("fit_seconds", {}).get("mean", float("nan"))
        row[("Time", "", "infer ms/step")] = f"{infer:.3g}"
        row[("Time", "", "fit s")] = f"{fit:.3g}"
        num["infer_ms_per_step"], num["fit_seconds"] = infer, fit
        display_rows.append(row)
        numeric_rows.append(num)
        index.append(rec["label"])
    display = pd.DataFrame(display_rows, index=pd.Index(index, name="Method"))
    display.columns = pd.MultiIndex.from_tuples(display.columns)
    return display, pd.DataFrame(numeric_rows)


def to_markdown(display: pd.DataFrame) -> str:
    """Markdown with flattened 'Viewed / Interpolation / d(t=30)' headers."""
    flat = display.copy()
    flat.columns = [" / ".join(p for p in col if p) for col in flat.columns]
    return flat.to_markdown()


def write_tables(runs_dir: Path, out_dir: Path, task: str = "cdg") -> list[Path]:
    """Write one markdown/LaTeX/CSV table per (scene, preset) from the records of `task`; return the paths."""
    if task != "cdg":
        raise ClodsError(f"no table layout for task '{task}' yet", where="tables --task")
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for _, rec in iter_records(runs_dir, task):
        groups.setdefault((rec["scene"], rec["preset"]), []).append(rec)
    if not groups:
        raise ClodsError(f"no '{task}' run records found", where=str(runs_dir), hint="run e.g. `clods-bench run cdg --sim constvel` first")
    written = []
    for (scene, preset), recs in sorted(groups.items()):
        recs.sort(key=lambda r: r["label"])
        display, numeric = cdg_frame(recs)
        stem = out_dir / f"{task}_{scene}_{preset}"
        seeds = sorted({len(r["seeds"]) for r in recs})
        caption = (
            f"CDG rollout RMSE ({scene}, preset {preset}); mean ± std over {'/'.join(map(str, seeds))} seeds; "
            "Viewed = second half of the training trajectories, Unviewed = test trajectories."
        )
        write_text(stem.with_suffix(".md"), f"{caption}\n\n{to_markdown(display)}\n")
        write_text(stem.with_suffix(".tex"), display.to_latex(caption=caption, multicolumn_format="c"))
        write_text(stem.with_suffix(".csv"), numeric.to_csv(index=False))
        written += [stem.with_suffix(s) for s in (".md", ".tex", ".csv")]
    return written
