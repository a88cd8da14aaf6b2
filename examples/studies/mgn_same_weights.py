"""Is clods-bench's MGN DeepMind's MeshGraphNets cloth model? Same weights, same inputs: network, loss, gradients, update.

The reference is github.com/google-deepmind/deepmind-research, `meshgraphnets/`, at commit
d8df4155dc72fc3dfff9f857412168993348ca23 (a git checkout, given as the argument). It is TensorFlow 1 and Sonnet 1
code; `mgn_reference_run.py` runs it under `--tf-python`, a Python with tensorflow 1.15 and dm-sonnet 1.36
(Python 3.7; e.g. `pip install tensorflow-cpu==1.15.0 dm-sonnet==1.36 tensorflow-probability==0.8.0 "numpy<1.19"
"protobuf<3.21"`). Every clods-bench tensor is copied to the reference variable of the same role; compared:

- A, float64: `core_model.EncodeProcessDecode` (encoders, residual GraphNetBlocks, decoder) against clods-bench's
  encoders, `MgnProcessor` and decoder, on the same normalised features: the output and the gradients of
  sum(output * probe) with respect to the features and every parameter; at the ci widths on the ci flag and at
  the paper's (latent 128, 15 steps) on the FLAGSIMPLE-size flag;
- B, float32 (the reference's `Normalizer` keeps float32 sums, so its cloth model runs in float32 only):
  `cloth_model.Model.loss` on K consecutive frames of a simulated flag (features, online normalisers accumulating,
  target acceleration, the loss over NORMAL nodes) against clods-bench's `Trainer.one_step_loss` with zero noise,
  the gradients of the last loss, and the integrated next positions;
- C: one frame through `dataset.split_and_preprocess` (the training noise): noise only on NORMAL nodes, the
  target moved by (1 - gamma) of it, and clods-bench's target acceleration from that noise;
- D: `run_model.learner`'s learning rate against `MgnConfig().learning_rate_at` at several steps.

    PYTHONPATH=. python examples/studies/mgn_same_weights.py /path/to/deepmind-research --tf-python /path/to/py37/bin/python \
        --out results/studies/mgn_same_weights/result.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch

from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.meshes import make_flag_mesh, make_flagsimple_mesh
from clods_bench.datasets.types import NORMAL, Trajectory
from clods_bench.plugins.simulators.learned.config import MgnConfig
from clods_bench.plugins.simulators.learned.graph import EdgeSet, TopologyCache, mesh_edges
from clods_bench.plugins.simulators.learned.mgn import build_mgn
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.trainer import Batch, Trainer, TrainingData

sys.path.insert(0, str(Path(__file__).resolve().parent))
from same_weights_common import check_checkout, fail, max_differences, write_result  # noqa: E402

REFERENCE = "github.com/google-deepmind/deepmind-research (meshgraphnets/)"
COMMIT = "d8df4155dc72fc3dfff9f857412168993348ca23"
PINNED = SimpleNamespace(name="study", has_obstacles=False, has_handles=True)
LR_STEPS = [0, 1000, 123_456, 2_500_000, 5_000_000, 9_999_999]


def tf_name(name: str, steps: int) -> str:
    """The reference variable of one of clods-bench's MGN tensors (ValueError when there is no rule for it)."""
    parts = name.split(".")
    if parts[0] == "node_encoder":
        scope, rest = "EncodeProcessDecode/encoder", parts[1:]
        mlp, norm = "mlp", "layer_norm"
    elif parts[:2] == ["edge_encoders", "mesh"]:
        scope, rest, mlp, norm = "EncodeProcessDecode/encoder", parts[2:], "mlp_1", "layer_norm_1"
    elif parts[0] == "decoder":
        scope, rest, mlp, norm = "EncodeProcessDecode/decoder", parts[1:], "mlp", ""
    elif parts[:2] == ["processor", "blocks"] and int(parts[2]) < steps:
        block = "GraphNetBlock" + (f"_{parts[2]}" if parts[2] != "0" else "")
        if parts[3:6] == ["edge_fns", "mesh", "mlp"]:
            scope, rest = f"EncodeProcessDecode/{block}/mesh_edges_edge_fn", parts[6:]
        elif parts[3] == "node_fn":
            scope, rest = f"EncodeProcessDecode/{block}/node_fn", parts[4:]
        else:
            raise ValueError(name)
        mlp, norm = "mlp", "layer_norm"
    else:
        raise ValueError(name)
    index, kind = int(rest[0]), rest[1]
    if index % 2 == 0:  # Linear layers sit at 0, 2, 4 of make_mlp's Sequential (ReLUs between)
        return f"{scope}/{mlp}/linear_{index // 2}/{'w' if kind == 'weight' else 'b'}:0"
    if norm:
        return f"{scope}/{norm}/{'gamma' if kind == 'weight' else 'beta'}:0"
    raise ValueError(name)


