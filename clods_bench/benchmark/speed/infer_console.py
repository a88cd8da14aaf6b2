"""`clods-bench bench infer` on the console: the benchmark run under a progress bar, its table, caps and notes, and
the files of `outputs.infer_output`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from clods_bench.benchmark.outputs.infer_output import PIPELINE_NAMES, PIPELINES, ratio, write_infer_outputs
from clods_bench.benchmark.speed.infer_bench import bench_infer


def print_bench_infer(console: Console, cfg: Any, out_dir: Path, progress: bool = True, **kwargs: Any) -> dict[str, Any]:
    """Run `bench_infer` on `cfg` with a progress bar, print its table, caps and notes, write its files; return the result."""
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console, transient=True, disable=not progress) as bar:
        job = bar.add_task(f"bench infer {cfg.preset}: simulating, fitting, warming up", total=None)

        def on_frame(i: int, n: int) -> None:
            bar.update(job, description=f"bench infer {cfg.preset}: frames (first untimed)", completed=i, total=n)

        r = bench_infer(cfg, on_frame=on_frame, **kwargs)
    c, t = r["counts"], r["threads"]
    table = Table(title=(f"clods-bench bench infer: preset {r['preset']} ({r['scene']}), {c['nodes']} nodes, {c['views']} views "
                         f"{c['width']}x{c['height']} ({c['pixels']} pixels), {c['gaussians']} Gaussians ({c['gaussians_per_face']} per face), "
                         f"device {r['device']}, threads: torch {t['torch']}, numba {t['numba']}, {r['sim']} {t['sim'] or 'torch default'}"
                         + (f", cap {t['cap']}" if t["cap"] else "")))  # fmt: skip
    for col in ("pipeline", "simulator step ms", "render ms (all views)", "total ms per frame", "min-max step / render ms"):
        table.add_column(col, justify="left" if col == "pipeline" else "right")
    for p in PIPELINES:
        sim = r["sim"] if p == "clods" else r["reference_sim"]
        ren = r["renderer"] if p == "clods" else f"rasterizer, supersample {c['raster_supersample']}"
        s, q = r[p]["sim_step"], r[p]["render"]
        table.add_row(f"{PIPELINE_NAMES[p]} ({sim} + {ren})", f"{s['median_ms']:.2f}", f"{q['median_ms']:.2f}", f"{r[p]['total_ms']:.2f}",
                      f"{s['min_ms']:.1f}-{s['max_ms']:.1f} / {q['min_ms']:.1f}-{q['max_ms']:.1f}")  # fmt: skip
    console.print(table)
    console.print(f"traditional / CloDS per frame: {ratio(r):.2f}x "
                  f"({'CloDS faster' if ratio(r) > 1 else 'traditional faster'} here); medians of {r['frames']} frames, total = sum of the parts' medians")  # fmt: skip
    for cap in r["caps"]:
        console.print(f"[bold]capped[/bold]: {cap}")
    for note in r["notes"]:
        console.print(f"note: {note}")
    paths = write_infer_outputs(r, out_dir)
    console.print("wrote " + ", ".join(str(p) for p in paths))
    return r
