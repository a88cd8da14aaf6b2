"""Tables from run records in the layout each task declares (`TaskSpec.table`): markdown, LaTeX and CSV (pandas).

The paper's layouts are in `rollout_tables`, `image_tables` and `extraction_tables`; `metric_frame` gives any task
one column per metric. A task that declares no layout has no table: asking for one is one error naming the field.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import pandas as pd

from clods_bench.atomic import write_text
from clods_bench.benchmark.core.descriptors import TableLayout
from clods_bench.benchmark.core.registry import Registry, default_registry
from clods_bench.benchmark.running.records import RECORD_FILE, check_consistent, iter_records, runs_label
from clods_bench.errors import ClodsError


def fmt_cell(mean: float, std: float, digits: int = 4, diverged: int | None = None) -> str:
    """'0.1293 ± 0.0240', or 'diverged@k' when the value is not finite."""
    if mean is None or not math.isfinite(mean):
        return f"diverged@{diverged}" if diverged is not None else "n/a"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def scored_scenes(rec: dict[str, Any]) -> set[str]:
    """Scenes a record was trained on and scored on (a CDG run with `eval_data` scores another scene)."""
    return {rec["scene"], *(s["extra"]["scored_data"]["scene"] for s in rec.get("per_seed", {}).values() if "scored_data" in s.get("extra", {}))}


def to_markdown(display: pd.DataFrame) -> str:
    """Markdown with flattened 'Viewed / Interpolation / d(t=30)' headers."""
    flat = display.copy()
    flat.columns = [" / ".join(p for p in col if p) for col in flat.columns]
    return flat.to_markdown()


def metric_frame(records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """Any task's records as a table (`TableLayout(frame=metric_frame)`): one 'mean ± std' column per metric, the
    timing means as 'time: <key>' columns (CSV: '<metric>/mean', '<metric>/std', 'time/<key>'); no notes."""
    metric_keys = sorted({k for r in records for k in r["metrics"]})
    timing_keys = sorted({k for r in records for k in r["timings"] if not k.startswith("fit/")})
    display_rows, numeric_rows, index = [], [], []
    for rec in records:
        row, num = {}, {"method": rec["label"], "seeds": len(rec["seeds"])}
        for key in metric_keys:
            v = rec["metrics"].get(key) or {}
            mean = float("nan") if v.get("mean") is None else float(v["mean"])
            std = float("nan") if v.get("std") is None else float(v["std"])
            row[key] = fmt_cell(mean, std)
            num[f"{key}/mean"], num[f"{key}/std"] = mean, std
        for key in timing_keys:
            v = (rec["timings"].get(key) or {}).get("mean")
            value = float("nan") if v is None else float(v)
            row[f"time: {key}"] = f"{value:.3g}"
            num[f"time/{key}"] = value
        display_rows.append(row)
        numeric_rows.append(num)
        index.append(rec["label"])
    return pd.DataFrame(display_rows, index=pd.Index(index, name="Method")), pd.DataFrame(numeric_rows), []


def table_layout(task: str, registry: Registry) -> TableLayout:
    """The layout `task` declares; a ClodsError naming the task and the field when it declares none."""
    layout = getattr(registry.get("task", task), "table", None)
    if layout is None:
        raise ClodsError(f"task '{task}' declares no table layout, so it has no table", where=f"TaskSpec(name='{task}').table",
                         hint="give its TaskSpec table=TableLayout(frame=...), e.g. TableLayout(frame=metric_frame) from "
                              "clods_bench.api for one column per metric")  # fmt: skip
    return layout


def layout_frames(layout: TableLayout, records: list[dict[str, Any]]) -> tuple[pd.DataFrame, pd.DataFrame, str]:
    """(display, numeric, footnotes joined by '; ') of `records` in `layout`."""
    display, numeric, notes = layout.frame(records)
    return display, numeric, "; ".join(notes)


def write_table(stem: Path, caption: str, display: pd.DataFrame, numeric: pd.DataFrame) -> list[Path]:
    """`<stem>.md` (the caption above the table), `<stem>.tex` and `<stem>.csv`; return the three paths."""
    markdown = to_markdown(display) if isinstance(display.columns, pd.MultiIndex) else display.to_markdown()
    write_text(stem.with_suffix(".md"), f"{caption}\n\n{markdown}\n")
    write_text(stem.with_suffix(".tex"), display.to_latex(caption=caption, multicolumn_format="c"))
    write_text(stem.with_suffix(".csv"), numeric.to_csv(index=False))
    return [stem.with_suffix(s) for s in (".md", ".tex", ".csv")]


def seeds_phrase(records: list[dict[str, Any]], unit: str = "seeds") -> str:
    """'2 seeds' when every row has as many; else the most rows' count and the rows with another one named, so that
    a row standing on fewer seeds than its neighbours shows in the caption ('2 seeds (1: MGN*, HCMT)')."""
    counts = [len(r["seeds"]) for r in records]
    if len(set(counts)) <= 1:
        return f"{counts[0] if counts else 0} {unit}"
    usual = max(sorted(set(counts), reverse=True), key=counts.count)
    others: dict[int, list[str]] = {}
    for rec, n in zip(records, counts):
        if n != usual:
            others.setdefault(n, []).append(str(rec["label"]))
    return f"{usual} {unit} (" + "; ".join(f"{n}: {', '.join(sorted(labels))}" for n, labels in sorted(others.items())) + ")"


def default_caption(task: str, scene: str, preset: str, records: list[dict[str, Any]], notes: list[str]) -> str:
    """The caption of a table whose layout gives none: task, scene, preset, seeds, then the notes."""
    where = f"{scene}, preset {preset}" if scene else f"preset {preset}"
    return f"{task} ({where}); mean ± std over {seeds_phrase(records)}." + "".join(f" {n}." for n in notes)


def write_tables(runs_dir: Path | Sequence[Path], out_dir: Path, task: str = "cdg", registry: Registry | None = None) -> list[Path]:
    """Write the tables of `task` from its records (under one runs folder or several) in the layout the task declares:
    one markdown/LaTeX/CSV set per (scene, preset), or per preset; return the paths. Every seed of a record counts;
    a record whose means or stds differ from its per-seed values is refused (`check_consistent`)."""
    layout = table_layout(task, registry or default_registry())
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for rdir, rec in iter_records(runs_dir, task):
        check_consistent(rec, str(rdir / RECORD_FILE))
        groups.setdefault((rec["scene"] if layout.per == "scene" else "", rec["preset"]), []).append(rec)
    if not groups:
        raise ClodsError(f"no '{task}' run records found", where=runs_label(runs_dir), hint=f"run e.g. `clods-bench run {task} ...` first")
    written = []
    for (scene, preset), recs in sorted(groups.items()):
        recs.sort(key=lambda r: (r["label"], r["scene"]))
        display, numeric, notes = layout.frame(recs)
        caption = (layout.caption or (lambda *a: default_caption(task, *a)))(scene, preset, recs, notes)
        written += write_table(Path(out_dir) / "_".join(p for p in (task, scene, preset) if p), caption, display, numeric)
    return written
