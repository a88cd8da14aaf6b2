"""The layouts of the image tables: NVS (the paper's Table 3), DVC (Table 4) and DVC on several trajectories
(appendix): PSNR, SSIM, LPIPS (and RMSE) per row, scaled as the paper prints them, LPIPS footnotes."""

from __future__ import annotations

from typing import Any

import pandas as pd

from clods_bench.benchmark.outputs.tables import fmt_cell, seeds_phrase

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
    text = f"{what} ({scene}, preset {preset}); {scored}; mean ± std over {seeds_phrase(records)}; {per_image} ms per image (one view, one frame)."
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
