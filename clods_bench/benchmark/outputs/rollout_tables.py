"""The layouts of the rollout tables: CDG (the paper's Table 2, per group, phase and statistic) and stability
(long rollouts per simulator and scene, and where they diverge)."""

from __future__ import annotations

import math
import re
from typing import Any

import pandas as pd

from clods_bench.benchmark.outputs.tables import fmt_cell, seeds_phrase
from clods_bench.benchmark.scoring.metrics import GROUPS, PHASES, STATS

GROUP_NAMES = {"viewed": "Viewed", "unviewed": "Unviewed"}
PHASE_NAMES = {"interp": "Interpolation", "extrap": "Extrapolation"}


def _stat_names(phase: str, interp: int, last: int) -> dict[str, str]:
    if phase == "interp":
        return {"d_avg": f"d_avg(t<={interp})", "d_end": f"d(t={interp})", "avg": "Avg."}
    return {"d_avg": f"d_avg({interp}<t<={last})", "d_end": f"d(t={last})", "avg": "Avg."}


def _first_divergence(rec: dict[str, Any]) -> int | None:
    steps = [s for r in rec.get("per_seed", {}).values() for s in r.get("extra", {}).get("diverged", {}).values()]
    return min(steps) if steps else None


def _scored_horizon(rec: dict[str, Any]) -> tuple[int, int]:
    """(last interpolation frame, last frame) of the data a CDG record scored: as its seeds recorded them
    (`scored_data`, which `task_config.cdg.eval_data` may have changed), else its `data` section's."""
    data = dict(rec["config"]["data"])
    for seed in rec.get("per_seed", {}).values():
        data.update({k: v for k, v in seed.get("extra", {}).get("scored_data", {}).items() if k in ("interp_steps", "num_steps")})
    return int(data["interp_steps"]), int(data["num_steps"]) - 1


def cdg_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """(display frame with 'mean ± std' strings and MultiIndex columns, numeric frame for CSV, no notes)."""
    display_rows, numeric_rows, index = [], [], []
    for rec in records:
        interp, last = _scored_horizon(rec)
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
        strain = rec["metrics"].get("max_strain") or {}
        s_mean = float("nan") if strain.get("mean") is None else strain["mean"]
        s_std = float("nan") if strain.get("std") is None else strain["std"]
        row[("Stability", "", "max edge strain")] = fmt_cell(s_mean, s_std, digits=3, diverged=div)  # a diverged rollout's strain is inf
        num["max_strain/mean"], num["max_strain/std"] = s_mean, s_std
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
    return display, pd.DataFrame(numeric_rows), []




def cdg_caption(scene: str, preset: str, records: list[dict[str, Any]], notes: list[str]) -> str:
    """Caption of a CDG table: what is scored and over how many seeds."""
    return (
        f"CDG rollout RMSE ({scene}, preset {preset}); mean ± std over {seeds_phrase(records)}; "
        "Viewed = second half of the training trajectories, Unviewed = test trajectories."
    )


def _divergence_cell(rec: dict[str, Any]) -> tuple[str, float, str]:
    """('stable' | 'frame k (n/N rollouts): reason', first failing frame or NaN, its reason) over every seed's rollouts."""
    failed, rollouts = [], 0
    for seed in rec.get("per_seed", {}).values():
        extra = seed.get("extra", {})
        rollouts += int(extra.get("rollouts", 0))
        for key, frame in extra.get("diverged", {}).items():
            failed.append((int(frame), str(extra.get("reasons", {}).get(key, "diverged"))))
    if not failed:
        return "stable", float("nan"), ""
    frame, reason = min(failed)
    return f"frame {frame} ({len(failed)}/{rollouts} rollouts): {reason}", float(frame), reason


def failure_kind(reason: str) -> str:
    """The kind of a divergence reason without its measured values: 'edge strain 0.523 > 0.5' -> 'edge strain',
    'exception: FloatingPointError: overflow ...' -> 'exception: FloatingPointError' (CSV cells compared as text)."""
    if reason.startswith("exception:"):
        return ":".join(reason.split(":")[:2]).strip()
    return re.split(r"\s+[-+]?\d", reason, maxsplit=1)[0].strip()


def stability_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """(display frame, numeric frame, no notes): per simulator and scene, long-rollout RMSE, max edge strain, divergence
    or 'stable'."""
    display_rows, numeric_rows, index = [], [], []
    for rec in records:
        m, t = rec["metrics"], rec["timings"]

        def get(key: str, section: dict[str, Any] = m) -> tuple[float, float]:
            v = section.get(key, {})
            mean, std = v.get("mean"), v.get("std")
            return (float("nan") if mean is None else mean, float("nan") if std is None else std)

        rmse, strain = get("rmse"), get("max_strain")
        horizon = int(get("horizon_frames")[0]) if math.isfinite(get("horizon_frames")[0]) else None
        cell, first, reason = _divergence_cell(rec)
        display_rows.append(
            {
                "Scene": rec["scene"],
                "Frames": "n/a" if horizon is None else str(horizon),
                "RMSE": fmt_cell(*rmse) if math.isfinite(rmse[0]) else "n/a (diverged)",
                "Max edge strain": fmt_cell(*strain, digits=3) if math.isfinite(strain[0]) else "n/a (diverged)" if math.isfinite(first) else "n/a",
                "GT max strain": f"{get('gt_max_strain')[0]:.3g}",
                "Divergence": cell,
                "infer ms/step": f"{get('infer_ms_per_step', t)[0]:.3g}",
            }
        )
        numeric_rows.append(
            {
                "method": rec["label"],
                "scene": rec["scene"],
                "seeds": len(rec["seeds"]),
                "horizon_frames": horizon,
                "rmse/mean": rmse[0],
                "rmse/std": rmse[1],
                "max_strain/mean": strain[0],
                "max_strain/std": strain[1],
                "gt_max_strain": get("gt_max_strain")[0],
                "diverged_fraction": get("diverged_fraction")[0],
                "first_divergence": first,
                "reason": failure_kind(reason),
                "infer_ms_per_step": get("infer_ms_per_step", t)[0],
                "fit_seconds": get("fit_seconds", t)[0],
            }
        )
        index.append(rec["label"])
    return pd.DataFrame(display_rows, index=pd.Index(index, name="Method")), pd.DataFrame(numeric_rows), []




def stability_caption(scene: str, preset: str, records: list[dict[str, Any]], notes: list[str]) -> str:
    """Caption of a stability table (one per preset, its rows on several scenes); rows on fewer seeds are named."""
    over = "seeds" if len({len(r["seeds"]) for r in records}) <= 1 else seeds_phrase(records)
    return (
        f"Long-rollout stability (preset {preset}); RMSE over the frames with ground truth and max edge strain "
        f"|l/l0 - 1|: mean ± std over {over}; divergence = first frame with NaN/Inf, strain or kinetic energy over threshold."
    )
