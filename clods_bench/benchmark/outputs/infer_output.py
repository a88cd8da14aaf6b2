"""Output of `clods-bench bench infer`: JSON and CSV per (preset, device), its table, one stacked-bar PNG.

Layout of the output folder (default `bench/`): `infer_<preset>.json` / `.csv` (`infer_<preset>_<device>` on a GPU),
and `infer_time.png`, redrawn from every `infer_*.json` there after each run, so the presets measured one after
another end up side by side. The HTML report (`clods-bench report --bench DIR`) reads the same JSON files.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from clods_bench.atomic import atomic_path, write_json, write_text
from clods_bench.errors import ClodsError

PIPELINES = ("clods", "traditional")
PARTS = ("sim_step", "render")
PLOT_FILE = "infer_time.png"
PIPELINE_NAMES = {"clods": "CloDS", "traditional": "traditional"}
PART_NAMES = {"sim_step": "simulator step", "render": "render (all views)"}
PRESET_ORDER = ("ci", "small", "paper")


def result_stem(result: dict[str, Any]) -> str:
    """File stem of a result: infer_<preset>, with _<device> when it is not the CPU (cuda:0 -> cuda0)."""
    device = str(result["device"]).replace(":", "")
    return f"infer_{result['preset']}" + ("" if device == "cpu" else f"_{device}")


def result_rows(result: dict[str, Any]) -> list[dict[str, Any]]:
    """One CSV row per (pipeline, part and total) with the counts of the run."""
    c = result["counts"]
    common = {"preset": result["preset"], "scene": result["scene"], "device": result["device"], "frames": result["frames"],
              "nodes": c["nodes"], "views": c["views"], "views_preset": c["views_preset"], "pixels": c["pixels"],
              "gaussians": c["gaussians"]}  # fmt: skip
    rows = []
    for pipeline in PIPELINES:
        sim = result["sim"] if pipeline == "clods" else result["reference_sim"]
        renderer = result["renderer"] if pipeline == "clods" else "rasterizer"
        for part in PARTS:
            p = result[pipeline][part]
            rows.append({**common, "pipeline": pipeline, "part": part, "plugin": sim if part == "sim_step" else renderer,
                         "median_ms": p["median_ms"], "min_ms": p["min_ms"], "max_ms": p["max_ms"]})  # fmt: skip
        rows.append({**common, "pipeline": pipeline, "part": "total", "plugin": f"{sim}+{renderer}", "median_ms": result[pipeline]["total_ms"]})
    return rows


def write_infer_outputs(result: dict[str, Any], out_dir: Path) -> list[Path]:
    """Write the result's JSON and CSV into `out_dir` and redraw its plot of every result there; return the paths."""
    out_dir = Path(out_dir)
    stem = result_stem(result)
    json_path, csv_path = out_dir / f"{stem}.json", out_dir / f"{stem}.csv"
    write_json(json_path, result)
    write_text(csv_path, pd.DataFrame(result_rows(result)).to_csv(index=False))
    png = out_dir / PLOT_FILE
    plot_infer(load_infer_results(out_dir), png)
    return [json_path, csv_path, png]


def load_infer_results(folder: Path) -> list[dict[str, Any]]:
    """Every `infer_*.json` in `folder`, ordered ci, small, paper (others after, by name); [] if there is none."""
    results = []
    for path in sorted(Path(folder).glob("infer_*.json")):
        try:
            result = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ClodsError(f"unreadable bench infer result: {exc}", where=str(path)) from exc
        if not all(k in result for k in ("preset", "counts", *PIPELINES)):
            raise ClodsError("not a bench infer result (needs preset, counts, clods, traditional)", where=str(path))
        results.append(result)
    return sorted(results, key=lambda r: (PRESET_ORDER.index(r["preset"]) if r["preset"] in PRESET_ORDER else len(PRESET_ORDER), r["preset"], r["device"]))


def ratio(result: dict[str, Any]) -> float:
    """traditional / CloDS total of a result (NaN where it was not finite: stored as null)."""
    value = result.get("ratio_traditional_over_clods")
    return float("nan") if value is None else float(value)


