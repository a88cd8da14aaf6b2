"""Is clods-bench's BSMS processor the authors' BSMS-GNN? Same graphs, same weights, float64: hierarchy, outputs, gradients.

The reference is the authors' code, github.com/Eydcao/BSMS-GNN at commit accc09213cf94cdd56c416d4a047e4f6cda3b0a3
(a git checkout, given as the argument; run with Python packages its `src` imports need: torch, torch_geometric,
sparse_dot_mkl, matplotlib, pytz, pillow, wandb, tabulate). On each study mesh:

- hierarchy: its `BistrideMultiLayerGraph` (seeds, bi-stride selection, 2-hop coarse edges) against
  `bistride.build_bistride`: kept nodes element by element, coarse edges as sets (it lists a row's columns in the
  order its sparse product leaves them; the order changes only the order of a sum);
- processor: its `BSGMP(unet_depth, latent, hidden_layer, pos_dim=5)` and clods-bench's `BsmsProcessor` with every
  tensor of the reference copied one to one, each on its own levels, on the same node latents, rest+world positions (V, 2+3) and levels;
  the outputs and the gradients of a random projection of them with respect to the latents, the world positions
  and every parameter.

    PYTHONPATH=. python examples/studies/bsms_same_weights.py /path/to/BSMS-GNN --out results/studies/bsms_same_weights/result.json
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from clods_bench.plugins.simulators.learned.bistride import build_bistride
from clods_bench.plugins.simulators.learned.bsms import BsmsProcessor
from clods_bench.plugins.simulators.learned.graph import EdgeSet
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))
from same_weights_common import check_checkout, fail, max_differences, study_meshes, write_result  # noqa: E402

REFERENCE = "github.com/Eydcao/BSMS-GNN"
COMMIT = "accc09213cf94cdd56c416d4a047e4f6cda3b0a3"
CONFIGS = [dict(levels=3, latent=64, hidden=2), dict(levels=6, latent=32, hidden=3)]  # the ci preset's shape; the default depth
"""The default depth is cut to the deepest level that still has edges: the reference's `degree` takes the node count
from the largest sender index, so it fails on a level without edges (a mesh already pooled to one node)."""


def usable_levels(s: np.ndarray, r: np.ndarray, mesh_pos: np.ndarray, wanted: int) -> int:
    """The largest L <= wanted whose levels 0..L all have edges."""
    h = build_bistride(s, r, len(mesh_pos), mesh_pos, wanted)
    return next((level - 1 for level in range(wanted + 1) if len(h.senders[level]) == 0), wanted)


def import_reference(path: Path) -> tuple[Any, Any]:
    """(BSGMP class, BistrideMultiLayerGraph class) from the checkout's src/."""
    sys.path.insert(0, str(path / "src"))
    try:
        ops = importlib.import_module("ops")
        wrappers = importlib.import_module("graph_wrappers")
    except ImportError as e:
        fail(f"{path / 'src'}: cannot import the reference's modules ({e}); install what its src/ imports")
    if Path(ops.__file__).resolve().parent != (path / "src" / "ops").resolve():
        fail(f"{ops.__file__}: imported instead of {path / 'src' / 'ops'}")
    return ops.BSGMP, wrappers.BistrideMultiLayerGraph


def reference_name(name: str, levels: int) -> str:
    """The reference's name of one of clods-bench's tensors (ValueError when there is no rule for it)."""
    m = re.fullmatch(r"(down|up)\.(\d+)\.(edge\.mlp|node)\.(\d+)\.(weight|bias)", name) or re.fullmatch(
        r"(bottom)\.()(edge\.mlp|node)\.(\d+)\.(weight|bias)", name
    )
    if m is None:
        raise ValueError(name)
    part, level, mlp, layer, kind = m.groups()
    block = {"down": f"down_gmps.{level}", "up": f"up_gmps.{levels - 1 - int(level or 0)}", "bottom": "bottom_gmp"}[part]
    return f"{block}.{'mlp_edge' if mlp == 'edge.mlp' else 'mlp_node'}.seq.{layer}.{kind}"


def copy_weights(ref: torch.nn.Module, ours: torch.nn.Module, levels: int) -> dict[str, str]:
    """Copy every reference tensor into ours; the map (ours -> reference). Exits naming a tensor that does not map."""
    ref_state = ref.state_dict()
    mapping, used = {}, set()
    for name, tensor in ours.state_dict().items():
        try:
            rname = reference_name(name, levels)
        except ValueError:
            fail(f"{name}: no reference tensor maps to this clods-bench tensor")
        if rname not in ref_state or ref_state[rname].shape != tensor.shape:
            fail(f"{name}: reference tensor {rname} is {tuple(ref_state[rname].shape) if rname in ref_state else 'missing'}, ours {tuple(tensor.shape)}")
        with torch.no_grad():
            tensor.copy_(ref_state[rname])
        mapping[name] = rname
        used.add(rname)
    left = sorted(set(ref_state) - used)
    if left:
        fail(f"{left[0]}: reference tensor not mapped to clods-bench ({len(left)} left)")
    return mapping


