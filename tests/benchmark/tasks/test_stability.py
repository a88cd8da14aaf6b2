"""Stability task: exploding test doubles are caught at the right frame; monitors against brute force."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.core.interfaces import RolloutInput
from clods_bench.benchmark.core.registry import Registry, make_plugin_manager
from clods_bench.benchmark.outputs.rollout_samples import ROLLOUT_FILE, load_rollout_sample
from clods_bench.benchmark.outputs.rollout_strain import rollout_divergence, strain_model
from clods_bench.benchmark.outputs.tables import write_tables
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.benchmark.scoring.monitors import MeshMonitor, first_failure, lumped_mass
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.scenes import get_scene, simulate_scene
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.baselines import ConstantVelocity
from tests.conftest import tiny_config

K = 7  # the doubles break at this frame


class NaNAt(ConstantVelocity):
    """Constant velocity until frame K, NaN from there on."""

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        out = super().rollout(inp)
        out[K:] = np.nan
        return out


class RaiseAt(ConstantVelocity):
    """Raises whenever asked for frame K or later (a model that throws mid-rollout)."""

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        if inp.num_frames > K:
            raise FloatingPointError("overflow in the processor")
        return super().rollout(inp)


class StretchAt(ConstantVelocity):
    """Finite, but free nodes fly 3x away from the handle centre from frame K on (runaway strain)."""

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        out = super().rollout(inp)
        free = ~inp.kinematic_mask
        centre = out[1, ~free].mean(axis=0)
        out[K:, free] = centre + 3.0 * (out[K:, free] - centre)
        return out


class Doubles:
    @hookimpl
    def clods_bench_simulators(self) -> list[PluginSpec]:
        return [PluginSpec(name=n, description=n, build=lambda cfg, ctx, c=c: c()) for n, c in
                (("nan-at", NaNAt), ("raise-at", RaiseAt), ("stretch-at", StretchAt))]  # fmt: skip


@pytest.fixture(scope="module")
def registry() -> Registry:
    return Registry.from_plugin_manager(make_plugin_manager(extra_plugins=[Doubles()]))


def _run(root: Path, runs: Path, registry: Registry, sim: str, *extra: str) -> dict:
    cfg = tiny_config(root, f"runs_dir={runs}", *extra, sim=sim, task="stability")
    return json.loads((run_task(cfg, registry) / RECORD_FILE).read_text())


@pytest.mark.parametrize(("sim", "reason"), [("nan-at", "non-finite"), ("raise-at", "exception: FloatingPointError"), ("stretch-at", "edge strain")])
def test_double_diverges_at_k_with_reason(tiny_root: Path, tmp_path: Path, registry: Registry, sim: str, reason: str) -> None:
    rec = _run(tiny_root, tmp_path / "runs", registry, sim)
    extra = rec["per_seed"]["0"]["extra"]
    assert list(extra["diverged"].values()) == [K]
    assert next(iter(extra["reasons"].values())).startswith(reason)
    assert rec["metrics"]["first_divergence"]["mean"] == K and rec["metrics"]["diverged_fraction"]["mean"] == 1.0
    if sim == "stretch-at":  # 3x about the centre: some edge at least doubles (strain >= 2 > 0.5)
        assert rec["metrics"]["max_strain"]["mean"] >= 2.0 and math.isfinite(rec["metrics"]["rmse"]["mean"])
    else:
        assert rec["metrics"]["rmse"]["mean"] is None  # NaN in the record: no RMSE for a blown-up rollout
    # the report's rollout sample: the watched trajectory's long rollout and truth, and its divergence the run's own
    (path,) = (tmp_path / "runs").rglob(ROLLOUT_FILE)
    sample = load_rollout_sample(path)
    assert sample.trajectory in extra["diverged"] and sample.num_frames == extra["horizon_frames"] and sample.truth is not None
    div = rollout_divergence(sample, strain_model(sample, registry.get("scene", "flag")), "stability", rec["per_seed"]["0"])
    assert (div.frame, div.reason) == (K, extra["reasons"][sample.trajectory])


def test_baselines_stable_and_labelled_in_table(tiny_root: Path, tmp_path: Path, registry: Registry) -> None:
    runs = tmp_path / "runs"
    recs = {sim: _run(tiny_root, runs, registry, sim) for sim in ("constvel", "frozen")}
    _run(tiny_root, runs, registry, "nan-at", "label=exploder")
    paths = write_tables(runs, tmp_path / "tables", task="stability")
    csv = pd.read_csv(next(p for p in paths if p.suffix == ".csv"))
    assert sorted(csv["method"]) == ["Const. velocity", "Frozen", "exploder"]  # plugin row labels, and the one given
    md = next(p for p in paths if p.suffix == ".md").read_text()
    assert "stable" in md and f"frame {K} (1/1 rollouts): non-finite" in md
    # independent numbers: the long ground truth re-simulated here, the constant-velocity RMSE longhand
    store = DatasetStore.open(tiny_config(tiny_root).data.dataset_dir())
    traj = store.load_trajectory(2)
    frames = 2 * (traj.num_steps - 1) + 1
    gt = simulate_scene(get_scene("flag"), get_scene("flag").build_mesh((6, 4)), frames, traj.meta["seed"]).world_pos
    np.testing.assert_allclose(gt[: traj.num_steps], traj.world_pos, atol=1e-6)
    pred = gt.astype(np.float64).copy()
    free = traj.node_type == 0
    for t in range(2, frames):
        pred[t, free] = 2 * pred[t - 1, free] - pred[t - 2, free]
    rmse = np.mean([np.sqrt(np.mean((pred[t] - gt[t]) ** 2)) for t in range(2, frames)])
    row = csv[csv["method"] == "Const. velocity"].iloc[0]
    assert row["rmse/mean"] == pytest.approx(rmse, rel=1e-4) == pytest.approx(recs["constvel"]["metrics"]["rmse"]["mean"])
    assert row["horizon_frames"] == frames
    # the stability verdict, longhand: first frame >= 2 whose largest |l / l_rest - 1| over the
    # rest flag's edges exceeds the default threshold 0.5 (kinetic energy never triggers first here)
    rest = get_scene("flag").build_mesh((6, 4)).rest_pos
    edges = np.unique(np.sort(np.concatenate([traj.cells[:, [0, 1]], traj.cells[:, [1, 2]], traj.cells[:, [2, 0]]]), axis=1), axis=0)
    l0 = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    strain = np.abs(np.linalg.norm(pred[:, edges[:, 0]] - pred[:, edges[:, 1]], axis=2) / l0 - 1).max(axis=1)
    over = [t for t in range(2, frames) if strain[t] > 0.5]
    assert row["max_strain/mean"] == pytest.approx(strain.max(), rel=1e-4)
    if over:  # a flying flag extrapolated linearly tears apart: reported, with the frame
        assert row["diverged_fraction"] == 1 and row["first_divergence"] == over[0]
    else:
        assert row["diverged_fraction"] == 0
    assert csv[csv["method"] == "Frozen"].iloc[0]["diverged_fraction"] == 0  # the frozen flag never stretches


def test_bad_task_config_is_a_clear_error(tiny_root: Path, tmp_path: Path, registry: Registry) -> None:
    with pytest.raises(ClodsError, match="strain_threshold"):
        _run(tiny_root, tmp_path, registry, "constvel", "task_config.stability.strain_threshold=-1")
    with pytest.raises(ClodsError, match="unknown config key"):
        _run(tiny_root, tmp_path, registry, "constvel", "task_config.stability.horizon=3")


def test_monitors_against_brute_force() -> None:
    mesh = make_flag_mesh(4, 3, 2.0, 1.0)
    rng = np.random.default_rng(0)
    frames = mesh.rest_pos[None] + 0.05 * rng.standard_normal((5, mesh.num_nodes, 3))
    dt, density = 0.02, 0.3
    mon = MeshMonitor.from_rest(mesh.cells, mesh.rest_pos, density, dt)
    edges = {tuple(sorted((int(a), int(b)))) for c in mesh.cells for a, b in ((c[0], c[1]), (c[1], c[2]), (c[2], c[0]))}
    for t in range(5):
        worst = max(abs(np.linalg.norm(frames[t, a] - frames[t, b]) / np.linalg.norm(mesh.rest_pos[a] - mesh.rest_pos[b]) - 1) for a, b in edges)
        assert mon.max_strain(frames)[t] == pytest.approx(worst, rel=1e-12)
    # lumped masses: the 2 m x 1 m flag weighs density * 2 m^2 in total
    assert lumped_mass(mesh.rest_pos, mesh.cells, density).sum() == pytest.approx(density * 2.0, rel=1e-12)
    m = mon.mass
    for t in range(1, 5):
        ke = sum(0.5 * m[i] * np.sum(((frames[t, i] - frames[t - 1, i]) / dt) ** 2) for i in range(mesh.num_nodes))
        assert mon.kinetic_energy(frames)[t] == pytest.approx(ke, rel=1e-12)
    # thresholds: the first frame over each threshold, frames 0 and 1 never checked
    strain = mon.max_strain(frames)
    fail, _, _ = first_failure(frames, mon, strain_threshold=float(np.min(strain[2:])) - 1e-9, energy_threshold=1e30)
    assert fail.frame == 2 and "strain" in fail.reason
    energy = mon.kinetic_energy(frames)
    threshold = float(np.median(energy[2:]))
    fail, _, _ = first_failure(frames, mon, strain_threshold=1e9, energy_threshold=threshold)
    assert fail.frame == next(t for t in range(2, 5) if energy[t] > threshold) and "energy" in fail.reason
    bad = frames.copy()
    bad[4, 0, 1] = np.inf
    assert first_failure(bad, mon, 1e9, 1e30)[0].frame == 4
    assert first_failure(frames, mon, 1e9, 1e30)[0] is None


MGN_TINY = ["sim_config.mgn.train_steps=30", "sim_config.mgn.warmup_steps=5", "sim_config.mgn.latent_size=16",
            "sim_config.mgn.message_passing_steps=2", "sim_config.mgn.checkpoint_every=10"]  # fmt: skip


def test_training_curve_scores_every_snapshot_and_ends_at_the_final_model(tiny_root: Path, tmp_path: Path, registry: Registry) -> None:
    runs = tmp_path / "runs"
    plain = _run(tiny_root, runs, registry, "mgn", *MGN_TINY)  # trains the shared fit, without snapshots
    rec = _run(tiny_root, runs, registry, "mgn", *MGN_TINY, "task_config.stability.curve_every=10")
    curve = rec["per_seed"]["0"]["extra"]["training_curve"]
    assert curve["step"] == [10.0, 20.0, 30.0]
    # the fit finished without snapshots, so the curve trained its own copy: deterministic, the same final model
    assert len(list((runs / "fit_cache").glob("mgn-*"))) == 2
    for key in ("rmse", "max_strain", "diverged_fraction"):
        final = rec["metrics"][key]["mean"]
        assert final == plain["metrics"][key]["mean"] and curve[key][-1] == pytest.approx(final, nan_ok=True)
    assert all(math.isfinite(v) for v in curve["train_loss"])
    # a snapshot's point is the model of that step: scored again by hand with the step-10 weights
    work = next(p for p in (runs / "fit_cache").glob("mgn-*") if (p / "snapshots").is_dir())
    cfg = tiny_config(tiny_root, f"runs_dir={runs}", *MGN_TINY, sim="mgn", task="stability")
    from clods_bench.benchmark.core.builders import build_simulator, fit_on_meshes
    from clods_bench.benchmark.core.descriptors import TaskContext

    ctx = TaskContext(config=cfg, seed=0, work_dir=tmp_path / "w", registry=registry)
    store = DatasetStore.open(cfg.data.dataset_dir())
    sim = build_simulator(ctx)
    fit_on_meshes(ctx, sim, store, snapshot_every=10, identity_extra={"snapshot_every": 10})
    sim.use_snapshot(work / "snapshots" / "step_0000010.pt")
    traj = store.load_trajectory(2)
    frames = 2 * (traj.num_steps - 1) + 1
    gt = simulate_scene(get_scene("flag"), get_scene("flag").build_mesh((6, 4)), frames, traj.meta["seed"]).world_pos
    base = RolloutInput.from_trajectory(traj)
    kin = np.full((frames, *base.kinematic_pos.shape[1:]), np.nan, np.float32)
    kin[:, base.kinematic_mask] = gt[:, base.kinematic_mask]
    from dataclasses import replace

    pred = sim.rollout(replace(base, kinematic_pos=kin))
    rmse = np.mean([np.sqrt(np.mean((pred[t].astype(np.float64) - gt[t]) ** 2)) for t in range(2, frames)]) if np.isfinite(pred).all() else float("nan")
    assert math.isfinite(rmse) and curve["rmse"][0] == pytest.approx(rmse, rel=1e-5)


def test_training_curve_needs_a_learned_simulator(tiny_root: Path, tmp_path: Path, registry: Registry) -> None:
    with pytest.raises(ClodsError, match="keeps no weight snapshots") as err:
        _run(tiny_root, tmp_path / "runs", registry, "constvel", "task_config.stability.curve_every=10")
    assert "task_config.stability.curve_every" in str(err.value)
    with pytest.raises(ClodsError, match="curve_every"):
        _run(tiny_root, tmp_path / "runs", registry, "mgn", "task_config.stability.curve_every=-1")


def test_hop_distance_against_a_brute_force_shortest_path() -> None:
    from itertools import product

    from clods_bench.benchmark.scoring.monitors import hop_distance

    mesh = make_flag_mesh(5, 4, 2.0, 1.0)
    mon = MeshMonitor.from_rest(mesh.cells, mesh.rest_pos, 1.0, 0.01)
    n = mesh.num_nodes
    d = np.full((n, n), np.inf)  # Floyd-Warshall over unit-weight edges
    np.fill_diagonal(d, 0)
    for a, b in mon.edges:
        d[a, b] = d[b, a] = 1
    for k, i, j in product(range(n), repeat=3):
        d[i, j] = min(d[i, j], d[i, k] + d[k, j])
    sources = np.array([0, 7])
    assert np.array_equal(hop_distance(mon.edges, n, sources), d[sources].min(axis=0).astype(int))
    island = hop_distance(np.array([[0, 1]]), 4, np.array([0]))  # nodes 2 and 3 unreachable
    assert island.tolist() == [0, 1, -1, -1]


def test_a_strain_failure_names_how_far_the_tear_is_from_a_handle(tiny_root: Path) -> None:
    """Stretch one chosen edge of a flag pinned along one side: the failure reason and the task's watch name the
    edge's hop distance from the handles, which a hand count on the grid gives."""
    import dataclasses

    from clods_bench.benchmark.scoring.monitors import cloth_monitor, hop_distance
    from clods_bench.benchmark.tasks.stability import StabilityConfig, watch
    from clods_bench.datasets.types import HANDLE

    mesh = make_flag_mesh(6, 3, 2.0, 1.0)  # 6 columns along x, 3 rows along z
    node_type = np.zeros(mesh.num_nodes, np.int32)
    pinned = np.flatnonzero(np.isclose(mesh.rest_pos[:, 0], mesh.rest_pos[:, 0].min()))
    node_type[pinned] = HANDLE
    mon = cloth_monitor(object(), mesh.cells, mesh.mesh_pos, node_type, 1.0, 0.01)
    mon = dataclasses.replace(mon, rest_length=np.linalg.norm(mesh.rest_pos[mon.edges[:, 0]] - mesh.rest_pos[mon.edges[:, 1]], axis=1))
    frames = np.repeat(mesh.rest_pos[None], 6, axis=0)
    # the free end: the node farthest from the pinned side, moved away along +x at frame 4
    far = int(np.argmax(mesh.rest_pos[:, 0]))
    frames[4:, far, 0] += 5.0
    fail, _, _ = first_failure(frames, mon, 0.5, 1e30)
    hops = hop_distance(mon.edges, mesh.num_nodes, pinned)
    assert hops[far] == 5  # 5 columns from the pinned side; the most stretched edge runs to its neighbour, 4 hops out
    assert fail.frame == 4 and fail.reason.endswith(", 4 hops from a handle")
    result = watch(frames, None, mon, StabilityConfig(), 1.0, None, None)
    assert result["failure_frame"] == 4 and result["tear_hops_to_handle"] == 4
    frames[4:] = mesh.rest_pos
    frames[4:, pinned[0], 0] -= 5.0  # a handle node pulled: the torn edge touches a handle
    fail, _, _ = first_failure(frames, mon, 0.5, 1e30)
    assert fail.reason.endswith(", at a handle")
    no_handles = cloth_monitor(object(), mesh.cells, mesh.mesh_pos, np.zeros(mesh.num_nodes, np.int32), 1.0, 0.01)
    assert no_handles.handle_hops is None and no_handles.edge_hops_to_handle(0) is None
