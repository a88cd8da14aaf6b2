"""`clods-bench bench determinism`: what deterministic mode costs, as ratios against the host's own paths.

Deterministic mode can only be switched before numpy, torch and numba load, so each mode runs in its own child
process, at the same thread count (deterministic mode's), alternating (deterministic, host, deterministic, host) so
that a drift of the machine's load hits both; the faster of each mode's runs counts. Measured: `bench sim`'s MGN
(training step and inference step on the 1579-node FLAGSIMPLE-size flag) and `bench render`'s CPU splatting
backend (forward and forward + backward, 8 views of 128 px).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import Any

from rich.console import Console
from rich.table import Table

from clods_bench import numerics as dm
from clods_bench.errors import ClodsError

_CHILD = """
import json, sys
from clods_bench import numerics
if numerics.requested():
    numerics.pin_environment()
from rich.console import Console
from clods_bench.benchmark.speed.sim_bench import bench_sim
from clods_bench.splatting.bench import bench_render
with numerics.maybe_exact():
    sim = bench_sim(Console(quiet=True), sims=["mgn", "physics"], frames=int(sys.argv[1]))["mgn"]
    render = bench_render(repeats=int(sys.argv[2]), memory=False, reference=False)["cpu"]
print("RESULT " + json.dumps({"sim train s/step": sim.train_s_per_step, "sim infer ms/step": sim.infer_ms_per_step,
                              "render forward ms": render["forward_ms"], "render forward+backward ms": render["forward_backward_ms"]}))
"""


def _child_env(deterministic: bool) -> dict[str, str]:
    """The environment of one mode's child, both at deterministic mode's thread count."""
    env = dict(os.environ) if deterministic else dm.host_environ()
    env[dm.SWITCH_ENV] = "1" if deterministic else "0"
    n = str(dm.threads())
    for key in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS", "CLODS_BENCH_MAX_THREADS"):
        env[key] = n
    return env


def _measure(deterministic: bool, frames: int, repeats: int) -> dict[str, float]:
    out = subprocess.run([sys.executable, "-c", _CHILD, str(frames), str(repeats)], env=_child_env(deterministic), capture_output=True, text=True)
    lines = [line for line in out.stdout.splitlines() if line.startswith("RESULT ")]
    if out.returncode != 0 or not lines:
        raise ClodsError(f"the {'deterministic' if deterministic else 'host-path'} child failed: {out.stderr.strip().splitlines()[-1:]}",
                         where="bench determinism")  # fmt: skip
    return json.loads(lines[-1][len("RESULT "):])


def bench_determinism(console: Console, rounds: int = 2, frames: int = 8, repeats: int = 3) -> dict[str, Any]:
    """Time both modes `rounds` times each, alternating; print and return {metric: {host, deterministic, ratio}}."""
    best: dict[bool, dict[str, float]] = {True: {}, False: {}}
    for r in range(rounds):
        for deterministic in (True, False):
            with console.status(f"round {r + 1} of {rounds}: {'deterministic mode' if deterministic else 'host paths'} ..."):
                got = _measure(deterministic, frames, repeats)
            for key, value in got.items():
                best[deterministic][key] = min(value, best[deterministic].get(key, float("inf")))
    result = {k: {"host": best[False][k], "deterministic": best[True][k], "ratio": best[True][k] / best[False][k]} for k in best[True]}
    table = Table(title=f"deterministic mode against the host's own paths ({dm.cpu_model()}, {dm.threads()} thread(s), best of {rounds})")
    for col in ("measure", "host paths", "deterministic", "deterministic / host"):
        table.add_column(col, justify="left" if col == "measure" else "right")
    for key, v in result.items():
        table.add_row(key, f"{v['host']:.3g}", f"{v['deterministic']:.3g}", f"{v['ratio']:.2f}x")
    console.print(table)
    return result
