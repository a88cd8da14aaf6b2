"""Stability: train as in CDG, roll out the test trajectories for a long horizon and watch them blow up.

The rollout runs `horizon_factor` times the stored trajectory length (num_steps - 1 steps; the
simulator trains on the first interp_steps of them). Ground truth past the stored frames is
re-simulated from the trajectory's seed with the scene's solver (checked against the stored
frames, cached next to the dataset); when that is impossible (imported data, another scene)
frames past the stored ones are scored only by the finite / strain / energy monitors.
A rollout fails at the first frame with NaN/Inf, edge strain above `strain_threshold`, or
kinetic energy above `energy_factor` x the ground truth's maximum; an exception inside
`rollout` counts as a failure at the frame it happens (found by bisection over shorter
horizons), and the run goes on with the next trajectory.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import Progress

from clods_bench import integrity
from clods_bench.benchmark.core.builders import build_simulator, fit_on_meshes, split_spec
from clods_bench.benchmark.core.descriptors import TaskContext, TaskResult
from clods_bench.benchmark.core.fit_cache import fit_cost_seconds
from clods_bench.benchmark.core.interfaces import ContractError, RolloutInput, Simulator, check_rollout
from clods_bench.benchmark.outputs.rollout_samples import ROLLOUT_FILE, save_rollout_sample
from clods_bench.benchmark.scoring.metrics import diverged_max, recorded_max, rmse_per_step
from clods_bench.benchmark.scoring.monitors import MeshMonitor, cloth_monitor, first_failure
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict


@dataclass(frozen=True)
class StabilityConfig:
    """Options of the stability task (`task_config.stability`)."""

    horizon_factor: float = 2.0
    """Rollout length as a multiple of the stored trajectory's num_steps - 1 steps (>= 1)."""
    strain_threshold: float = 0.5
    """A frame fails when max over edges |l/l0 - 1| exceeds this."""
    energy_factor: float = 10.0
    """A frame fails when its kinetic energy exceeds this times the ground truth's largest."""
    extend_ground_truth: bool = True
    """Re-simulate the ground truth past the stored frames (else score only the monitors there)."""
    locate_exceptions: bool = True
    """Bisect over shorter horizons to find the frame at which a raising rollout fails."""
    curve_every: int = 0
    """> 0: a training curve: the learned simulator keeps its weights every this many steps, and each snapshot's
    long rollouts are scored like the final model's (RMSE, max strain, divergence against training step)."""

    def validate(self, where: str = "task_config.stability") -> None:
        """Raise ClodsError naming the field that is out of range."""
        for name, ok in (
            ("horizon_factor", self.horizon_factor >= 1.0),
            ("strain_threshold", self.strain_threshold > 0),
            ("energy_factor", self.energy_factor > 0),
            ("curve_every", self.curve_every >= 0),
        ):
            if not ok:
                raise ClodsError(f"value {getattr(self, name)!r} is out of range", where=f"{where}.{name}")


def stability_config(ctx: TaskContext) -> StabilityConfig:
    """The run's stability options, typed and checked."""
    cfg = dataclass_from_dict(StabilityConfig, dict(ctx.config.task_config.get("stability", {})), where="task_config.stability")
    cfg.validate()
    return cfg


def horizon_frames(num_steps: int, factor: float) -> int:
    """Frames of the long rollout: round(factor * (num_steps - 1)) steps after frame 0."""
    return int(round(factor * (num_steps - 1))) + 1


