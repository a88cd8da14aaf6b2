"""Is clods-bench's HCMT the authors' HCMT? Same weights, same inputs, float64: outputs, loss and gradients.

The reference is the authors' code, github.com/yuyudeep/hcmt at commit 41fd785893acbe797a733231b360709c0f2583cd
(a git checkout, given as the argument), run by `hcmt_reference_run.py` under a Python with its stack (TensorFlow
2.8, dm-sonnet 2.0.1: `--reference-python`). Its `HCMT` (encoders, 2 contact blocks, 6 levels, decoder; latent 128,
4 heads, 2 hidden layers, all fixed in its code) gets every parameter of clods-bench's `hcmt` model one to one, the
normaliser statistics, and the same levels (`m_ids`: all nodes, then the kept nodes of each level; `m_gs_*`: each
level's edges, the mesh edges first). Checked on a flag without obstacles (the reference gets an empty contact
edge set) and on a flag with an obstacle near its free nodes (contact edges both ways):

- eval: the decoder output from the raw node features (velocity and node-type one-hot, computed here) and positions;
- train: the same with the normalisers accumulating (every level's edges feed the mesh-edge normaliser, as in the
  code), and the gradient of every parameter of mean_nodes |target - output|^2 with a fixed random target.

clods-bench's normaliser rounds its statistics to float32 (its models run in float32); here they are read in
float64 so that both sides normalise alike. Mesh positions are multiples of 1/8 (exact in float32). The attention's
P weights are drawn 4x larger than at initialisation so that some scores pass the clip at +-2 (the table gives
the share): at initialisation none does, and the clip would go unchecked.

    python examples/studies/hcmt_same_weights.py /path/to/hcmt --reference-python /path/to/tf-venv/bin/python \
        --out results/studies/hcmt_same_weights/differences.txt
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.types import HANDLE, NODE_TYPE_SIZE, NORMAL, OBSTACLE
from clods_bench.plugins.simulators.learned.graph import Topology, build_topology, world_edges
from clods_bench.plugins.simulators.learned.hcmt import SCORE_CLIP, EdgeAttention, build_hcmt
from clods_bench.plugins.simulators.learned.normalizer import Normalizer
from clods_bench.plugins.simulators.learned.unet_configs import HcmtConfig

REFERENCE = "github.com/yuyudeep/hcmt"
COMMIT = "41fd785893acbe797a733231b360709c0f2583cd"
RUNNER = Path(__file__).with_name("hcmt_reference_run.py")
RADIUS = 0.1  # contact radius (m) of the obstacle scene
PROJ_GAIN = 4.0  # the attention's P weights are drawn this much larger than at initialisation, so that scores reach the clip


def count_clipped(model: torch.nn.Module, run: object) -> float:
    """Fraction of attention scores (all blocks, edges and channels) beyond the clip while `run()` runs."""
    counts = [0, 0]
    original = EdgeAttention.propagate

    def spy(self: EdgeAttention, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, edges: object) -> torch.Tensor:
        score = self.proj(edges.features) * k.index_select(0, edges.senders) * q.index_select(0, edges.receivers) / self.scale
        counts[0] += int((score.abs() > SCORE_CLIP).sum())
        counts[1] += score.numel()
        return original(self, q, k, v, edges)

    EdgeAttention.propagate = spy
    try:
        run()
    finally:
        EdgeAttention.propagate = original
    return counts[0] / max(counts[1], 1)


def fail(message: str) -> None:
    print(message)
    raise SystemExit(1)


def check_checkout(path: Path) -> None:
    """One clear line and exit unless `path` is a git checkout of the reference at COMMIT."""
    if not (path / "core_model.py").is_file():
        fail(f"{path}: no core_model.py here; expected a checkout of {REFERENCE}")
    head = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        fail(f"{path}: not a git checkout ({head.stderr.strip()}); expected {REFERENCE} at {COMMIT}")
    if head.stdout.strip() != COMMIT:
        fail(f"{path}: checkout is at {head.stdout.strip()}, this study knows {REFERENCE} at {COMMIT}")


def scene(obstacle: bool, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(cells, mesh_pos, node_type, pos, prev) of a 12 x 7 flag bent out of plane, with a 4-node obstacle if asked."""
    mesh = make_flag_mesh(12, 7, length=11 / 8, height=6 / 8)
    rng = np.random.default_rng(seed)
    cells, mesh_pos, node_type = mesh.cells, mesh.mesh_pos, mesh.node_type.copy()
    pos = mesh.rest_pos + rng.normal(0.0, 0.03, mesh.rest_pos.shape)
    if obstacle:  # a square of 2 triangles 5 cm in front of nodes in the middle of the flag, far from the pole
        centre = np.array([0.9, 0.05, 0.4])
        square = centre + np.array([[-0.1, 0, -0.1], [0.1, 0, -0.1], [0.1, 0, 0.1], [-0.1, 0, 0.1]])
        n = len(node_type)
        cells = np.concatenate([cells, n + np.array([[0, 1, 2], [0, 2, 3]])])
        mesh_pos = np.concatenate([mesh_pos, np.full((4, 2), 2.0)])  # obstacle nodes share one rest position, as in the data
        node_type = np.concatenate([node_type, np.full(4, OBSTACLE, node_type.dtype)])
        pos = np.concatenate([pos, square])
    prev = pos - rng.normal(0.0, 0.01, pos.shape) * (node_type == NORMAL)[:, None]
    return cells, mesh_pos, node_type, pos, prev


