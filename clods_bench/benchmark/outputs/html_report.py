"""`clods-bench report`: one self-contained HTML page (`index.html`, images and videos embedded as base64).

It holds every table found in the run records (one per task and scene/preset, in the layout each task declares,
`TaskSpec.table`), the error-against-time plots and rollout RMSE curves of `report.py` (whose PNG and
CSV files are kept next to the page), and the media the runs wrote: novel-view image grids
(`nvs_grid.png`), DVC videos and grids (`*.gif`, `*.mp4`, `*.png` in seed directories), and, when a
`bench infer` output folder is given (`--bench`, default `bench/`), the inference-time table and plot. Mesh samples
the CDG and extract tasks saved (`*_meshes.npz`) are drawn as pictures: truth beside the extracted or predicted cloth
with per-node error as colour (PNGs under `meshes/` next to the page). The Watch section (`watch.py`, first after the
contents) animates the runs: rollout videos and 3D views of CDG and stability runs, true and predicted frames of NVS
and DVC runs (files under `watch/` next to the page).
"""

from __future__ import annotations

import base64
import html
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from clods_bench.atomic import write_text
from clods_bench.benchmark.core.registry import Registry, default_registry
from clods_bench.benchmark.outputs.mesh_pictures import MESH_SUFFIX, plot_mesh_sample
from clods_bench.benchmark.outputs.tables import layout_frames, table_layout
from clods_bench.benchmark.outputs.training_curves import write_training_curves
from clods_bench.benchmark.outputs.watch import WATCH_ANCHOR, build_watch, watch_html
from clods_bench.benchmark.running.records import iter_records
from clods_bench.errors import ClodsError