def long_ground_truth(ctx: TaskContext, scene: Any, traj: Trajectory, index: int, frames: int) -> np.ndarray | None:
    """Ground truth (frames,V,3) re-simulated from the trajectory's seed, or None when it cannot be reproduced.

    Cached atomically in `<dataset dir>-long<frames>/traj_<index>.npz`; the re-simulation must
    match the stored frames to 1e-5 m, so only data this scene generated is ever extended.
    """
    from clods_bench.datasets.generate import resolution_of
    from clods_bench.datasets.scenes import simulate_scene

    if frames <= traj.num_steps:
        return traj.world_pos[:frames]
    seed = traj.meta.get("seed")
    if seed is None or traj.meta.get("scene") != getattr(scene, "name", None):
        return None
    data_dir = ctx.config.data.dataset_dir()
    path = data_dir.with_name(f"{data_dir.name}-long{frames}") / f"traj_{index:04d}.npz"
    world = None
    if path.is_file():
        integrity.check_zip(path, "delete it to simulate it again")
        try:
            with np.load(path, allow_pickle=False) as npz:
                world = npz["world_pos"]
        except (OSError, ValueError, KeyError):
            world = None
    if world is None:
        try:
            mesh = scene.build_mesh(resolution_of(ctx.config.data))
            world = simulate_scene(scene, mesh, frames, int(seed)).world_pos
        except ClodsError:
            return None
        integrity.write_npz(path, world_pos=world)
    stored = traj.world_pos
    if world.shape != (frames, *stored.shape[1:]) or not np.allclose(world[: len(stored)], stored, atol=1e-5):
        return None
    return world


def long_input(traj: Trajectory, gt: np.ndarray | None, frames: int) -> RolloutInput:
    """Rollout input of `frames` frames: kinematic positions from the long ground truth, else the last stored ones held."""
    base = RolloutInput.from_trajectory(traj)
    kin = np.full((frames, *base.kinematic_pos.shape[1:]), np.nan, np.float32)
    mask = base.kinematic_mask
    if gt is not None:
        kin[:, mask] = gt[:frames, mask]
    else:
        n = min(frames, traj.num_steps)
        kin[:n, mask] = traj.world_pos[:n, mask]
        kin[n:, mask] = traj.world_pos[n - 1, mask]
    return replace(base, kinematic_pos=kin)


def _truncate(inp: RolloutInput, frames: int) -> RolloutInput:
    return replace(inp, kinematic_pos=inp.kinematic_pos[:frames])


def safe_rollout(sim: Simulator, inp: RolloutInput, name: str, locate: bool) -> tuple[np.ndarray, int | None, str | None]:
    """(frames (T,V,3) with NaN past a failure, frame of an exception or None, its message).

    An exception in `sim.rollout` is caught; with `locate` the largest horizon that runs is
    found by bisection (hi frames fail, lo frames run: the failure is at frame hi - 1) and its
    frames are kept; without it the failure is put at frame 2, the first predicted one. A wrong
    output (non-numeric, a wrong shape, given positions changed: `ContractError`) is a plugin bug, not a
    divergence, and is raised.
    """
    full = inp.num_frames
    try:
        return check_rollout(sim.rollout(inp), inp, name), None, None
    except ContractError:
        raise
    except Exception as exc:  # noqa: BLE001 - a diverging model may raise anything (memory too); record it and go on
        message = f"{type(exc).__name__}: {exc}"
    out = np.full((full, *inp.init_pos.shape[1:]), np.nan, np.float32)
    out[:2] = inp.init_pos
    lo, hi, best = 2, full, None
    while locate and hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            pred = check_rollout(sim.rollout(_truncate(inp, mid)), _truncate(inp, mid), name)
            lo, best = mid, pred
        except Exception:  # noqa: BLE001
            hi = mid
    if best is not None:
        out[:lo] = best
    return out, (hi - 1 if locate else 2), message


def watch(
    pred: np.ndarray, gt: np.ndarray | None, monitor: MeshMonitor, cfg: StabilityConfig, gt_energy_max: float, exc_frame: int | None,
    exc_message: str | None,
) -> dict[str, Any]:
    """Score one long rollout: RMSE where ground truth exists, strain/energy curves, first failure and reason."""
    failure, strain, energy = first_failure(pred, monitor, cfg.strain_threshold, cfg.energy_factor * gt_energy_max)
    frame, reason = (failure.frame, failure.reason) if failure is not None else (None, None)
    tear_hops = failure.tear_hops_to_handle if failure is not None else None  # where a strain failure tore the cloth
    if exc_frame is not None and (frame is None or exc_frame <= frame):
        frame, reason, tear_hops = exc_frame, f"exception: {exc_message}", None
    n = 0 if gt is None else min(len(gt), len(pred))
    curve = rmse_per_step(pred[:n], gt[:n], monitor.nodes) if n else np.zeros(0)
    scored = curve[2:]
    return {
        "rmse": float(np.mean(scored)) if scored.size and np.isfinite(scored).all() else float("nan"),
        "rmse_curve": curve,
        "strain_curve": strain,
        "energy_ratio_curve": energy / max(gt_energy_max, 1e-300),
        "max_strain": diverged_max(strain[2:]),
        "max_energy_ratio": float(np.nanmax(energy[2:]) / max(gt_energy_max, 1e-300)) if len(energy) > 2 else 0.0,
        "failure_frame": frame,
        "reason": reason,
        "tear_hops_to_handle": tear_hops,
    }


