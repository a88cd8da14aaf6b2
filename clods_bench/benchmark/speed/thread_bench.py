"""`clods-bench bench threads`: what more threads per job buy, and whether each model family keeps its bits.

Each thread count runs in its own child process (the pins fix the thread count when the libraries load), inside the
exact scope, alternating between the counts so that a drift of the machine's load hits all of them; the fastest of
each count's rounds counts. Measured: one MGN training step (20 steps timed, the difference of a 25- and a 5-step fit) at the `small` preset's size and settings (the 288-node
flag, 10 message-passing steps, batch 2), as `bench sim` times it, and the four probe fits' digests (graph net,
video predictor, renderer fit, extraction), compared with the first count's: a family whose digest moves with the
thread count must run at one thread per job, and the machine's cores then go to parallel jobs instead.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from typing import Any, Sequence

from rich.console import Console
from rich.table import Table

from clods_bench import numerics
from clods_bench.errors import ClodsError

SMALL_MGN = {"message_passing_steps": 10, "batch_size": 2}
"""The `small` preset's MGN settings that decide a training step's cost (presets/small.yaml)."""

_CHILD = """
import json, sys
from clods_bench import numerics
numerics.pin_environment()
from rich.console import Console
from clods_bench.benchmark.speed.determinism_probe import probe
from clods_bench.benchmark.speed.sim_bench import bench_sim
with numerics.exact():
    sim = bench_sim(Console(quiet=True), sims=["mgn"], frames=int(sys.argv[1]), resolution=(24, 12), train_steps=(5, 25),
                    sim_config={"mgn": json.loads(sys.argv[2])})["mgn"]
    digests = {k: v["digest"] for k, v in probe().items()}
print("RESULT " + json.dumps({"train_s_per_step": sim.train_s_per_step, "digests": digests}))
"""


def _child_env(threads: int) -> dict[str, str]:
    """This process's environment with the thread pins at `threads`."""
    env = dict(os.environ)
    env[numerics.THREADS_ENV] = str(threads)
    env.update(numerics.pins(threads))
    return env


def _measure(threads: int, frames: int) -> dict[str, Any]:
    out = subprocess.run([sys.executable, "-c", _CHILD, str(frames), json.dumps(SMALL_MGN)], env=_child_env(threads),
                         capture_output=True, text=True)  # fmt: skip
    lines = [line for line in out.stdout.splitlines() if line.startswith("RESULT ")]
    if out.returncode != 0 or not lines:
        raise ClodsError(f"the {threads}-thread child failed: {out.stderr.strip().splitlines()[-1:]}", where="bench threads")
    return json.loads(lines[-1][len("RESULT "):])


def bench_threads(console: Console, counts: Sequence[int] = (1, 2), rounds: int = 3, frames: int = 8) -> dict[int, dict[str, Any]]:
    """Time MGN's `small` training step and take the probe digests at each thread count; print and return
    {count: {'train_s_per_step', 'speedup', 'digests', 'same_bits': {family: bool}}}."""
    if not counts or min(counts) < 1:
        raise ClodsError(f"thread counts must be >= 1, got {list(counts)}", where="bench threads --threads")
    best: dict[int, dict[str, Any]] = {}
    for r in range(rounds):
        for n in counts:
            with console.status(f"round {r + 1} of {rounds}: {n} thread(s) ..."):
                got = _measure(n, frames)
            step = got["train_s_per_step"]
            usable = math.isfinite(step) and step > 0  # a difference of two fits: a load burst can make it <= 0
            if n not in best:
                best[n] = {**got, "train_s_per_step": step if usable else math.inf}
            elif usable and step < best[n]["train_s_per_step"]:
                best[n]["train_s_per_step"] = step
    ref = best[counts[0]]
    for n in counts:
        both = math.isfinite(ref["train_s_per_step"]) and math.isfinite(best[n]["train_s_per_step"])
        best[n]["speedup"] = ref["train_s_per_step"] / best[n]["train_s_per_step"] if both else math.nan
        best[n]["same_bits"] = {k: v == ref["digests"][k] for k, v in best[n]["digests"].items()}
    table = Table(title=f"threads per job: MGN's small training step, and whether each family's probe fit keeps the bits of "
                        f"{counts[0]} thread(s) ({numerics.cpu_model()}, best of {rounds})")  # fmt: skip
    table.add_column("threads", justify="right")
    table.add_column("MGN train s/step", justify="right")
    table.add_column(f"speed-up vs {counts[0]}", justify="right")
    for family in ref["digests"]:
        table.add_column(family, justify="center")
    for n in counts:
        timed, ratio = math.isfinite(best[n]["train_s_per_step"]), best[n]["speedup"]
        table.add_row(str(n), f"{best[n]['train_s_per_step']:.3f}" if timed else "noisy", f"{ratio:.2f}x" if math.isfinite(ratio) else "-",
                      *["yes" if best[n]["same_bits"][f] else "no" for f in ref["digests"]])  # fmt: skip
    console.print(table)
    return best