def compare_hierarchy(graph_cls: Any, s: np.ndarray, r: np.ndarray, mesh_pos: np.ndarray, levels: int) -> tuple[dict[str, Any], list, list]:
    """Kept nodes (element by element) and coarse edges (as sets: the reference lists a row's columns in the order
    its sparse product leaves them) of both builders, exiting at the first difference; also the reference's
    levels (kept indices, edge lists), which its processor then runs on."""
    ref = graph_cls(np.stack([s, r]), levels, len(mesh_pos), mesh_pos)
    _, ref_edges, ref_ids = ref.get_multi_layer_graphs()
    ours = build_bistride(s, r, len(mesh_pos), mesh_pos, levels)
    for level in range(levels):
        if not np.array_equal(np.asarray(ref_ids[level]), ours.kept[level].numpy()):
            fail(f"level {level + 1}: kept nodes differ from the reference's")
        want = np.asarray(ref_edges[level + 1], dtype=np.int64)
        got = {(int(a), int(b)) for a, b in zip(ours.senders[level + 1], ours.receivers[level + 1])}
        if {(int(a), int(b)) for a, b in want.T} != got or want.shape[1] != len(got):
            fail(f"level {level + 1}: coarse edges differ from the reference's")
    row = {"nodes_per_level": ours.num_nodes, "edges_per_level": [len(x) for x in ours.senders], "kept_and_edge_sets_identical": True}
    ids = [torch.as_tensor(np.asarray(i, dtype=np.int64)) for i in ref_ids]
    return row, ids, [torch.as_tensor(np.asarray(e, dtype=np.int64)) for e in ref_edges]


def compare_processor(
    bsgmp: Any, s: np.ndarray, r: np.ndarray, mesh_pos: np.ndarray, world: np.ndarray, cfg: dict, m_ids: list, m_gs: list
) -> dict[str, Any]:
    """Outputs and gradients of the two processors with the same weights, float64; the reference on its own levels."""
    torch.manual_seed(0)
    ref = bsgmp(cfg["levels"], cfg["latent"], cfg["hidden"], 5).double()
    ours = BsmsProcessor(cfg["latent"], cfg["hidden"], ["mesh"], BsmsConfig(latent_size=cfg["latent"], levels=cfg["levels"], position_scale="raw", fibre_norms="joint")).double()
    mapping = copy_weights(ref, ours, cfg["levels"])
    g = torch.Generator().manual_seed(1)
    n = len(mesh_pos)
    nodes = torch.randn(n, cfg["latent"], generator=g, dtype=torch.float64)
    probe = torch.randn(n, cfg["latent"], generator=g, dtype=torch.float64)
    mp, wp = torch.as_tensor(mesh_pos), torch.as_tensor(world)  # rest positions float32 (as in the model), world float64
    st, rt = torch.as_tensor(s), torch.as_tensor(r)
    ref_params = dict(ref.named_parameters())
    our_params = dict(ours.named_parameters())

    x, w = nodes.clone().requires_grad_(True), wp.clone().requires_grad_(True)
    ref_out = ref(x, m_ids, m_gs, torch.cat([mp.double(), w], 1))
    ref_grads = torch.autograd.grad((ref_out * probe).sum(), [x, w, *ref_params.values()])
    ref_grad = dict(zip(ref_params, ref_grads[2:]))

    x, w = nodes.clone().requires_grad_(True), wp.clone().requires_grad_(True)
    inputs = ProcessorInputs({"mesh": EdgeSet(torch.zeros(len(s), 1, dtype=torch.float64), st, rt)}, w, mp, "study")
    out = ours(x, inputs)
    grads = torch.autograd.grad((out * probe).sum(), [x, w, *our_params.values()])
    our_grad = {mapping[k]: v for k, v in zip(our_params, grads[2:])}
    worst = max((max_differences(our_grad[k], ref_grad[k])[0], k) for k in ref_grad)
    return {
        "config": cfg,
        "parameters": sum(p.numel() for p in ours.parameters()),
        "output_max_abs_diff": max_differences(out, ref_out)[0],
        "output_max_rel_diff": max_differences(out, ref_out)[1],
        "grad_latents_max_abs_diff": max_differences(grads[0], ref_grads[0])[0],
        "grad_world_pos_max_abs_diff": max_differences(grads[1], ref_grads[1])[0],
        "grad_parameters_max_abs_diff": worst[0],
        "grad_parameters_worst_tensor": worst[1],
        "output_max_abs": float(ref_out.detach().abs().max()),
        "largest_reference_gradient": max(float(g.abs().max()) for g in ref_grads),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", type=Path, help="a git checkout of github.com/Eydcao/BSMS-GNN")
    parser.add_argument("--out", type=Path, help="write the result file here (JSON)")
    args = parser.parse_args()
    check_checkout(args.reference, "src/ops/BSMS.py", REFERENCE, COMMIT)
    bsgmp, graph_cls = import_reference(args.reference)
    rows, worst = [], 0.0
    for name, s, r, mesh_pos, world in study_meshes():
        mesh_pos = mesh_pos.astype(np.float32)  # as the model holds rest positions (exact seed ties follow their rounding)
        for wanted in CONFIGS:
            cfg = {**wanted, "levels": usable_levels(s, r, mesh_pos, wanted["levels"])}
            levels, m_ids, m_gs = compare_hierarchy(graph_cls, s, r, mesh_pos, cfg["levels"])
            row = {"mesh": name, **levels, **compare_processor(bsgmp, s, r, mesh_pos, world, cfg, m_ids, m_gs)}
            rows.append(row)
            diffs = [row[k] for k in row if k.endswith("max_abs_diff")]
            worst = max(worst, *diffs)
            print(f"{name:38s} levels {cfg['levels']}: nodes {row['nodes_per_level']}  output {row['output_max_abs_diff']:.2e}  "
                  f"grads {max(diffs[1:]):.2e}")  # fmt: skip
    print(f"max absolute difference over all meshes, outputs and gradients: {worst:.3e} (target 1e-10)")
    if args.out:
        command = f"PYTHONPATH=. python examples/studies/bsms_same_weights.py <BSMS-GNN checkout> --out {args.out}"
        write_result(args.out, REFERENCE, COMMIT, command, {"max_abs_diff": worst, "rows": rows})
    if worst > 1e-10:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
