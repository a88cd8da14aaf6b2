"""Where a learned simulator's long rollouts first pass 0.5 edge strain: how many edges, how far from the handles, and
whether they are stretched or compressed.

Issue 14, item 4: the stability task flags a rollout at the first frame where any edge's |l / l0 - 1| exceeds 0.5;
this says whether that is a tear (stretched edges, spreading) or a local crumple. Loads the finished fit of
`run stability --sim <sim> --preset <preset> --set seeds=[0]` from the fit cache (it does not train) and rolls it out
on the unviewed trajectories over the task's 2x horizon against the re-simulated ground truth.

    python examples/studies/tear_location.py mgn small
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

from clods_bench.benchmark.core.builders import build_simulator, fit_on_meshes, split_spec
from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.descriptors import TaskContext
from clods_bench.benchmark.core.fit_cache import fit_work_dir, sim_fit_identity
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.tasks.stability import horizon_frames, long_ground_truth, long_input, scene_monitor, stability_config
from clods_bench.datasets.store import DatasetStore


def hops_from_handles(edges: np.ndarray, node_type: np.ndarray) -> np.ndarray:
    """(V,) graph distance in edges from each node to the nearest non-NORMAL (handle) node."""
    v = len(node_type)
    a = coo_matrix((np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])), shape=(v, v))
    return shortest_path(a, unweighted=True, indices=np.nonzero(np.asarray(node_type) != 0)[0]).min(0)


def main(sim_name: str, preset: str) -> None:
    reg = default_registry()
    cfg = load_config(preset, None, [f"sim={sim_name}", "task=stability", "seeds=[0]"])
    ctx = TaskContext(config=cfg, seed=0, work_dir=Path(cfg.runs_dir), registry=reg)
    store = DatasetStore.open(cfg.data.dataset_dir())
    splits, scfg = split_spec(ctx), stability_config(ctx)
    sim = build_simulator(ctx)
    work = fit_work_dir(ctx, sim_fit_identity(ctx, list(splits.train), splits.interp_steps + 1, supervision="mesh"))
    if not (work / sim.checkpoint_name).exists():
        raise SystemExit(f"no fit in {work}: run `clods-bench run stability --sim {sim_name} --preset {preset} --set seeds=[0]` first")
    fit_on_meshes(ctx, sim, store)  # loads the finished fit
    scene = reg.get("scene", cfg.data.scene)
    frames = horizon_frames(splits.num_steps, scfg.horizon_factor)
    for i in splits.unviewed:
        stored = store.load_trajectory(i)
        traj = stored.slice(0, splits.num_steps)
        gt = long_ground_truth(ctx, scene, stored, i, frames)
        pred = sim.rollout(long_input(traj, gt, frames))
        mon = scene_monitor(scene, traj)
        e = mon.edges
        strain = np.linalg.norm(pred[:, e[:, 0]] - pred[:, e[:, 1]], axis=2) / mon.rest_length[None] - 1.0
        strain_gt = np.linalg.norm(gt[:, e[:, 0]] - gt[:, e[:, 1]], axis=2) / mon.rest_length[None] - 1.0
        past = np.abs(strain).max(1) > 0.5
        if not past.any():
            print(f"traj {i}: never past 0.5 (max {np.abs(strain).max():.3f})")
            continue
        f = int(np.argmax(past))
        hops = hops_from_handles(e, traj.node_type)
        bad = np.nonzero(np.abs(strain[f]) > 0.5)[0]
        eh = np.minimum(hops[e[bad, 0]], hops[e[bad, 1]])
        top = bad[np.argsort(-np.abs(strain[f, bad]))][:5]
        print(f"traj {i}: first frame past 0.5: {f}; {len(bad)} edges past 0.5 there; their hops from a handle: "
              f"min {eh.min():.0f} median {np.median(eh):.0f} max {eh.max():.0f} (mesh max {hops.max():.0f}); "
              f"strains of the 5 worst {np.round(strain[f, top], 3).tolist()} (ground truth {np.round(strain_gt[f, top], 3).tolist()}); "
              f"max |strain| over the rollout {np.abs(strain).max():.3f}; frames with an edge past 0.5: {int(past.sum())} of {frames}; "
              f"edges past 0.5 at the last frame: {int((np.abs(strain[-1]) > 0.5).sum())} of {len(e)}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "small")
