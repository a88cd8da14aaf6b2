"""The layout of the mesh-extraction table (CloDS stages 1-2, the ablations): E-GT per part of the video, or the
extraction re-rendered when the dataset has no meshes, and the stage-2 cost."""

from __future__ import annotations

from typing import Any

import pandas as pd

from clods_bench.benchmark.outputs.tables import fmt_cell, seeds_phrase

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




def extract_caption(scene: str, preset: str, records: list[dict[str, Any]], notes: list[str]) -> str:
    """Caption of a mesh-extraction table: seeds and what E-GT (or the re-rendered PSNR) is."""
    return f"Mesh extraction ({scene}, preset {preset}); mean ± std over {seeds_phrase(records, 'extraction seeds')}. {notes[0]}."
