"""Cloth dynamics grounding (CDG): train a simulator, roll it out, score RMSE in the paper's Table 2 columns."""

from __future__ import annotations

import time

import numpy as np
from rich.progress import Progress

from clods_bench.benchmark.clods.labels import clods_label
from clods_bench.benchmark.core.builders import build_simulator, data_splits, fit_on_meshes
from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.descriptors import TaskContext, TaskResult
from clods_bench.benchmark.core.eval_data import WHERE, scored_data
from clods_bench.benchmark.core.fit_cache import fit_cost_seconds
from clods_bench.benchmark.core.interfaces import RolloutInput, rollout_checked
from clods_bench.benchmark.outputs.mesh_pictures import save_mesh_sample
from clods_bench.benchmark.outputs.rollout_samples import ROLLOUT_FILE, save_rollout_sample
from clods_bench.benchmark.scoring.metrics import cdg_columns, diverged_max, divergence_step, recorded_max, rmse_per_step
from clods_bench.benchmark.scoring.monitors import cloth_monitor
from clods_bench.datasets.data_config import DataConfig
from clods_bench.datasets.obstacle_nodes import cloth_nodes
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError


def cdg_row_label(cfg: RunConfig) -> str | None:
    """The row label of a CDG run given none: a simulator learned from video (--sim and --renderer) is a CloDS row
    ('CloDS**', 'CloDS*', 'CloDS', see `clods.labels`); other rows get the default (their plugin names)."""
    return clods_label(cfg) if cfg.sim and cfg.renderer else None


def run_cdg(ctx: TaskContext) -> TaskResult:
    """One seed of CDG: fit on the training meshes' interpolation frames, roll out the viewed and unviewed trajectories
    of the scored dataset (`data`, or `task_config.cdg.eval_data` laid over it)."""
    cfg = ctx.config
    store = DatasetStore.open(cfg.data.dataset_dir())
    store.require_meshes("task cdg")
    scored = scored_data(cfg, ctx.registry)
    splits, eval_store = data_splits(scored), _scored_store(store, scored, scored == cfg.data)
    clods_extra: dict[str, object] = {}
    extraction = None  # (extracted meshes, their truth) of a row learned from video
    t0 = time.perf_counter()
    if cfg.renderer:  # learned from video: the CloDS pipeline (stages 1-3) replaces mesh supervision
        from clods_bench.benchmark.clods.pipeline import error_accumulation, run_pipeline, video_train_ids

        train_ids = video_train_ids(ctx)
        clods = run_pipeline(ctx, train_ids)
        sim, fit_stats = clods.simulator, clods.stats
        extraction = (clods.meshes, clods.truth)
        fit_wall = time.perf_counter() - t0
        clods_extra = {
            "egt_curve": clods.egt_curve,
            "egt_per_trajectory": clods.egt_per_trajectory,
            "accumulation": error_accumulation(sim, clods.meshes, clods.truth),  # E-GT, P-GT, P-E on the training videos
        }
        fit_seconds = max(fit_wall, float(fit_stats.get("cost_seconds", 0.0)))
    else:  # a simulator with nothing to learn (physics) is built for the scene it is rolled out on
        learned = ctx.registry.get("simulator", cfg.sim).learned
        sim = build_simulator(ctx, None if learned else scored.scene)
        train_ids, fit_stats, fit_wall, _ = fit_on_meshes(ctx, sim, store)
        fit_seconds = fit_cost_seconds(fit_wall, fit_stats)

    groups = {"viewed": list(splits.viewed), "unviewed": list(splits.unviewed)}
    curves: dict[str, list[np.ndarray]] = {g: [] for g in groups}
    diverged: dict[str, int] = {}
    infer_seconds, infer_steps = 0.0, 0
    strains: list[float] = []  # per rollout: largest edge strain |l/l0 - 1| over its frames (RMSE alone hides a tear)
    scene = ctx.registry.get("scene", scored.scene)  # rest shape of the max-strain column: the scored cloth's
    num_nodes: set[int] = set()
    total = sum(len(v) for v in groups.values())
    sample: tuple[str, int, object, np.ndarray] | None = None
    with Progress(transient=True, disable=not cfg.progress) as bar:
        job = bar.add_task(f"rollouts ({cfg.sim})", total=total)
        for group, ids in groups.items():
            for i in ids:
                traj = eval_store.load_trajectory(i)
                num_nodes.add(traj.num_nodes)
                inp = RolloutInput.from_trajectory(traj, splits.num_steps)
                t1 = time.perf_counter()
                pred = rollout_checked(sim, inp, cfg.sim or "?")
                infer_seconds += time.perf_counter() - t1
                infer_steps += inp.num_frames - 2
                step = divergence_step(pred)
                if step is not None:
                    diverged[f"{group}/{i}"] = step
                curves[group].append(rmse_per_step(pred, traj.world_pos[: splits.num_steps], cloth_nodes(traj.node_type)))
                if sample is None or (group == "unviewed" and sample[0] != "unviewed"):  # picture: an unseen trajectory if any
                    sample = (group, i, traj, pred)
                strains.append(_max_strain(scene, traj, pred))
                bar.advance(job)

    _save_pictures(ctx, sample, splits.interp_steps, extraction)
    metrics = cdg_columns(curves, splits.interp_steps, splits.num_steps)
    metrics["max_strain"] = recorded_max(max(strains)) if strains else float("nan")  # NaN: a rollout diverged
    timings = {
        "fit_seconds": fit_seconds,  # training cost; a fit read from the cache counts at its recorded cost
        "fit_wall_seconds": fit_wall,
        "infer_ms_per_step": 1000.0 * infer_seconds / max(infer_steps, 1),
        "infer_seconds": infer_seconds,
    }
    timings.update({f"fit/{k}": float(v) for k, v in (fit_stats or {}).items()})
    mean_curves = {g: np.mean(np.stack(c), axis=0).tolist() for g, c in curves.items() if c}
    scored_info = {
        "scene": scored.scene,
        "dataset": eval_store.root.name,
        "num_nodes": sorted(num_nodes),
        "num_steps": splits.num_steps,
        "interp_steps": splits.interp_steps,
        **{g: list(v) for g, v in groups.items()},
    }
    extra = {"diverged": diverged, "train_ids": list(train_ids), "scored_data": scored_info, **clods_extra}
    return TaskResult(metrics=metrics, timings=timings, curves=mean_curves, extra=extra)