def float64_topology(topo: Topology) -> Topology:
    """The topology with its float tensors in float64 (the mesh features recomputed from float64 positions)."""
    mp = topo.mesh_pos.double()
    rel = mp[topo.senders] - mp[topo.receivers]
    return dataclasses.replace(
        topo, mesh_pos=mp, mesh_rel=torch.cat([rel, torch.linalg.vector_norm(rel, dim=1, keepdim=True)], 1),
        node_type_onehot=topo.node_type_onehot.double(), rest_spacing=topo.rest_spacing.double(),
    )  # fmt: skip


def run_case(obstacle: bool, checkout: Path, python: str, seed: int = 0) -> dict[str, float]:
    """Export the model and inputs, run both sides, return the largest differences by quantity."""
    Normalizer.mean = property(lambda self: self.acc_sum / self.acc_count.clamp(min=1.0))  # float64 statistics
    Normalizer.std = property(lambda self: torch.sqrt((self.acc_sum_squared / self.acc_count.clamp(min=1.0) - self.mean**2).clamp(min=0.0)).clamp(min=self.std_epsilon))
    cells, mesh_pos, node_type, pos_np, prev_np = scene(obstacle, seed)
    ctx = SimpleNamespace(scene=SimpleNamespace(name="study", has_obstacles=obstacle, has_handles=True))
    sim = build_hcmt(HcmtConfig(world_radius=RADIUS), ctx)
    model = sim.build_model(seed).double()
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, EdgeAttention):
                m.proj.weight.mul_(PROJ_GAIN)
    topo = float64_topology(build_topology(cells, mesh_pos, node_type))
    pos, prev = torch.as_tensor(pos_np), torch.as_tensor(prev_np)
    rng = np.random.default_rng(seed + 1)
    with torch.no_grad():  # realistic normaliser statistics: a few accumulating calls on jittered states
        for _ in range(3):
            jitter = torch.as_tensor(rng.normal(0.0, 0.02, pos_np.shape))
            model(topo, "study", pos + jitter, prev, accumulate=True)
    ws, wr = world_edges(topo, pos, RADIUS) if obstacle else (torch.zeros(0, dtype=torch.int64),) * 2
    if obstacle and (ws.numel() == 0 or np.isin(node_type[wr.numpy()], [HANDLE]).any()):
        fail("the obstacle scene must have contact edges, none with a handle (the code links obstacles to NORMAL nodes)")
    h = model.processor.hierarchies.get("study", topo.senders, topo.receivers, topo.mesh_pos)
    onehot = np.eye(NODE_TYPE_SIZE)[node_type]
    target = rng.normal(0.0, 1.0, (len(node_type), 3))
    norms = {"node": model.node_normalizer, **{k: v for k, v in model.edge_normalizers.items()}}
    data: dict[str, np.ndarray] = {
        "levels": np.array(h.levels), "contact": np.array(obstacle), "raw_nodes": np.concatenate([pos_np - prev_np, onehot], 1),
        "world_pos": pos_np, "mesh_pos": topo.mesh_pos.numpy(), "target": target,
        "m_senders": topo.senders.numpy().astype(np.int32), "m_receivers": topo.receivers.numpy().astype(np.int32),
        "c_senders": ws.numpy().astype(np.int32), "c_receivers": wr.numpy().astype(np.int32),
    }  # fmt: skip
    ids = [np.arange(len(node_type))] + [k.numpy() for k in h.kept]
    for i in range(h.levels + 1):
        data[f"m_ids_{i}"] = ids[i].astype(np.int32)
        data[f"m_gs_s_{i}"], data[f"m_gs_r_{i}"] = h.senders[i].numpy().astype(np.int32), h.receivers[i].numpy().astype(np.int32)
    data.update({f"param.{k}": v.detach().numpy() for k, v in model.named_parameters()})
    saved = {k: {b: getattr(n, b).clone() for b in ("acc_count", "num_accumulations", "acc_sum", "acc_sum_squared")} for k, n in norms.items()}
    data.update({f"norm.{k}.{b}": v.numpy() for k, d in saved.items() for b, v in d.items()})

    ours: dict[str, np.ndarray] = {}
    with torch.no_grad():
        clipped = count_clipped(model, lambda: model(topo, "study", pos, prev, accumulate=False))
    for mode in ("eval", "train"):
        for k, n in norms.items():
            for b, v in saved[k].items():
                getattr(n, b).copy_(v)
        model.zero_grad(set_to_none=True)
        out = model(topo, "study", pos, prev, accumulate=mode == "train")
        loss = ((torch.as_tensor(target) - out) ** 2).sum(-1).mean()
        loss.backward()
        ours[f"{mode}.output"], ours[f"{mode}.loss"] = out.detach().numpy(), loss.detach().numpy()
        ours.update({f"{mode}.grad.{k}": p.grad.numpy() for k, p in model.named_parameters()})
        ours.update({f"{mode}.norm.{k}.acc_sum": n.acc_sum.numpy().copy() for k, n in norms.items()})
        ours.update({f"{mode}.norm.{k}.acc_count": n.acc_count.numpy().copy() for k, n in norms.items()})

    with tempfile.TemporaryDirectory() as tmp:
        np.savez(Path(tmp) / "in.npz", **data)
        run = subprocess.run([python, str(RUNNER), str(checkout), str(Path(tmp) / "in.npz"), str(Path(tmp) / "out.npz")], capture_output=True, text=True)
        if run.returncode != 0:
            fail(f"reference run failed: {(run.stdout + run.stderr).strip().splitlines()[-1]}")
        ref = dict(np.load(Path(tmp) / "out.npz"))
    result: dict[str, float] = {}
    for key, value in ref.items():
        if key not in ours:
            fail(f"reference quantity {key} has no clods-bench counterpart")
        scale = max(float(np.abs(value).max(initial=0.0)), 1e-300)
        group = key.split(".grad.")[0] + ".grad" if ".grad." in key else key
        rel = float(np.abs(ours[key] - value).max(initial=0.0)) / scale
        result[group] = max(result.get(group, 0.0), rel)
    result["parameters"] = float(sum(p.numel() for p in model.parameters()))
    result["clipped"] = clipped
    result["gradients compared"] = float(sum(1 for k in ref if ".grad." in k) // 2)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkout", type=Path, help=f"a git checkout of {REFERENCE} at {COMMIT}")
    parser.add_argument("--reference-python", required=True, help="a Python with tensorflow 2.8 and dm-sonnet 2.0.1")
    parser.add_argument("--out", type=Path, help="also write the table here")
    args = parser.parse_args()
    check_checkout(args.checkout)
    lines = [f"reference: {REFERENCE} @ {COMMIT}", "max |clods-bench - reference| / max |reference|, float64", ""]
    worst = 0.0
    for obstacle in (False, True):
        res = run_case(obstacle, args.checkout, args.reference_python)
        lines.append(f"flag {'with an obstacle (contact edges)' if obstacle else 'without obstacles'}: "
                     f"{int(res.pop('parameters'))} parameters, {int(res.pop('gradients compared'))} parameter gradients, "
                     f"{100 * res.pop('clipped'):.1f} % of attention scores clipped")  # fmt: skip
        for key, value in sorted(res.items()):
            lines.append(f"  {key:<28} {value:.3e}")
            worst = max(worst, value)
    lines += ["", f"worst: {worst:.3e} ({'within' if worst <= 1e-10 else 'OUTSIDE'} 1e-10)"]
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    sys.exit(0 if worst <= 1e-10 else 1)


if __name__ == "__main__":
    main()