def export_weights(model: torch.nn.Module, steps: int) -> dict[str, np.ndarray]:
    """`w:<tf variable>` -> value (Linear weights transposed to Sonnet's (in, out)); exits naming a tensor without a rule."""
    out = {}
    for name, p in model.named_parameters():
        try:
            key = "w:" + tf_name(name, steps)
        except ValueError:
            fail(f"{name}: no reference variable maps to this clods-bench tensor")
        value = p.detach().double().numpy()
        out[key] = value.T if value.ndim == 2 else value
    return out


def flag_frames(nx: int, ny: int, frames: int) -> Trajectory:
    """A flag swinging under gravity in still air (the benchmark's solver), float32 as stored data."""
    mesh = make_flag_mesh(nx, ny, length=1.0, height=0.5)
    solver = ClothSolver(mesh, SolverParams(air_density=0.0, damping_mass=0.5), 0.02)
    pos = solver.simulate(mesh.rest_pos, np.zeros_like(mesh.rest_pos), frames)
    return Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, pos.astype(np.float32), 0.02)


def part_a_inputs(tag: str, cells: np.ndarray, latent: int, steps: int, seed: int) -> tuple[dict, Any]:
    """Inputs and our float64 model for part A; returns (npz entries, (model, tensors))."""
    sim = build_mgn(MgnConfig(latent_size=latent, hidden_layers=2, message_passing_steps=steps), SimpleNamespace(scene=PINNED))
    model = sim.build_model(seed).double()
    s, r = mesh_edges(cells)
    n = int(cells.max()) + 1
    g = torch.Generator().manual_seed(seed)
    node = torch.randn(n, 12, generator=g, dtype=torch.float64)
    edge = torch.randn(len(s), 7, generator=g, dtype=torch.float64)
    probe = torch.randn(n, 3, generator=g, dtype=torch.float64)
    entries = {"a_node": node.numpy(), "a_edge": edge.numpy(), "a_senders": s.astype(np.int32), "a_receivers": r.astype(np.int32), "a_probe": probe.numpy()}
    entries.update({"latent": np.array(latent), "layers": np.array(2), "steps": np.array(steps)})
    entries.update(export_weights(model, steps))
    return entries, (model, node, edge, probe, torch.as_tensor(s), torch.as_tensor(r), tag)


def part_a_ours(model: Any, node: torch.Tensor, edge: torch.Tensor, probe: torch.Tensor, s: torch.Tensor, r: torch.Tensor) -> dict:
    x_in, e_in = node.clone().requires_grad_(True), edge.clone().requires_grad_(True)
    x = model.node_encoder(x_in)
    sets = {"mesh": EdgeSet(model.edge_encoders["mesh"](e_in), s, r)}
    n = x.shape[0]
    x = model.processor(x, ProcessorInputs(sets, torch.zeros(n, 3, dtype=torch.float64), torch.zeros(n, 2, dtype=torch.float64), "study"))
    out = model.decoder(x)
    params = dict(model.named_parameters())
    grads = torch.autograd.grad((out * probe).sum(), [x_in, e_in, *params.values()], allow_unused=True)
    return {"out": out.detach(), "node": grads[0], "edge": grads[1], "params": dict(zip(params, grads[2:]))}


def run_reference(ref: Path, tf_python: str, entries: dict) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(src, **entries)
        run = subprocess.run([tf_python, str(Path(__file__).with_name("mgn_reference_run.py")), str(ref), str(src), str(dst)], capture_output=True, text=True)
        if run.returncode != 0:
            fail(f"{tf_python}: the reference run failed: {(run.stdout + run.stderr).strip().splitlines()[-1]}")
        return dict(np.load(dst))


