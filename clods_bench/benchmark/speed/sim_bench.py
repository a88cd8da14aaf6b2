"""`clods-bench bench sim`: train-step and inference-step time of each simulator on the FLAGSIMPLE-size flag.

Simulators are built through the plugin registry, so whatever is installed is timed and a
name that is not registered is skipped with a note. A learned simulator's training step is
timed through its public `fit`: two fits of n1 < n2 steps (its config's step-count option),
time per step = (t(n2) - t(n1)) / (n2 - n1), which cancels set-up costs (graph building,
first-call allocation; an untimed fit of n1 steps runs first so one-time imports are not
charged to the n1 fit); a warm-up option (`warmup_steps`: steps that only feed normaliser
statistics) is set to 0 so the timed steps are optimiser steps. Inference is timed on a
rollout after one warm-up rollout, per rollout step. The physics solver is the reference
for the inference-time ratio. With more than one device (`--device cuda`), each learned simulator
that has a `device` option is timed on the CPU and on each other device in the same run, and the
table gives the speed-up of each device over the CPU.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from rich.console import Console
from rich.table import Table

from clods_bench.benchmark.core.descriptors import BuildContext, PluginSpec
from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.datasets.scenes import Resolution, get_scene, simulate_scene
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError
from clods_bench.numerics import cpu_model

STEP_OPTIONS = ("train_steps", "steps", "num_steps", "max_steps", "iterations", "num_iterations")
"""Config fields, in order of preference, taken to be a learned simulator's number of training steps."""
WARMUP_OPTIONS = ("warmup_steps", "warmup_iterations")
"""Config fields counting leading steps without a parameter update; set to 0 so every timed step is an optimiser step."""


@dataclass(frozen=True)
class SimTiming:
    """One simulator's timings (NaN where not measured) and how they were obtained."""

    name: str
    train_s_per_step: float
    infer_ms_per_step: float
    note: str


def step_option(spec: PluginSpec) -> str | None:
    """The config field that sets a learned simulator's training steps, or None."""
    names = [f.name for f in dataclasses.fields(spec.config_cls)] if dataclasses.is_dataclass(spec.config_cls) else []
    return next((n for n in STEP_OPTIONS if n in names), None)


def _build(spec: PluginSpec, values: Mapping[str, Any], scene: Any, work: Path) -> Any:
    cfg = spec.make_config(dict(values), where=f"sim_config.{spec.name}")
    return spec.build(cfg, BuildContext(scene=scene, seed=0, work_dir=work, progress=False))


def time_simulator(
    spec: PluginSpec,
    scene: Any,
    train: Sequence[Trajectory],
    inp: RolloutInput,
    work: Path,
    base_config: Mapping[str, Any] | None = None,
    train_steps: tuple[int, int] = (2, 6),
    clock: Callable[[], float] = time.perf_counter,
) -> SimTiming:
    """Time one simulator: training step by differencing two short fits (learned ones), inference per rollout step."""
    base = dict(base_config or {})
    notes = []
    train_s = float("nan")
    option = step_option(spec) if spec.learned else None
    if spec.learned and option is None:
        sim = _build(spec, base, scene, work)
        notes.append(f"no step-count option ({'/'.join(STEP_OPTIONS)}): training step not timed")
    elif spec.learned:
        n1, n2 = train_steps
        names = [f.name for f in dataclasses.fields(spec.config_cls)]
        no_warmup = {w: 0 for w in WARMUP_OPTIONS if w in names}  # MGN's 1000 statistics-only steps would be timed instead
        times = []
        for i, n in enumerate((n1, n1, n2)):  # the first, untimed fit pays the process-wide first-call costs (imports)
            sim = _build(spec, {**base, **no_warmup, option: n}, scene, work / f"fit{i}")
            t0 = clock()
            sim.fit(train, FitContext(work_dir=work / f"fit{i}", seed=0, progress=False))
            times.append(clock() - t0)
        train_s = (times[2] - times[1]) / (n2 - n1)
        notes.append(f"fit with {option}={n2} minus {option}={n1}, / {n2 - n1}" + "".join(f", {w}=0" for w in no_warmup))
    else:
        sim = _build(spec, base, scene, work)
        sim.fit(train, FitContext(work_dir=work, seed=0, progress=False))
        notes.append("not trained")
    warm = RolloutInput(inp.cells, inp.mesh_pos, inp.node_type, inp.init_pos, inp.kinematic_pos[:3], inp.dt)
    sim.rollout(warm)  # JIT / first-call allocation outside the timing
    t0 = clock()
    sim.rollout(inp)
    infer_ms = 1000.0 * (clock() - t0) / max(inp.num_frames - 2, 1)
    return SimTiming(spec.name, train_s, infer_ms, "; ".join(notes))