def scene_monitor(scene: Any, traj: Trajectory) -> MeshMonitor:
    """The cloth monitor (edges, rest lengths, masses) of a trajectory's mesh, with the scene's cloth density."""
    params = getattr(scene, "params", None)
    return cloth_monitor(scene, traj.cells, traj.mesh_pos, traj.node_type, float(getattr(params, "density", 1.0)), traj.dt)


def _nanmean_curves(curves: list[np.ndarray], length: int, reduce: str) -> list[float]:
    stacked = np.full((len(curves), length), np.nan)
    for i, c in enumerate(curves):
        stacked[i, : len(c)] = c
    with np.errstate(all="ignore"):
        out = np.mean(stacked, axis=0) if reduce == "mean" else np.max(stacked, axis=0)
    return [float(v) for v in out]


def run_stability(ctx: TaskContext) -> TaskResult:
    """One seed: fit as in CDG, roll out every test trajectory for the long horizon, record failures."""
    cfg = ctx.config
    scfg = stability_config(ctx)
    splits = split_spec(ctx)
    scene = ctx.registry.get("scene", cfg.data.scene)
    store = DatasetStore.open(cfg.data.dataset_dir())
    store.require_meshes("task stability")
    sim = build_simulator(ctx)
    name = cfg.sim or "?"

    if scfg.curve_every > 0:
        train_ids, fit_stats, fit_wall, work, snaps = _fit_with_snapshots(ctx, sim, store, scfg.curve_every)
    else:
        train_ids, fit_stats, fit_wall, work = fit_on_meshes(ctx, sim, store)  # the CDG run's training, shared through the fit cache
        snaps = []
    fit_seconds = fit_cost_seconds(fit_wall, fit_stats)

    frames = horizon_frames(splits.num_steps, scfg.horizon_factor)
    ids = list(splits.unviewed)
    curve_rows: list[dict[str, float]] = []
    loss_of = _loss_at_step(work / f"{name}_train_log.json") if snaps else None
    if snaps:
        with Progress(transient=True, disable=not cfg.progress) as bar:
            job = bar.add_task(f"training curve ({name}, {len(snaps)} snapshots)", total=len(snaps))
            for step, path in snaps[:-1]:  # the last snapshot is the final model, scored below
                sim.use_snapshot(path)
                rows, _, _ = long_rollouts(ctx, sim, scene, store, splits, ids, frames, scfg, name, progress=False)
                curve_rows.append({"step": float(step), "train_loss": loss_of(step), **rollout_summary(list(rows.values()), frames)})
                bar.advance(job)
        sim.use_snapshot(snaps[-1][1])
    kept: list[tuple[int, Trajectory, np.ndarray, np.ndarray]] = []
    per_traj, infer_seconds, extended = long_rollouts(ctx, sim, scene, store, splits, ids, frames, scfg, name, progress=cfg.progress, keep=kept)
    _save_rollout(ctx, kept, splits.num_steps)
    infer_steps = (frames - 2) * len(ids)

    results = list(per_traj.values())
    metrics = rollout_summary(results, frames)
    if snaps:
        curve_rows.append({"step": float(snaps[-1][0]), "train_loss": loss_of(snaps[-1][0]), **metrics})  # type: ignore[misc]
    timings = {"fit_seconds": fit_seconds, "fit_wall_seconds": fit_wall, "infer_ms_per_step": 1000.0 * infer_seconds / max(infer_steps, 1), "infer_seconds": infer_seconds}
    timings.update({f"fit/{k}": float(v) for k, v in (fit_stats or {}).items()})
    curves = {
        "rmse": _nanmean_curves([r["rmse_curve"] for r in results], frames, "mean"),
        "max_strain": _nanmean_curves([r["strain_curve"] for r in results], frames, "max"),
        "energy_ratio": _nanmean_curves([r["energy_ratio_curve"] for r in results], frames, "max"),
    }
    extra = {
        "diverged": {k: r["failure_frame"] for k, r in per_traj.items() if r["failure_frame"] is not None},
        "reasons": {k: r["reason"] for k, r in per_traj.items() if r["reason"] is not None},
        "tear_hops_to_handle": {k: r["tear_hops_to_handle"] for k, r in per_traj.items() if r.get("tear_hops_to_handle") is not None},
        "rollouts": len(results),
        "horizon_frames": frames,
        "ground_truth_frames": frames if extended else splits.num_steps,
        "thresholds": {"strain": scfg.strain_threshold, "energy_factor": scfg.energy_factor},
        "train_ids": list(train_ids),
    }
    if curve_rows:
        extra["training_curve"] = {key: [row[key] for row in curve_rows] for key in curve_rows[0]}
    return TaskResult(metrics=metrics, timings=timings, curves=curves, extra=extra)


