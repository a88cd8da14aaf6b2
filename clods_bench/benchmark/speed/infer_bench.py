"""`clods-bench bench infer`: inference time per frame of CloDS against the traditional pipeline, at a preset's size.

CloDS (paper appendix "Inference Time of CloDS"): one step of a learned simulator (MGN by default, the preset's
model size) plus an SMGS render of every camera view (the preset's cameras, resolution and Gaussians per face).
Traditional: one frame of the `physics` simulator plugin (the implicit solver, the scene's dt and sub-steps) plus
the ground-truth mesh rasterizer with the data generator's settings (texture, supersampling, lighting), every view.

Everything runs on one ground-truth trajectory of the preset's scene and mesh, simulated here (no dataset needed).
Frame t is timed as: each simulator rolls out one step from the true frames t-1, t (through the plugin interface),
and both renderers draw the true mesh of frame t+1, so both pipelines draw the same geometry; the simulators'
outputs are discarded. The parts of one frame are timed one after another, so load on the machine hits both
pipelines alike. One untimed frame first pays compilation and caches. Reported per part: the median over the timed
frames (and min, max, every frame); a pipeline's total is the sum of its parts' medians.
The learned simulator is fitted for a single optimiser step (untrained weights: a step's cost does not depend on
their values); the renderer keeps its initial parameters unless `fit_iterations` > 0.
"""

from __future__ import annotations

import dataclasses
import statistics
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from clods_bench.benchmark.core.descriptors import BuildContext
from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.benchmark.outputs.infer_output import PARTS, PIPELINES
from clods_bench.benchmark.speed.sim_bench import WARMUP_OPTIONS, step_option
from clods_bench.datasets.generate import make_cameras, make_texture, resolution_of, scene_raster_settings
from clods_bench.datasets.obstacle_nodes import face_colors, render_uv
from clods_bench.datasets.rasterizer import render_views
from clods_bench.datasets.scenes import simulate_scene
from clods_bench.errors import ClodsError
from clods_bench.numerics.thread_limits import thread_cap

if TYPE_CHECKING:
    from clods_bench.benchmark.core.config import RunConfig
    from clods_bench.benchmark.core.registry import Registry

REFERENCE_SIM = "physics"
"""The traditional pipeline's simulator plugin."""


def check_device(device: str, where: str = "bench infer --device") -> None:
    """Raise ClodsError unless `device` is 'cpu', or 'cuda[:N]' with a CUDA GPU torch can see."""
    import torch

    name = str(device)
    if not (name in ("cpu", "cuda") or (name.startswith("cuda:") and name[5:].isdigit())):
        raise ClodsError(f"unknown device '{name}'; known: cpu, cuda, cuda:N", where=where)
    if name != "cpu" and not torch.cuda.is_available():
        raise ClodsError(f"device '{name}' asked for, but torch sees no CUDA GPU", where=where,
                         hint="run on a machine with a GPU and gsplat installed, or use --device cpu")  # fmt: skip


def _part(ms: list[float]) -> dict[str, Any]:
    """Median, min, max and every value of one part's per-frame times (ms)."""
    return {"median_ms": statistics.median(ms), "min_ms": min(ms), "max_ms": max(ms), "per_frame_ms": list(ms)}


def learned_values(cfg: "RunConfig", spec: Any, name: str, device: str) -> dict[str, Any]:
    """Config values of the timed learned simulator: the preset's, one optimiser step, no warm-up, and on `device`
    when it is not the CPU and the simulator has a `device` option (CloDS's step then runs on the GPU too)."""
    option = step_option(spec)
    names = {f.name for f in dataclasses.fields(spec.config_cls)}
    values = {**cfg.sim_config.get(name, {}), option: 1, **{w: 0 for w in WARMUP_OPTIONS if w in names}}
    if device != "cpu" and "device" in names:
        values["device"] = device
    return values


def _learned_simulator(cfg: "RunConfig", registry: "Registry", name: str, scene: Any, traj: Any, work: Path, device: str = "cpu") -> Any:
    """The learned simulator `name` at the preset's size, fitted for one optimiser step (no warm-up) on `traj`."""
    spec = registry.get("simulator", name)
    if not spec.learned:
        raise ClodsError(f"'{name}' is not a learned simulator", where="bench infer --sim",
                         hint=f"CloDS's simulator is learned (e.g. mgn); '{REFERENCE_SIM}' is the traditional pipeline's")  # fmt: skip
    option = step_option(spec)
    if option is None:
        raise ClodsError(f"simulator '{name}' has no training-step option, so it cannot be fitted for one step to time it",
                         where="bench infer --sim")  # fmt: skip
    values = learned_values(cfg, spec, name, device)
    sim = spec.build(spec.make_config(values, where=f"sim_config.{name}"), BuildContext(scene=scene, seed=0, work_dir=work, progress=False))
    sim.fit([traj], FitContext(work_dir=work, seed=0, progress=False))
    return sim