def _fmt(value: float) -> str:
    return f"{value:.3g}" if value == value else "n/a"


def has_option(spec: PluginSpec, option: str) -> bool:
    """Whether the plugin's config dataclass has the field `option`."""
    return dataclasses.is_dataclass(spec.config_cls) and option in {f.name for f in dataclasses.fields(spec.config_cls)}


def sim_overrides(items: Sequence[tuple[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per-simulator options from `--set sim_config.<name>.<field>=value` pairs; any other key is refused."""
    out: dict[str, dict[str, Any]] = {}
    for key, value in items:
        parts = key.split(".")
        if len(parts) != 3 or parts[0] != "sim_config":
            raise ClodsError(f"'{key}' is not of the form sim_config.<simulator>.<field>", where="bench sim --set")
        out.setdefault(parts[1], {})[parts[2]] = value
    return out


def row_name(name: str, device: str) -> str:
    """Result key of a simulator timed on `device`: the name on the CPU, 'name@device' elsewhere."""
    return name if device == "cpu" else f"{name}@{device}"


def bench_sim(
    console: Console,
    sims: Sequence[str] = ("mgn", "bsms", "hcmt", "physics"),
    frames: int = 12,
    resolution: Resolution = "flagsimple",
    train_steps: tuple[int, int] = (2, 6),
    sim_config: Mapping[str, Mapping[str, Any]] | None = None,
    registry: Any = None,
    reference: str = "physics",
    clock: Callable[[], float] = time.perf_counter,
    devices: Sequence[str] = ("cpu",),
) -> dict[str, SimTiming]:
    """Time each registered simulator in `sims` on the flag scene (default the 1579-node FLAGSIMPLE size); print a table.

    `frames` frames are rolled out (frames - 2 timed steps); learned simulators train on one
    trajectory of that length. `sim_config` holds options per simulator (e.g. {'mgn': {'loss': 'rollout'}}).
    Each learned simulator with a `device` option is also timed on every device of `devices` other than
    'cpu' (keys 'name@device'). Returns the timings by key; names not registered are skipped.
    """
    from clods_bench.benchmark.core.registry import default_registry

    reg = registry if registry is not None else default_registry()
    scene = get_scene("flag")
    mesh = scene.build_mesh(resolution)
    with console.status(f"ground truth: {frames} frames of the {mesh.num_nodes}-node flag ..."):
        traj = simulate_scene(scene, mesh, frames, seed=0)
    inp = RolloutInput.from_trajectory(traj)
    known = set(reg.names("simulator"))
    results: dict[str, SimTiming] = {}
    skipped = [n for n in sims if n not in known]
    with tempfile.TemporaryDirectory(prefix="clods-bench-sim-") as tmp:
        for name in sims:
            if name in skipped:
                continue
            spec = reg.get("simulator", name)
            for device in ["cpu", *[d for d in devices if d != "cpu"]]:
                if device != "cpu" and not (spec.learned and has_option(spec, "device")):
                    continue  # solvers and simulators without a device option run on the CPU only
                key = row_name(name, device)
                base = {**dict((sim_config or {}).get(name, {})), **({"device": device} if device != "cpu" else {})}
                with console.status(f"timing {key} ..."):
                    results[key] = time_simulator(spec, scene, [traj], inp, Path(tmp) / key.replace(":", "_"), base,
                                                  train_steps, clock)  # fmt: skip
    ref = results.get(reference)
    table = Table(title=f"clods-bench bench sim ({mesh.num_nodes}-node flag, {frames - 2} rollout steps, {cpu_model()})")
    many = len(set(devices) | {"cpu"}) > 1
    cols = ["simulator", "train s/step", "infer ms/step", f"infer / {reference}"] + (["train cpu / this", "infer cpu / this"] if many else [])
    for col in cols + ["how"]:
        table.add_column(col, justify="left" if col in ("simulator", "how") else "right")
    for key, r in results.items():
        ratio = r.infer_ms_per_step / ref.infer_ms_per_step if ref is not None and ref.infer_ms_per_step > 0 else float("nan")
        speed = []
        if many:
            cpu = results.get(key.split("@")[0])
            speed = [_fmt(cpu.train_s_per_step / r.train_s_per_step) if cpu and r.train_s_per_step > 0 else "n/a",
                     _fmt(cpu.infer_ms_per_step / r.infer_ms_per_step) if cpu and r.infer_ms_per_step > 0 else "n/a"]  # fmt: skip
        table.add_row(key, _fmt(r.train_s_per_step), _fmt(r.infer_ms_per_step), _fmt(ratio), *speed, r.note)
    for name in skipped:
        table.add_row(name, "-", "-", "-", "not registered: skipped")
    console.print(table)
    return results