def grad_difference(ours: dict, theirs: dict, prefix: str, steps: int) -> tuple[float, str, float]:
    """(max |ours - theirs| over every parameter's gradient, its tensor, largest reference gradient)."""
    worst, scale = (0.0, ""), 0.0
    for name, g in ours.items():
        want = theirs[prefix + tf_name(name, steps)]
        want = want.T if want.ndim == 2 else want
        got = g.detach().double().numpy() if g is not None else np.zeros_like(want)
        worst = max(worst, (float(np.abs(got - want).max()), name))
        scale = max(scale, float(np.abs(want).max()))
    return worst[0], worst[1], scale


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", type=Path, help="a git checkout of github.com/google-deepmind/deepmind-research")
    parser.add_argument("--tf-python", required=True, help="a Python with tensorflow 1.15 and dm-sonnet 1.36")
    parser.add_argument("--out", type=Path, help="write the result file here (JSON)")
    args = parser.parse_args()
    check_checkout(args.reference, "meshgraphnets/core_model.py", REFERENCE, COMMIT)
    body: dict[str, Any] = {"A_network_float64": []}

    # --- B/C/D inputs: a simulated 16 x 8 flag, the ci widths -----------------------------------------------
    calls = 3
    traj = flag_frames(16, 8, calls + 2)
    sim = build_mgn(MgnConfig(latent_size=64, hidden_layers=2, message_passing_steps=4, noise_std=0.0, warmup_steps=0), SimpleNamespace(scene=PINNED))
    model = sim.build_model(0)
    cache = TopologyCache()
    data = TrainingData([traj], cache, 1)
    trainer = Trainer(model, sim.config, data, seed=0)
    key, topo = cache.get(traj.cells, traj.mesh_pos, traj.node_type)
    entries_b: dict[str, Any] = {"b_cells": traj.cells.astype(np.int32), "b_mesh_pos": traj.mesh_pos.astype(np.float32)}
    entries_b["b_node_type"] = traj.node_type.astype(np.int32)[:, None]
    entries_b["b_calls"] = np.array(calls)
    for k in range(calls):
        entries_b[f"b_prev_{k}"], entries_b[f"b_world_{k}"], entries_b[f"b_target_{k}"] = traj.world_pos[k], traj.world_pos[k + 1], traj.world_pos[k + 2]
    rng = np.random.default_rng(0)
    c = {"c_world": traj.world_pos[2], "c_prev": traj.world_pos[1], "c_target": traj.world_pos[3], "c_node_type": traj.node_type.astype(np.int32)[:, None]}
    entries_cd = {**c, "c_seed": np.array(int(rng.integers(1 << 30))), "c_noise": np.array(0.003), "c_gamma": np.array(0.1), "d_steps": np.array(LR_STEPS)}

    a_cases = [("flag 16x8 (ci), latent 64, 4 steps", make_flag_mesh(16, 8).cells, 64, 4), ("flag 1579 nodes, latent 128, 15 steps", make_flagsimple_mesh().cells, 128, 15)]
    for i, (tag, cells, latent, steps) in enumerate(a_cases):
        entries, (amodel, node, edge, probe, s, r, _) = part_a_inputs(tag, cells, latent, steps, seed=i)
        if i == 0:  # the first case's model is part B's (the same config and seed): one reference run does A to D
            entries.update({**entries_b, **entries_cd})
        theirs = run_reference(args.reference, args.tf_python, entries)
        ours = part_a_ours(amodel, node, edge, probe, s, r)
        g = grad_difference(ours["params"], theirs, "a_grad:", steps)
        row = {
            "case": tag, "parameters": sum(p.numel() for p in amodel.parameters()),
            "output_max_abs_diff": max_differences(ours["out"], torch.as_tensor(theirs["a_out"]))[0],
            "grad_features_max_abs_diff": max(max_differences(ours["node"], torch.as_tensor(theirs["a_grad_node"]))[0],
                                              max_differences(ours["edge"], torch.as_tensor(theirs["a_grad_edge"]))[0]),
            "grad_parameters_max_abs_diff": g[0], "grad_parameters_worst_tensor": g[1], "largest_reference_gradient": g[2],
        }  # fmt: skip
        body["A_network_float64"].append(row)
        print(f"A {tag}: output {row['output_max_abs_diff']:.2e}, gradients {max(row['grad_features_max_abs_diff'], g[0]):.2e}")
        if i == 0:
            body.update(parts_bcd(theirs, model, trainer, traj, topo, key, calls))
            print(json.dumps({k: body[k] for k in ("B_cloth_model_float32", "C_training_noise", "D_learning_rate")}, indent=1))
    worst = max(max(r["output_max_abs_diff"], r["grad_features_max_abs_diff"], r["grad_parameters_max_abs_diff"]) for r in body["A_network_float64"])
    body["A_max_abs_diff"] = worst
    print(f"A: max absolute difference, outputs and gradients, float64: {worst:.3e} (target 1e-10)")
    if args.out:
        command = f"PYTHONPATH=. python examples/studies/mgn_same_weights.py <deepmind-research checkout> --tf-python <py3.7 with TF 1.15> --out {args.out}"
        write_result(args.out, REFERENCE, COMMIT, command, body)
    if worst > 1e-10:
        raise SystemExit(1)