def long_rollouts(
    ctx: TaskContext, sim: Simulator, scene: Any, store: DatasetStore, splits: Any, ids: list[int], frames: int, scfg: StabilityConfig,
    name: str, progress: bool, keep: list[tuple[int, Trajectory, np.ndarray, np.ndarray]] | None = None,
) -> tuple[dict[str, dict[str, Any]], float, bool]:  # fmt: skip
    """Roll `sim` out on the trajectories `ids` for `frames` frames and watch each; returns (per trajectory, inference
    seconds, whether every ground truth reached the full horizon). `keep` receives the first trajectory's
    (index, stored trajectory, ground truth, rollout) for the report's videos."""
    per_traj: dict[str, dict[str, Any]] = {}
    infer_seconds, extended = 0.0, True
    with Progress(transient=True, disable=not progress) as bar:
        job = bar.add_task(f"long rollouts ({name}, {frames} frames)", total=len(ids))
        for i in ids:
            stored = store.load_trajectory(i)
            traj = stored.slice(0, splits.num_steps)
            gt = long_ground_truth(ctx, scene, stored, i, frames) if scfg.extend_ground_truth else None
            extended &= gt is not None and len(gt) >= frames
            gt = gt if gt is not None else traj.world_pos
            inp = long_input(traj, gt if len(gt) >= frames else None, frames)
            t1 = time.perf_counter()
            pred, exc_frame, message = safe_rollout(sim, inp, name, scfg.locate_exceptions)
            infer_seconds += time.perf_counter() - t1
            monitor = scene_monitor(scene, traj)
            gt_energy = float(np.max(monitor.kinetic_energy(gt)))
            result = watch(pred, gt, monitor, scfg, gt_energy, exc_frame, message)
            result["gt_max_strain"] = float(np.max(monitor.max_strain(gt)[1:]))
            per_traj[f"unviewed/{i}"] = result
            if keep is not None and not keep:
                keep.append((i, traj, gt, pred))
            if result["failure_frame"] is not None and progress:
                Console(stderr=True).print(f"[yellow]{name}: trajectory {i} diverged at frame {result['failure_frame']}: {result['reason']}[/yellow]")
            bar.advance(job)
    return per_traj, infer_seconds, extended