INDEX_FILE = "index.html"
MEDIA_SUFFIXES = {".png": "image/png", ".gif": "image/gif", ".jpg": "image/jpeg", ".webp": "image/webp", ".mp4": "video/mp4", ".webm": "video/webm"}
MAX_EMBED_BYTES = 25 * 2**20  # larger media are linked by path instead of embedded
TASK_ORDER = ("cdg", "nvs", "dvc", "dvc_multi", "stability", "extract")
INFER_ANCHOR = "bench-infer"

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.5em; text-align: right; }
th { background: #f3f3f3; }
img, video { max-width: 100%; border: 1px solid #ddd; }
figure { margin: 1em 0; }
figcaption, .caption { color: #555; font-size: 0.9em; }
"""


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _stderr(line: str) -> None:
    print(f"warning: {line}", file=sys.stderr)


def _data_uri(path: Path) -> str | None:
    mime = MEDIA_SUFFIXES.get(path.suffix.lower())
    if mime is None or path.stat().st_size > MAX_EMBED_BYTES:
        return None
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def media_html(path: Path, caption: str) -> str:
    """A <figure> embedding an image or video file (or linking it when it is too large to embed)."""
    uri = _data_uri(path)
    cap = f"<figcaption>{html.escape(caption)}</figcaption>"
    if uri is None:
        return f'<figure><a href="{html.escape(str(path.resolve()))}">{html.escape(path.name)}</a>{cap}</figure>'
    if path.suffix.lower() in (".mp4", ".webm"):
        return f'<figure><video controls loop muted src="{uri}"></video>{cap}</figure>'
    return f'<figure><img alt="{html.escape(path.name)}" src="{uri}">{cap}</figure>'


def _grouped(runs_dir: Path) -> dict[str, dict[tuple[str, str], list[tuple[Path, dict[str, Any]]]]]:
    """task -> (scene, preset) -> [(record dir, record)] (stability groups every scene of a preset together)."""
    out: dict[str, dict[tuple[str, str], list[tuple[Path, dict[str, Any]]]]] = {}
    for rdir, rec in iter_records(runs_dir):
        scene = "all scenes" if rec["task"] == "stability" else rec["scene"]
        out.setdefault(rec["task"], {}).setdefault((scene, rec["preset"]), []).append((rdir, rec))
    return out


def _seed_media(rdir: Path, seeds: int = 1) -> list[Path]:
    """Images and videos the first `seeds` seeds of a run wrote into their seed directories (checkpoints and the like are skipped)."""
    dirs = sorted((d for d in rdir.glob("seed_*") if d.is_dir() and d.name[5:].isdigit()), key=lambda d: int(d.name[5:]))
    found = []
    for seed_dir in dirs[:seeds]:
        found += sorted(p for p in seed_dir.rglob("*") if p.is_file() and p.suffix.lower() in MEDIA_SUFFIXES and not p.name.startswith("."))
    return found


def _seed_mesh_samples(rdir: Path, seeds: int = 1) -> list[Path]:
    """Mesh samples (`*_meshes.npz`) the first `seeds` seeds of a run saved, drawn as pictures by the report."""
    dirs = sorted((d for d in rdir.glob("seed_*") if d.is_dir() and d.name[5:].isdigit()), key=lambda d: int(d.name[5:]))
    return [p for d in dirs[:seeds] for p in sorted(d.glob(f"*{MESH_SUFFIX}"))]


def infer_section(bench_dir: Path, out_dir: Path) -> tuple[str, list[Path]]:
    """HTML of the `bench infer` results in `bench_dir` (table, stacked-bar plot redrawn into `out_dir`, caps and notes);
    ('', []) when there is none."""
    from clods_bench.benchmark.outputs.infer_output import PLOT_FILE, infer_table, load_infer_results, plot_infer, result_label

    results = load_infer_results(bench_dir) if Path(bench_dir).is_dir() else []
    if not results:
        return "", []
    png = Path(out_dir) / PLOT_FILE
    plot_infer(results, png)
    parts = [f"<h2 id='{INFER_ANCHOR}'>Inference time: CloDS against the traditional pipeline</h2>",
             f"<p class='caption'>From <code>clods-bench bench infer</code> results in <code>{html.escape(str(Path(bench_dir).resolve()))}</code>: "
             "median ms per frame; a pipeline's total is the sum of its parts' medians.</p>",
             infer_table(results).to_html(index=False, border=0, na_rep="n/a", escape=True),
             media_html(png, "ms per frame: simulator step and render of every view, stacked, per pipeline and preset")]  # fmt: skip
    for r in results:
        lines = [*(f"capped: {c}" for c in r.get("caps", [])), *r.get("notes", [])]
        parts.append(f"<p class='caption'>{html.escape(result_label(r))} ({html.escape(str(r.get('created', '')))}): "
                     + "; ".join(html.escape(line) for line in lines) + "</p>")  # fmt: skip
    return "".join(parts), [png]


def build_html_report(
    runs_dir: Path,
    out_dir: Path,
    metric: str | None = None,
    media_seeds: int = 1,
    bench_dir: Path | None = None,
    registry: Registry | None = None,
    watch: Sequence[str] | None = (),
    warn: Callable[[str], None] | None = None,
) -> list[Path]:
    """Write `out_dir/index.html` (plus the PNG/CSV plots of `report.write_report` when CDG records exist); return the paths.

    Each task's records are shown in the table layout the task declares (`registry`: the installed plugins' by
    default). Media (grids, videos) are shown for the first `media_seeds` seeds of every run. With `bench_dir`, the
    `bench infer` results there (`infer_*.json`) get a section of their own. The Watch section (`watch.build_watch`)
    animates the records named in `watch` (labels or record folders; empty: every record; None: no Watch section);
    a record it cannot watch is one line to `warn` (default: stderr).
    """
    from clods_bench.benchmark.outputs.report import HEADLINE, write_report

    registry = registry or default_registry()

    runs_dir, out_dir = Path(runs_dir), Path(out_dir)
    infer_html, infer_files = infer_section(bench_dir, out_dir) if bench_dir is not None else ("", [])
    groups = _grouped(runs_dir) if runs_dir.is_dir() or not infer_html else {}  # bench results alone make a report too
    if not groups and not infer_html:
        raise ClodsError("no run records found", where=str(runs_dir), hint="run e.g. `clods-bench run cdg --sim constvel` first")
    written: list[Path] = [*infer_files]
    if "cdg" in groups:  # error-vs-time plots (cdg), training curves (stability)
        written += write_report(runs_dir, out_dir, metric or HEADLINE)
    elif "stability" in groups:  # stability records alone: their training curves, if any
        written += write_training_curves(runs_dir, out_dir)

    parts = [f"<h1>clods-bench report</h1><p class='caption'>Records under <code>{html.escape(str(runs_dir.resolve()))}</code>, "
             f"built {time.strftime('%Y-%m-%d %H:%M:%S')}.</p>"]  # fmt: skip
    toc = []
    for task in sorted(groups, key=lambda t: (TASK_ORDER.index(t) if t in TASK_ORDER else len(TASK_ORDER), t)):
        for (scene, preset), items in sorted(groups[task].items()):
            items.sort(key=lambda item: (item[1]["label"], item[1]["scene"]))
            anchor = f"{task}-{scene}-{preset}".replace(" ", "_")
            toc.append(f"<li><a href='#{anchor}'>{html.escape(task)}: {html.escape(scene)}, preset {html.escape(preset)} ({len(items)} rows)</a></li>")
            records = [rec for _, rec in items]
            display, _, note = layout_frames(table_layout(task, registry), records)
            parts.append(f"<h2 id='{anchor}'>{html.escape(task)}: {html.escape(scene)}, preset {html.escape(preset)}</h2>")
            parts.append(display.to_html(border=0, na_rep="n/a", escape=True))
            if note:
                parts.append(f"<p class='caption'>{html.escape(note)}</p>")
            if task == "cdg":
                stem = f"{scene}_{preset}"
                for name, caption in ((f"error_vs_time_{stem}.png", "error against inference and training time (Pareto front in red)"),
                                      (f"rollout_rmse_{stem}.png", "rollout RMSE per frame (dashed: end of interpolation)"),
                                      (f"error_accumulation_{stem}.png", "CloDS rows, training videos: extraction vs truth, prediction vs truth, prediction vs extraction")):  # fmt: skip
                    if (out_dir / name).is_file():
                        parts.append(media_html(out_dir / name, caption))
            if task == "stability" and (out_dir / f"training_curves_{scene}_{preset}.png").is_file():
                parts.append(media_html(out_dir / f"training_curves_{scene}_{preset}.png",
                                        "training curves: each weight snapshot's long rollouts scored like the final model (mean over seeds)"))  # fmt: skip
            if task == "extract":  # E-GT per frame, one line per setting
                from clods_bench.benchmark.outputs.report import mean_curves, plot_curves

                png = out_dir / f"extraction_egt_{scene}_{preset}_{len(written)}.png".replace(" ", "_")
                egt = any("egt_avg" in rec["metrics"] for _, rec in items)
                if egt:  # E-GT curves start at the given frame 0
                    plot_curves({rec["label"]: mean_curves(rdir, rec) for rdir, rec in items}, None, f"mesh extraction error per frame ({scene}, preset {preset})", png)
                    what = "E-GT: RMSE of the extracted against the true mesh per frame"
                else:  # a dataset without meshes: PSNR of the re-rendered extraction, from frame 1
                    plot_curves({rec["label"]: mean_curves(rdir, rec) for rdir, rec in items}, None, f"mesh extraction re-rendered ({scene}, preset {preset})",
                                png, ylabel="PSNR (dB), held-out cameras", first_frame=1)  # fmt: skip
                    what = "PSNR of the extracted meshes re-rendered in the held-out cameras per frame (a dataset without meshes)"
                written.append(png)
                parts.append(media_html(png, f"{what}, mean over seeds"))
            for rdir, rec in items:
                for path in _seed_media(rdir, media_seeds):
                    rel = path.relative_to(rdir)
                    parts.append(media_html(path, f"{rec['label']} ({rec['scene']}): {rel}"))
                for sample in _seed_mesh_samples(rdir, media_seeds):
                    png = out_dir / "meshes" / f"{rdir.parent.name}_{rdir.name}_{sample.parent.name}_{sample.stem}.png"
                    written.append(plot_mesh_sample(sample, png))
                    parts.append(media_html(png, f"{rec['label']} ({rec['scene']}): {sample.relative_to(rdir)}, per-node error as colour"))
    if watch is not None:
        items, warnings = build_watch(groups, out_dir, registry, watch, warn or _stderr)
        written += [p for item in items for p in (item.video, item.view3d) if p is not None]
        views = sum(i.view3d is not None for i in items)
        toc.insert(0, f"<li><a href='#{WATCH_ANCHOR}'>Watch: {_count(len(items), 'video')}, {_count(views, '3D view')}"
                      + (f" ({_count(len(warnings), 'run')} not watched)" if warnings else "") + "</a></li>")  # fmt: skip
        parts.insert(1, watch_html(items, warnings, out_dir, media_html))  # first after the contents, as listed there
    if infer_html:
        toc.append(f"<li><a href='#{INFER_ANCHOR}'>inference time: CloDS against the traditional pipeline (bench infer)</a></li>")
        parts.append(infer_html)
    body = parts[0] + "<h2>Contents</h2><ul>" + "".join(toc) + "</ul>" + "".join(parts[1:])
    page = f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>clods-bench report</title><style>{STYLE}</style></head><body>{body}</body></html>\n"
    index = out_dir / INDEX_FILE
    write_text(index, page)
    return [*written, index]
