"""Turn run records into the paper's table layout: markdown, LaTeX and CSV (pandas)."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from clods_bench.atomic import write_text
from clods_bench.benchmark.scoring.metrics import GROUPS, PHASES, STATS
from clods_bench.benchmark.running.records import iter_records, runs_label
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


def _scored_horizon(rec: dict[str, Any]) -> tuple[int, int]:
    """(last interpolation frame, last frame) of the data a CDG record scored: as its seeds recorded them
    (`scored_data`, which `task_config.cdg.eval_data` may have changed), else its `data` section's."""
    data = dict(rec["config"]["data"])
    for seed in rec.get("per_seed", {}).values():
        data.update({k: v for k, v in seed.get("extra", {}).get("scored_data", {}).items() if k in ("interp_steps", "num_steps")})
    return int(data["interp_steps"]), int(data["num_steps"]) - 1


def scored_scenes(rec: dict[str, Any]) -> set[str]:
    """Scenes a record was trained on and scored on (a CDG run with `eval_data` scores another scene)."""
    return {rec["scene"], *(s["extra"]["scored_data"]["scene"] for s in rec.get("per_seed", {}).values() if "scored_data" in s.get("extra", {}))}


def cdg_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(display frame with 'mean ± std' strings and MultiIndex columns, numeric frame for CSV)."""
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
        row[("Stability", "", "max edge strain")] = fmt_cell(s_mean, s_std, digits=3) if math.isfinite(s_mean) else "n/a"
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
    return display, pd.DataFrame(numeric_rows)


NVS_COLUMNS = (  # (metric key, column, scale, digits): the paper's Table 3 reports SSIM x10 and LPIPS x1000
    ("psnr", "PSNR (dB) ↑", 1.0, 4),
    ("ssim", "SSIM×10 ↑", 10.0, 3),
    ("lpips", "LPIPS×1000 ↓", 1000.0, 2),
)


def _lpips_reasons(rec: dict[str, Any]) -> list[str]:
    return sorted({r for s in rec.get("per_seed", {}).values() if (r := s.get("extra", {}).get("lpips_unavailable"))})


def image_metric_frame(
    records: list[dict[str, Any]],
    columns: tuple[tuple[str, str, float, int], ...],
    time_key: str,
    time_name: str,
    groups: tuple[tuple[str, str], ...] = (("", "Quality"),),
) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """(display frame, numeric frame with the scaled numbers shown, footnotes) of image-metric records (NVS, DVC).

    `columns`: (metric key, column name, scale, digits), repeated under each of `groups`: (metric key prefix,
    column group), e.g. ('extrap/', 'Extrapolation'). A record without LPIPS gets 'unavailable [k]' in its
    LPIPS cell, footnote k saying why.
    """
    display_rows, numeric_rows, index, notes = [], [], [], []
    for rec in records:
        row, num = {}, {"method": rec["label"], "seeds": len(rec["seeds"])}
        for (prefix, group), (key, name, scale, digits) in ((g, c) for g in groups for c in columns):
            col = prefix + (key if scale == 1.0 else f"{key}_x{scale:g}")  # CSV holds the scaled numbers shown
            m = rec["metrics"].get(prefix + key)
            if m is None or m["mean"] is None:
                reasons = _lpips_reasons(rec) if key == "lpips" else []
                marks = []
                for reason in reasons or ["not recorded"]:
                    if reason not in notes:
                        notes.append(reason)
                    marks.append(f"[{notes.index(reason) + 1}]")
                row[(group, name)] = "unavailable " + "".join(marks)
                num[f"{col}/mean"] = num[f"{col}/std"] = float("nan")
            else:
                row[(group, name)] = fmt_cell(scale * m["mean"], scale * (m["std"] or 0.0), digits=digits)
                num[f"{col}/mean"], num[f"{col}/std"] = scale * m["mean"], scale * (m["std"] or 0.0)
        t = rec["timings"]
        per_image = t.get(time_key, {}).get("mean", float("nan"))
        fit = t.get("fit_seconds", {}).get("mean", float("nan"))
        row[("Time", time_name)] = f"{per_image:.3g}"
        row[("Time", "fit s")] = f"{fit:.3g}"
        num[time_key], num["fit_seconds"] = per_image, fit
        display_rows.append(row)
        numeric_rows.append(num)
        index.append(rec["label"])
    display = pd.DataFrame(display_rows, index=pd.Index(index, name="Model"))
    display.columns = pd.MultiIndex.from_tuples(display.columns)
    return display, pd.DataFrame(numeric_rows), [f"[{k + 1}] {n}" for k, n in enumerate(notes)]


def nvs_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """(display frame in the paper's Table 3 layout, numeric frame for CSV, footnotes); rows are renderers."""
    return image_metric_frame(records, NVS_COLUMNS, "render_ms_per_frame", "render ms/frame")


def _image_caption(what: str, scored: str, per_image: str, scene: str, preset: str, records: list[dict[str, Any]], notes: list[str]) -> str:
    seeds = sorted({len(r["seeds"]) for r in records})
    text = f"{what} ({scene}, preset {preset}); {scored}; mean ± std over {'/'.join(map(str, seeds))} seeds; {per_image} ms per image (one view, one frame)."
    sources = sorted({src for r in records for s in r.get("per_seed", {}).values() if (src := s.get("extra", {}).get("lpips_source"))})
    if sources:
        text += " LPIPS: AlexNet v0.1, weights from " + " and ".join(sources) + "."
    return text + ("" if not notes else " LPIPS unavailable: " + "; ".join(notes) + ".")


def nvs_caption(scene: str, preset: str, records: list[dict[str, Any]], notes: list[str]) -> str:
    """Caption of the NVS table: what is scored, over how many seeds, and the footnotes."""
    return _image_caption("Dynamic-scene novel-view synthesis", "held-out cameras", "render", scene, preset, records, notes)


DVC_COLUMNS = (  # (metric key, column, scale, digits): the paper's Table 4 reports SSIM x10, LPIPS x100, RMSE x100
    ("psnr", "PSNR (dB) ↑", 1.0, 4),
    ("ssim", "SSIM×10 ↑", 10.0, 3),
    ("lpips", "LPIPS×100 ↓", 100.0, 3),
    ("rmse", "RMSE×100 ↓", 100.0, 2),
)


def dvc_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """(display frame in the paper's Table 4 layout, numeric frame for CSV, footnotes); rows are video predictors
    and simulator+renderer pairs."""
    return image_metric_frame(records, DVC_COLUMNS, "predict_ms_per_frame", "predict ms/frame")


def dvc_caption(scene: str, preset: str, records: list[dict[str, Any]], notes: list[str]) -> str:
    """Caption of the DVC table: what is scored, over how many seeds, and the footnotes."""
    return _image_caption("DVC forward / cloth video prediction", "extrapolation frames of the scored views", "predict", scene, preset, records, notes)


DVC_MULTI_COLUMNS = (  # the paper's appendix table on multiple trajectories prints SSIM, LPIPS and RMSE unscaled
    ("psnr", "PSNR (dB) ↑", 1.0, 4),
    ("ssim", "SSIM ↑", 1.0, 4),
    ("lpips", "LPIPS ↓", 1.0, 5),
    ("rmse", "RMSE ↓", 1.0, 5),
)
DVC_MULTI_GROUPS = (("extrap/", "Extrapolation"), ("gen/", "Generalization"))


def dvc_multi_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """(display frame in the layout of the paper's multi-trajectory table: Extrapolation and Generalization, each
    PSNR, SSIM, LPIPS, RMSE; numeric frame for CSV; footnotes)."""
    return image_metric_frame(records, DVC_MULTI_COLUMNS, "predict_ms_per_frame", "predict ms/frame", DVC_MULTI_GROUPS)


def dvc_multi_caption(scene: str, preset: str, records: list[dict[str, Any]], notes: list[str]) -> str:
    """Caption of the multi-trajectory table: which frames each group scores, seeds, footnotes."""
    scored = "Extrapolation = the frames after the interpolation phase of the training trajectories, Generalization = the first frames of unseen trajectories"
    return _image_caption("Video prediction trained on multiple trajectories", scored, "predict", scene, preset, records, notes)


EXTRACT_COLUMNS = (  # (metric key, column): E-GT in metres (RMSE of extracted vs true mesh, frames after the first)
    ("egt_avg", "E-GT avg (m) ↓"),
    ("egt_first_half", "E-GT 1st half"),
    ("egt_second_half", "E-GT 2nd half"),
    ("egt_end", "E-GT last frame"),
    ("edge_strain_max", "max edge strain"),
)
EXTRACT_IMAGE_COLUMNS = (  # a dataset without meshes: the extraction re-rendered, held-out cameras first
    ("psnr", "held-out PSNR (dB) ↑"),
    ("ssim", "held-out SSIM ↑"),
    ("train/psnr", "training PSNR (dB) ↑"),
    ("edge_strain_max", "max edge strain"),
)


def extract_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """(display frame, numeric frame, notes) of mesh-extraction runs: E-GT per part of the video, stage-2 cost."""
    display_rows, numeric_rows, index = [], [], []
    in_images = all("egt_avg" not in rec["metrics"] for rec in records)  # every row from video alone: no E-GT to show
    columns = EXTRACT_IMAGE_COLUMNS if in_images else EXTRACT_COLUMNS
    for rec in records:
        row, num = {}, {"method": rec["label"], "seeds": len(rec["seeds"])}
        for key, name in columns:
            m = rec["metrics"].get(key) or {}
            mean = float("nan") if m.get("mean") is None else float(m["mean"])
            std = float("nan") if m.get("std") is None else float(m["std"])
            row[("Extraction", name)] = fmt_cell(mean, std)
            num[f"{key}/mean"], num[f"{key}/std"] = mean, std
        t = rec["timings"]
        per_frame = t.get("stage2_ms_per_frame", {}).get("mean", float("nan"))
        fit = t.get("fit_seconds", {}).get("mean", float("nan"))
        row[("Time", "stage 2 ms/frame")] = f"{per_frame:.3g}"
        row[("Time", "stages 1-2 s")] = f"{fit:.3g}"
        num["stage2_ms_per_frame"], num["fit_seconds"] = per_frame, fit
        display_rows.append(row)
        numeric_rows.append(num)
        index.append(rec["label"])
    display = pd.DataFrame(display_rows, index=pd.Index(index, name="Setting"))
    display.columns = pd.MultiIndex.from_tuples(display.columns)
    note = "E-GT: RMSE (m) of the mesh recovered from video against the true mesh, frames after the given first one"
    if in_images:
        note = "a dataset without meshes: the recovered meshes rendered by their stage-1 renderer against the frames of the held-out and the training cameras"
    return display, pd.DataFrame(numeric_rows), [note]


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


def stability_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(display frame, numeric frame): per simulator and scene, long-rollout RMSE, max edge strain, divergence or 'stable'."""
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
                "Max edge strain": fmt_cell(*strain, digits=3) if math.isfinite(strain[0]) else "n/a",
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
    return pd.DataFrame(display_rows, index=pd.Index(index, name="Method")), pd.DataFrame(numeric_rows)


def write_stability_tables(runs_dir: Path | Sequence[Path], out_dir: Path) -> list[Path]:
    """One markdown/LaTeX/CSV stability table per preset, rows per (simulator, scene)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for _, rec in iter_records(runs_dir, "stability"):
        groups.setdefault(rec["preset"], []).append(rec)
    if not groups:
        raise ClodsError("no 'stability' run records found", where=runs_label(runs_dir), hint="run e.g. `clods-bench run stability --sim constvel` first")
    written = []
    for preset, recs in sorted(groups.items()):
        recs.sort(key=lambda r: (r["label"], r["scene"]))
        display, numeric = stability_frame(recs)
        stem = out_dir / f"stability_{preset}"
        caption = (
            f"Long-rollout stability (preset {preset}); RMSE over the frames with ground truth and max edge strain "
            "|l/l0 - 1|: mean ± std over seeds; divergence = first frame with NaN/Inf, strain or kinetic energy over threshold."
        )
        write_text(stem.with_suffix(".md"), f"{caption}\n\n{display.to_markdown()}\n")
        write_text(stem.with_suffix(".tex"), display.to_latex(caption=caption))
        write_text(stem.with_suffix(".csv"), numeric.to_csv(index=False))
        written += [stem.with_suffix(s) for s in (".md", ".tex", ".csv")]
    return written


def to_markdown(display: pd.DataFrame) -> str:
    """Markdown with flattened 'Viewed / Interpolation / d(t=30)' headers."""
    flat = display.copy()
    flat.columns = [" / ".join(p for p in col if p) for col in flat.columns]
    return flat.to_markdown()


def write_tables(runs_dir: Path | Sequence[Path], out_dir: Path, task: str = "cdg") -> list[Path]:
    """Write one markdown/LaTeX/CSV table per (scene, preset) from the records of `task` (under one runs folder
    or several); return the paths."""
    if task == "stability":
        return write_stability_tables(runs_dir, out_dir)
    if task not in ("cdg", "nvs", "dvc", "dvc_multi", "extract"):
        raise ClodsError(f"no table layout for task '{task}' yet", where="tables --task", hint="one of: cdg, nvs, dvc, dvc_multi, extract, stability")
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for _, rec in iter_records(runs_dir, task):
        groups.setdefault((rec["scene"], rec["preset"]), []).append(rec)
    if not groups:
        raise ClodsError(f"no '{task}' run records found", where=runs_label(runs_dir), hint="run e.g. `clods-bench run cdg --sim constvel` first")
    written = []
    for (scene, preset), recs in sorted(groups.items()):
        recs.sort(key=lambda r: r["label"])
        stem = out_dir / f"{task}_{scene}_{preset}"
        if task == "nvs":
            display, numeric, notes = nvs_frame(recs)
            caption = nvs_caption(scene, preset, recs, notes)
        elif task == "dvc":
            display, numeric, notes = dvc_frame(recs)
            caption = dvc_caption(scene, preset, recs, notes)
        elif task == "dvc_multi":
            display, numeric, notes = dvc_multi_frame(recs)
            caption = dvc_multi_caption(scene, preset, recs, notes)
        elif task == "extract":
            display, numeric, notes = extract_frame(recs)
            seeds = sorted({len(r["seeds"]) for r in recs})
            caption = f"Mesh extraction ({scene}, preset {preset}); mean ± std over {'/'.join(map(str, seeds))} extraction seeds. {notes[0]}."
        else:
            display, numeric = cdg_frame(recs)
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