def _renderer(cfg: "RunConfig", registry: "Registry", name: str, scene: Any, device: str, fit_iterations: int, work: Path) -> Any:
    """The renderer `name` with the preset's options, `fit_iterations` fit iterations, on `device` (gsplat there)."""
    spec = registry.get("renderer", name)
    names = {f.name for f in dataclasses.fields(spec.config_cls)} if dataclasses.is_dataclass(spec.config_cls) else set()
    values = dict(cfg.renderer_config.get(name, {}))
    if "iterations" not in names:
        raise ClodsError(f"renderer '{name}' has no 'iterations' option", where="bench infer", hint="time a mesh-driven renderer such as smgs")
    values["iterations"] = int(fit_iterations)
    if device != "cpu":
        if not {"backend", "device"} <= names:
            raise ClodsError(f"renderer '{name}' has no backend/device options", where="bench infer --device")
        values.update(backend="gsplat", device=device)
    return spec.build(spec.make_config(values, where=f"renderer_config.{name}"), BuildContext(scene=scene, seed=0, work_dir=work, progress=False))


def bench_infer(cfg: "RunConfig", registry: "Registry | None" = None, sim: str = "mgn", renderer: str = "smgs", frames: int = 5,
                views: int | None = None, device: str = "cpu", fit_iterations: int = 0, clock: Callable[[], float] = time.perf_counter,
                on_frame: Callable[[int, int], None] | None = None) -> dict[str, Any]:  # fmt: skip
    """Time `frames` frames of both pipelines at the size of `cfg` (a loaded preset); return the result dict.

    views: render only the first this many of the preset's cameras (a cap, reported in `caps`; never scaled up).
    device: 'cuda' renders with the gsplat backend on the GPU and steps the learned simulator there when it has a
    `device` option (the physics solver and the rasterizer stay on the CPU).
    on_frame(i, n) is called after each of the n frames (the first one untimed).
    """
    import torch

    check_device(device)
    threads = {"torch": torch.get_num_threads(), "numba": _numba_threads(), "cap": thread_cap(),
               "sim": cfg.sim_config.get(sim, {}).get("num_threads")}  # fmt: skip
    if frames < 1:
        raise ClodsError(f"must be >= 1, got {frames}", where="bench infer --frames")
    if fit_iterations < 0:
        raise ClodsError(f"must be >= 0, got {fit_iterations}", where="bench infer --fit-iterations")
    d = cfg.data
    if views is not None and not 1 <= views <= d.num_cameras:
        raise ClodsError(f"must be in 1..{d.num_cameras} (the preset's cameras), got {views}", where="bench infer --views")
    if registry is None:
        from clods_bench.benchmark.core.registry import default_registry

        registry = default_registry()
    scene = registry.get("scene", d.scene)
    mesh = scene.build_mesh(resolution_of(d))
    cameras = make_cameras(d, mesh)
    used = cameras[: views or len(cameras)]
    texture, uv = make_texture(d), mesh.texture_uv()
    settings = scene_raster_settings(d, scene)
    traj = simulate_scene(scene, mesh, frames + 3, seed=d.seed)  # frames 0..frames+2: one untimed frame, then the timed ones
    colors, uv = face_colors(traj.cells, traj.node_type), render_uv(uv, traj.num_nodes)  # obstacles drawn as in the data
    gpu = torch.device(device) if device != "cpu" else None

    def raster(t: int) -> np.ndarray:
        return render_views(traj.world_pos[t], traj.cells, uv, texture, used, settings, colors)

    def splat(t: int) -> Any:
        with torch.no_grad():
            v = torch.from_numpy(np.ascontiguousarray(traj.world_pos[t], dtype=np.float32))
            out = clods_renderer.render(v if gpu is None else v.to(gpu), used)
            if gpu is not None:
                torch.cuda.synchronize(gpu)
        return out

    with tempfile.TemporaryDirectory(prefix="clods-bench-infer-") as tmp:
        learned = _learned_simulator(cfg, registry, sim, scene, traj, Path(tmp) / "sim", device)
        pspec = registry.get("simulator", REFERENCE_SIM)
        physics = pspec.build(pspec.make_config(cfg.sim_config.get(REFERENCE_SIM, {}), where=f"sim_config.{REFERENCE_SIM}"),
                              BuildContext(scene=scene, seed=0, work_dir=Path(tmp), progress=False))  # fmt: skip
        physics.fit([traj], FitContext(work_dir=Path(tmp), seed=0, progress=False))
        clods_renderer = _renderer(cfg, registry, renderer, scene, device, fit_iterations, Path(tmp) / "renderer")
        clods_renderer.fit(traj.world_pos[:1], traj.cells, traj.mesh_pos, raster(0)[None], used)
    times: dict[tuple[str, str], list[float]] = {(p, q): [] for p in PIPELINES for q in PARTS}
    steps = (("clods", "sim_step", learned.rollout), ("clods", "render", splat), ("traditional", "sim_step", physics.rollout),
             ("traditional", "render", raster))  # fmt: skip
    for i, t in enumerate(range(1, frames + 2)):
        inp = RolloutInput.from_trajectory(traj.slice(t - 1, t + 2))  # true frames t-1, t; one step to t+1
        for pipeline, part, fn in steps:
            arg = inp if part == "sim_step" else t + 1
            t0 = clock()
            out = fn(arg)
            ms = 1e3 * (clock() - t0)
            if i == 0:
                _check_output(out, pipeline, part, inp, len(used), used[0])
            else:
                times[(pipeline, part)].append(ms)
        if on_frame is not None:
            on_frame(i + 1, frames + 1)
    return _result(cfg, sim, renderer, device, fit_iterations, frames, len(used), used[0], traj, clods_renderer, times, threads)


