"""Speed benchmarks printed as numbers and ratios against targets measured in the same run."""

from __future__ import annotations

from rich.console import Console
from rich.table import Table

from clods_bench.numerics import cpu_model

SOLVER_TARGET_S = 60.0  # 400 steps of the 1579-node flag on 2 cores
CONTACT_TARGET_RATIO = 2.0  # contact with an obstacle may at most double the solver's time per step
RASTER_TARGET_MS = 20.0  # one 128x128 view of that mesh


def bench_data(console: Console, steps: int = 400, views: int = 8) -> dict[str, float]:
    """Time the ground-truth cloth solver (without and with an obstacle to collide with) and rasterizer on the FLAGSIMPLE-size flag."""
    from clods_bench.datasets.raster_bench import bench_rasterizer
    from clods_bench.datasets.solver_bench import bench_solver

    with console.status(f"cloth solver: {steps} steps of the 1579-node flag ..."):
        solver = bench_solver(num_steps=steps, resolution="flagsimple")
    with console.status(f"cloth solver with contact: {steps} steps of the flag hitting a sphere ..."):
        contact = bench_solver(num_steps=steps, resolution="flagsimple", obstacles=True)
    with console.status(f"rasterizer: {views} views at 128x128 ..."):
        raster = bench_rasterizer(num_views=views, size=128)
    per400 = solver["seconds_per_step"] * 400
    table = Table(title=f"clods-bench bench data (1579-node flag, {cpu_model()})")
    for col in ("what", "measured", "target", "measured / target"):
        table.add_column(col, justify="right")
    table.add_row("solver steps / s", f"{solver['steps_per_second']:.2f}", f"{400 / SOLVER_TARGET_S:.2f}", "")
    table.add_row("solver: 400 steps (s)", f"{per400:.1f}", f"{SOLVER_TARGET_S:.0f}", f"{per400 / SOLVER_TARGET_S:.2f}")
    table.add_row("solver: simulated / wall time", f"{solver.get('realtime_factor', float('nan')):.2f}", "", "")
    slowdown = solver["steps_per_second"] / contact["steps_per_second"]
    table.add_row("solver steps / s with contact", f"{contact['steps_per_second']:.2f}", "", "")
    table.add_row("solver: nodes in contact / step", f"{contact['contacts_per_step']:.1f}", "", "")
    table.add_row("solver: time with / without contact", f"{slowdown:.2f}", f"{CONTACT_TARGET_RATIO:.1f}", f"{slowdown / CONTACT_TARGET_RATIO:.2f}")
    table.add_row("rasterizer ms / 128x128 view", f"{raster['ms_per_view']:.2f}", f"{RASTER_TARGET_MS:.0f}", f"{raster['ms_per_view'] / RASTER_TARGET_MS:.2f}")
    table.add_row(f"rasterizer: {views} views in 1 / {raster['threads']} threads (speed-up)", f"{raster['thread_speedup']:.2f}x",
                  "", f"{raster['ms_per_view_one_thread']:.2f} / {raster['ms_per_view']:.2f} ms a view")  # fmt: skip
    console.print(table)
    return {
        "solver_seconds_per_400": per400,
        "solver_steps_per_second": solver["steps_per_second"],
        "solver_contact_steps_per_second": contact["steps_per_second"],
        "solver_contact_slowdown": slowdown,
        "solver_contacts_per_step": contact["contacts_per_step"],
        "raster_ms_per_view": raster["ms_per_view"],
        "raster_threads": raster["threads"],
        "raster_thread_speedup": raster["thread_speedup"],
    }