def _scored_store(train_store: DatasetStore, scored: DataConfig, same: bool) -> DatasetStore:
    """The store of the scored dataset (the training store when they are one), checked to hold meshes."""
    if same:
        return train_store
    eval_store = DatasetStore.open(scored.dataset_dir())
    if not eval_store.has_meshes:
        raise ClodsError(f"the scored dataset {eval_store.root} has no meshes (imported from video); CDG scores rollouts against meshes",
                         where=f"{WHERE}.eval_data.path", hint="name a dataset with ground-truth meshes")  # fmt: skip
    return eval_store


def _max_strain(scene: object, traj: Trajectory, pred: np.ndarray) -> float:
    """Largest edge strain |l/l0 - 1| of a rollout's cloth against the scene's rest shape: inf for a rollout that
    diverged (a frame with NaN/Inf), never the strain of its finite part alone."""
    return diverged_max(cloth_monitor(scene, traj.cells, traj.mesh_pos, traj.node_type, 1.0, 1.0).max_strain(pred))


def _save_pictures(ctx: TaskContext, sample: tuple | None, interp_steps: int, extraction: tuple[list, list] | None) -> None:
    """Mesh samples for the report's pictures: the rollout of one (unviewed if any) trajectory against its truth and,
    for a row learned from video, the meshes stage 2 extracted from its first training video against their truth."""
    label = ctx.config.label or ctx.config.sim or "prediction"
    if sample is not None:
        group, i, traj, pred = sample
        save_rollout_sample(ctx.work_dir / ROLLOUT_FILE, label, pred, traj.world_pos, traj.cells, traj.mesh_pos, traj.node_type, traj.dt,
                            f"{group}/{i}", marks=[interp_steps], title=f"{label}: rollout of {group} trajectory {i}, seed {ctx.seed}")  # fmt: skip
    if extraction and extraction[0]:
        meshes, truth = extraction
        same = meshes[0].world_pos.shape[1:] == truth[0].world_pos.shape[1:]  # else a reconstructed mesh: its own topology
        save_mesh_sample(ctx.work_dir / "extraction_meshes.npz", meshes[0].cells, {"extracted (stage 2)": meshes[0].world_pos},
                         truth=truth[0].world_pos if same else None, title=f"{label}: meshes extracted from training video 0, seed {ctx.seed}")  # fmt: skip