def parts_bcd(theirs: dict, model: Any, trainer: Trainer, traj: Trajectory, topo: Any, key: str, calls: int) -> dict:
    """Parts B (cloth model, float32), C (noise) and D (learning rate) against the reference run's results."""
    frames = torch.as_tensor(traj.world_pos)
    zero = torch.zeros(frames.shape[1:])
    losses = []
    for k in range(calls):
        batch = Batch(frames[k : k + 3], topo, key)
        model.zero_grad()
        loss = trainer.one_step_loss(batch, zero)
        if k == calls - 1:
            loss.backward()
        losses.append(float(loss.detach()))
    ref_losses = [float(theirs[f"b_loss_{k}"]) for k in range(calls)]
    g = grad_difference({n: p.grad for n, p in model.named_parameters()}, theirs, "b_grad:", 4)
    with torch.no_grad():
        cur, prev = frames[calls], frames[calls - 1]
        nxt = model.step(topo, key, cur, prev, torch.as_tensor(theirs["b_next"]))
    normal = torch.as_tensor(traj.node_type == NORMAL)
    next_diff = max_differences(nxt[normal], torch.as_tensor(theirs["b_next"])[normal])
    # C: the reference's noisy frame
    world, target = theirs["c_world"].astype(np.float64), theirs["c_target"].astype(np.float64)
    noise = world - traj.world_pos[2].astype(np.float64)
    free = traj.node_type == NORMAL
    shift = target - traj.world_pos[3].astype(np.float64)
    ours_target = trainer._target_acceleration(Batch(frames[1:4], topo, key), torch.as_tensor(noise, dtype=torch.float32)).double().numpy()
    ref_target = target - 2.0 * world + traj.world_pos[1].astype(np.float64)
    ours_lr = np.array([MgnConfig().learning_rate_at(s) for s in LR_STEPS])
    return {
        "B_cloth_model_float32": {
            "case": "flag 16x8 simulated under gravity, latent 64, 4 steps, 3 training calls (normalisers accumulating)",
            "losses_ours": losses, "losses_reference": ref_losses,
            "loss_max_rel_diff": max(abs(a - b) / abs(b) for a, b in zip(losses, ref_losses)),
            "grad_parameters_max_abs_diff": g[0], "grad_parameters_worst_tensor": g[1], "largest_reference_gradient": g[2],
            "next_positions_max_abs_diff": next_diff[0], "next_positions_max_rel_diff": next_diff[1],
        },
        "C_training_noise": {
            "noise_on_non_normal_nodes_max_abs": float(np.abs(noise[~free]).max()), "noise_std_normal_nodes": float(noise[free].std()),
            "target_shift_minus_0.9_noise_max_abs": float(np.abs(shift - 0.9 * noise).max()),
            "target_acceleration_max_abs_diff": float(np.abs(ours_target - ref_target).max()),
            "target_acceleration_max_abs": float(np.abs(ref_target).max()),
        },
        "D_learning_rate": {"steps": LR_STEPS, "ours": ours_lr.tolist(), "reference": theirs["d_lr"].tolist(),
                            "max_rel_diff": float(np.max(np.abs(ours_lr - theirs["d_lr"]) / theirs["d_lr"]))},
    }  # fmt: skip


if __name__ == "__main__":
    main()