def result_label(result: dict[str, Any]) -> str:
    """A result's short label: preset, device when not the CPU, and the view cap if any."""
    c = result["counts"]
    label = result["preset"] + ("" if result["device"] == "cpu" else f" ({result['device']})")
    return label + (f", {c['views']} of {c['views_preset']} views" if c["views"] < c["views_preset"] else "")


def plot_infer(results: list[dict[str, Any]], path: Path) -> None:
    """Stacked bars (simulator step, render) per pipeline, one panel per result, ms per frame, ratio in the title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not results:
        raise ClodsError("no bench infer result to plot", where=str(path.parent), hint="run `clods-bench bench infer` first")
    fig, axes = plt.subplots(1, len(results), figsize=(3.6 * len(results), 4.0), squeeze=False, layout="constrained")
    colors = {"sim_step": "tab:blue", "render": "tab:orange"}
    for ax, r in zip(axes[0], results):
        x = list(range(len(PIPELINES)))
        bottom = [0.0] * len(PIPELINES)
        for part in PARTS:
            heights = [r[p][part]["median_ms"] for p in PIPELINES]
            ax.bar(x, heights, bottom=bottom, color=colors[part], label=PART_NAMES[part], width=0.6)
            bottom = [b + h for b, h in zip(bottom, heights)]
        for xi, p in zip(x, PIPELINES):
            ax.annotate(_ms(r[p]["total_ms"]), (xi, r[p]["total_ms"]), ha="center", va="bottom", fontsize=8,
                        xytext=(0, 2), textcoords="offset points")  # fmt: skip
        ax.set_xticks(x, [f"{PIPELINE_NAMES[p]}\n{r['sim'] if p == 'clods' else r['reference_sim']}+"
                          f"{r['renderer'] if p == 'clods' else 'raster'}" for p in PIPELINES], fontsize=8)  # fmt: skip
        ax.set_ylim(0, max(bottom) * 1.15 if max(bottom) > 0 else 1.0)
        c = r["counts"]
        t = r.get("threads", {})
        ax.set_title(f"{result_label(r)}\n{c['nodes']} nodes, {c['views']} x {c['width']}px, {c['gaussians']} Gaussians\n"
                     f"{r['device']}, threads torch {t.get('torch')} / numba {t.get('numba')}" + (f" (cap {t['cap']})" if t.get("cap") else "") + "\n"
                     f"traditional / CloDS = {ratio(r):.2f}", fontsize=8)  # fmt: skip
        ax.grid(True, axis="y", alpha=0.3)
        if ax is axes[0][0]:
            ax.set_ylabel("ms per frame (median)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=len(PARTS), fontsize=8)
    fig.suptitle("Inference time per frame: CloDS (learned step + Gaussian splatting) vs traditional (solver step + rasterizer)", fontsize=9)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
    plt.close(fig)


def _ms(value: float) -> str:
    """A bar's total: whole ms from 100 ms up, else one decimal."""
    return f"{value:,.0f} ms" if value >= 100 else f"{value:.1f} ms"


def infer_table(results: list[dict[str, Any]]) -> pd.DataFrame:
    """One row per result: counts, the parts' medians (ms), totals and the ratio, the caps."""
    rows = []
    for r in results:
        c = r["counts"]
        row = {"preset": result_label(r), "nodes": c["nodes"], "views": c["views"], "image": f"{c['width']}x{c['height']}",
               "gaussians": c["gaussians"], "frames": r["frames"]}  # fmt: skip
        for p in PIPELINES:
            for part in PARTS:
                row[f"{PIPELINE_NAMES[p]} {PART_NAMES[part]} (ms)"] = round(r[p][part]["median_ms"], 2)
            row[f"{PIPELINE_NAMES[p]} total (ms)"] = round(r[p]["total_ms"], 2)
        row["traditional / CloDS"] = round(ratio(r), 2)
        rows.append(row)
    return pd.DataFrame(rows)
