"""`clods-bench bench video`: training-step time of each video predictor at a preset's sizes, and what its training costs.

A predictor is built through the plugin registry with the preset's `video_config.<name>` (so `--set` changes its
size) and trained through its public `fit` on synthetic videos of the preset's shape (the interpolation phase of a
training view: `data.interp_steps + 1` frames of `data.image_size` px; a step's cost does not depend on the pixels).
Time per step = (t(n2) - t(n1)) / (n2 - n1) of two fits, after an untimed fit of n1 steps, as `bench sim` does; the
preset's step count times that gives the training time of one Table 4 row. With `--device cuda` each predictor with a
`device` option is also timed there, with its speed-up over the CPU.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.descriptors import BuildContext, PluginSpec
from clods_bench.benchmark.core.interfaces import FitContext
from clods_bench.benchmark.speed.sim_bench import has_option, row_name, step_option
from clods_bench.datasets.scenes import get_scene
from clods_bench.numerics import cpu_model

NUM_VIDEOS = 2
"""Synthetic training videos per fit (windows are drawn from all of them; the count does not change a step's cost)."""


@dataclass(frozen=True)
class VideoTiming:
    """One predictor's training-step time on one device and the preset's training length."""

    name: str
    device: str
    train_s_per_step: float
    preset_steps: int
    note: str

    @property
    def training_hours(self) -> float:
        """The preset's training length at this step time (one fit, one seed)."""
        return self.train_s_per_step * self.preset_steps / 3600.0


def synthetic_videos(frames: int, size: int, count: int = NUM_VIDEOS, seed: int = 0) -> list[np.ndarray]:
    """`count` float32 videos (frames, size, size, 3) in [0, 1]."""
    rng = np.random.default_rng(seed)
    return [rng.random((frames, size, size, 3), dtype=np.float32) for _ in range(count)]


def time_predictor(
    spec: PluginSpec,
    scene: Any,
    values: Mapping[str, Any],
    videos: Sequence[np.ndarray],
    work: Path,
    train_steps: tuple[int, int] = (2, 6),
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[float, str]:
    """(seconds per training step, how) of one predictor configured with `values`; NaN for an untrained one."""
    option = step_option(spec) if spec.learned else None
    if option is None:
        return float("nan"), "not trained" if not spec.learned else "no step-count option: not timed"
    n1, n2 = train_steps
    times = []
    for i, n in enumerate((n1, n1, n2)):  # the first, untimed fit pays the process-wide first-call costs
        cfg = spec.make_config({**dict(values), option: n, **({"checkpoint_every": 0} if has_option(spec, "checkpoint_every") else {})},
                               where=f"video_config.{spec.name}")  # fmt: skip
        pred = spec.build(cfg, BuildContext(scene=scene, seed=0, work_dir=work / f"fit{i}", progress=False))
        t0 = clock()
        pred.fit(videos, FitContext(work_dir=work / f"fit{i}", seed=0, progress=False))
        times.append(clock() - t0)
    return (times[2] - times[1]) / (n2 - n1), f"({option} {n2} - {n1}) / {n2 - n1}"


def bench_video(
    console: Console,
    config: RunConfig,
    predictors: Sequence[str] = ("simvp", "tau", "mau", "mmvp"),
    devices: Sequence[str] = ("cpu",),
    train_steps: tuple[int, int] = (2, 6),
    registry: Any = None,
    clock: Callable[[], float] = time.perf_counter,
    reference: str = "simvp",
    cpu: bool = True,
) -> dict[str, VideoTiming]:
    """Time each registered predictor in `predictors` at `config`'s sizes (its video_config, frames and image size) on
    the CPU (unless `cpu` is off: on a GPU machine those rows can take minutes) and each other device of `devices` it
    supports; print a table with each one's step time over `reference`'s on the same device and the preset's training
    time per row."""
    from clods_bench.benchmark.core.registry import default_registry

    reg = registry if registry is not None else default_registry()
    scene_name = config.data.scene  # a registry without scene plugins (tests) still knows the built-in ones
    scene = reg.get("scene", scene_name) if scene_name in reg.names("scene") else get_scene(scene_name)
    frames, size = config.data.interp_steps + 1, config.data.image_size
    videos = synthetic_videos(frames, size)
    known = set(reg.names("video_predictor"))
    results: dict[str, VideoTiming] = {}
    with tempfile.TemporaryDirectory(prefix="clods-bench-video-") as tmp:
        for name in (n for n in predictors if n in known):
            spec = reg.get("video_predictor", name)
            base = dict(config.video_config.get(name, {}))
            option = step_option(spec)
            steps = int(getattr(spec.make_config(base, where=f"video_config.{name}"), option)) if option else 0
            for device in [*(["cpu"] if cpu else []), *[d for d in devices if d != "cpu"]]:
                if device != "cpu" and not (spec.learned and has_option(spec, "device")):
                    continue
                key = row_name(name, device)
                values = {**base, **({"device": device} if device != "cpu" else {})}
                with console.status(f"timing {key} ..."):
                    s, how = time_predictor(spec, scene, values, videos, Path(tmp) / key.replace(":", "_"), train_steps, clock)
                results[key] = VideoTiming(name, device, s, steps, how)
    title = f"clods-bench bench video (preset {config.preset}: {NUM_VIDEOS} videos of {frames} frames, {size}x{size} px, {cpu_model()})"
    table = Table(title=title)
    many = any(r.device != "cpu" for r in results.values())
    cols = ["predictor", "train s/step", f"/ {reference}", "preset steps", "preset training h"] + (["cpu / this"] if many else []) + ["how"]
    for col in cols:
        table.add_column(col, justify="left" if col in ("predictor", "how") else "right")
    for key, r in results.items():
        ref = results.get(row_name(reference, r.device))
        ratio = r.train_s_per_step / ref.train_s_per_step if ref and ref.train_s_per_step > 0 else float("nan")
        cpu = results.get(r.name)
        speed = cpu.train_s_per_step / r.train_s_per_step if cpu and r.device != "cpu" and r.train_s_per_step > 0 else float("nan")
        table.add_row(key, _fmt(r.train_s_per_step), _fmt(ratio), str(r.preset_steps), _fmt(r.training_hours), *([_fmt(speed)] if many else []), r.note)
    for name in (n for n in predictors if n not in known):
        table.add_row(name, "-", "-", "-", "-", *(["-"] if many else []), "not registered: skipped")
    console.print(table)
    return results


def _fmt(value: float) -> str:
    return f"{value:.3g}" if value == value else "n/a"