def _check_output(out: Any, pipeline: str, part: str, inp: RolloutInput, n_views: int, cam: Any) -> None:
    """The untimed first frame's outputs have the shapes the pipeline promises (so the timed work is the real work)."""
    shape = tuple(out.shape)
    want = (3, inp.node_type.shape[0], 3) if part == "sim_step" else (n_views, cam.height, cam.width, 3)
    if shape != want:
        raise ClodsError(f"{part} returned shape {shape}, expected {want}", where=f"bench infer ({pipeline})")


def _result(cfg: "RunConfig", sim: str, renderer: str, device: str, fit_iterations: int, frames: int, n_views: int, cam: Any,
            traj: Any, clods_renderer: Any, times: dict[tuple[str, str], list[float]], threads: dict[str, Any]) -> dict[str, Any]:  # fmt: skip
    """The result dict: counts, caps, notes, and per pipeline its parts and total (sum of the parts' medians)."""
    d = cfg.data
    gaussians = int(getattr(clods_renderer, "num_gaussians", 0))
    counts = {"nodes": int(traj.world_pos.shape[1]), "faces": int(traj.cells.shape[0]), "views": n_views, "views_preset": d.num_cameras,
              "width": cam.width, "height": cam.height, "pixels_per_view": cam.width * cam.height, "pixels": n_views * cam.width * cam.height,
              "gaussians": gaussians, "gaussians_per_face": gaussians // max(int(traj.cells.shape[0]), 1),
              "raster_supersample": d.supersample}  # fmt: skip
    caps = [f"views: {n_views} of the preset's {d.num_cameras} rendered by both pipelines; the times are for {n_views} views, not scaled"] if n_views < d.num_cameras else []  # fmt: skip
    notes = [f"{sim}: 1 optimiser step, no warm-up (untrained weights: a step's cost does not depend on them)",
             f"{renderer}: " + (f"fitted {fit_iterations} iterations on frame 0's true views" if fit_iterations else
                                "initial parameters, not fitted to images (fitted opacities can change when compositing stops)"),
             "both renderers draw the true mesh of the same frame; simulators step from the true frames",
             f"medians of {frames} timed frames after 1 untimed frame"]  # fmt: skip
    if device != "cpu":
        notes.append(f"{renderer} renders with backend gsplat on {device} (vertices moved there inside the timing); {sim} steps on "
                     f"{device} (positions back on the host inside the timing); the physics solver and the rasterizer run on the "
                     "CPU (they have no GPU path)")  # fmt: skip
    result: dict[str, Any] = {"preset": cfg.preset, "scene": d.scene, "sim": sim, "renderer": renderer, "reference_sim": REFERENCE_SIM,
                              "device": device, "frames": frames, "dt": float(traj.dt), "counts": counts, "caps": caps, "notes": notes,
                              "threads": threads,
                              "created": time.strftime("%Y-%m-%d %H:%M:%S")}  # fmt: skip
    for pipeline in PIPELINES:
        parts = {part: _part(times[(pipeline, part)]) for part in PARTS}
        result[pipeline] = {**parts, "total_ms": sum(p["median_ms"] for p in parts.values())}
    clods_total = result["clods"]["total_ms"]
    result["ratio_traditional_over_clods"] = result["traditional"]["total_ms"] / clods_total if clods_total > 0 else float("nan")
    return result


def _numba_threads() -> int | None:
    """numba's thread count (None without numba)."""
    try:
        import numba

        return int(numba.get_num_threads())
    except ImportError:  # pragma: no cover
        return None