def _save_rollout(ctx: TaskContext, kept: list[tuple[int, Trajectory, np.ndarray, np.ndarray]], stored_frames: int) -> None:
    """The first watched trajectory's long rollout as the seed's rollout sample (the report's videos and 3D views);
    its ground truth only when it covers the whole horizon (re-simulated), else none."""
    if not kept:
        return
    i, traj, gt, pred = kept[0]
    label = ctx.config.label or ctx.config.sim or "prediction"
    truth = gt if len(gt) >= len(pred) else None
    save_rollout_sample(ctx.work_dir / ROLLOUT_FILE, label, pred, truth, traj.cells, traj.mesh_pos, traj.node_type, traj.dt, f"unviewed/{i}",
                        marks=[stored_frames - 1], title=f"{label}: long rollout of unviewed trajectory {i}, seed {ctx.seed}")  # fmt: skip


def rollout_summary(results: list[dict[str, Any]], frames: int) -> dict[str, float]:
    """The task's metrics over the watched rollouts: mean RMSE, largest strain and energy ratio, divergence."""
    failed = [r["failure_frame"] for r in results if r["failure_frame"] is not None]
    rmses = [r["rmse"] for r in results]
    return {
        "rmse": float(np.mean(rmses)) if rmses else float("nan"),
        "max_strain": recorded_max(np.nanmax([r["max_strain"] for r in results])) if results else float("nan"),  # NaN: one diverged
        "gt_max_strain": float(max(r["gt_max_strain"] for r in results)) if results else float("nan"),
        "max_energy_ratio": float(np.nanmax([r["max_energy_ratio"] for r in results])) if results else float("nan"),
        "diverged_fraction": len(failed) / max(len(results), 1),
        "first_divergence": float(min(failed)) if failed else float("nan"),
        "horizon_frames": float(frames),
    }


def _fit_with_snapshots(
    ctx: TaskContext, sim: Simulator, store: DatasetStore, every: int
) -> tuple[list[int], dict, float, Path, list[tuple[int, Path]]]:
    """Fit keeping weight snapshots every `every` steps; returns (train ids, fit stats, wall seconds, work dir,
    snapshots by step).

    The fit is the CDG run's (shared through the fit cache) when it trains here or was trained with the same
    snapshots; a fit that finished earlier without them is trained again in its own work directory."""
    where = "task_config.stability.curve_every"
    if not callable(getattr(sim, "snapshots", None)) or not callable(getattr(sim, "use_snapshot", None)):
        raise ClodsError(f"simulator '{ctx.config.sim}' keeps no weight snapshots", where=where,
                         hint="training curves need a learned simulator (mgn, bsms, hcmt, dhmp, lip, ...); set curve_every=0")  # fmt: skip
    train_ids, stats, wall, work = fit_on_meshes(ctx, sim, store, snapshot_every=every)
    steps = int(stats.get("train_steps", 0))
    want = _snapshot_steps(steps, every, int(getattr(getattr(sim, "config", None), "warmup_steps", 0)))
    snaps = sim.snapshots(work)  # type: ignore[attr-defined]
    if not want <= {s for s, _ in snaps}:
        train_ids, stats, wall, work = fit_on_meshes(ctx, sim, store, snapshot_every=every, identity_extra={"snapshot_every": every})
        snaps = sim.snapshots(work)  # type: ignore[attr-defined]
    snaps = [(s, p) for s, p in snaps if s in want]
    if not snaps or snaps[-1][0] != steps:
        raise ClodsError(f"the fit in {work} left snapshots at steps {[s for s, _ in snaps]}, not at its last step {steps}", where=where)
    return train_ids, stats, wall, work, snaps


def _snapshot_steps(train_steps: int, every: int, warmup: int) -> set[int]:
    """Steps at which a fit of `train_steps` keeps snapshots: multiples of `every` after the warm-up, and the last."""
    return {s for s in range(every, train_steps + 1, every) if s > warmup} | {train_steps}


def _loss_at_step(train_log: Path) -> Any:
    """step -> mean training loss of the curve block ending at or before it, from the fit's train log (NaN without)."""
    try:
        log = json.loads(Path(train_log).read_text())
    except (OSError, ValueError):
        log = {}
    curve, block = log.get("loss_curve"), log.get("curve_block")

    def loss(step: int) -> float:
        if not curve or not block:
            return float("nan")
        k = min(len(curve), int(step) // int(block)) - 1
        return float(curve[k]) if k >= 0 else float("nan")

    return loss
