"""Is clods-bench's DHMP processor the authors' code? Same graphs, weights and Gumbel noise, float64: levels, outputs, gradients.

The reference is the authors' public code of DHMP, published as EvoMesh: github.com/hbell99/EvoMesh at commit
28a5d96d1e1fca86535219094a521ce9b6b5d4d5 (a git checkout, given as the argument; run with the Python packages its
`src/core_model.py` and `src/helpers_bistride.py` import: torch, torch_geometric, torch_scatter, sparse_dot_mkl,
scikit-learn). Its cloth (`Flag`) settings: `lagrangian`, `enhance`, no position pooling. On each study mesh:

- fixed levels: its `generate_multi_layer_stride` with the `MinAve` seeds its flag data uses, against
  `bistride.build_bistride(rule="min_average")`: kept nodes and coarse edges, as sets of mesh-node indices;
- processor: its `EvoMesh(l_n, pre_l_n, bottom_ln, ...)` and clods-bench's `DhmpProcessor` (training mode), every
  tensor copied one to one, each on its own fixed levels (the reference on a batch of one, shape (1, V, .), as its
  trainer calls it), the same temperature and the same Gumbel noise (the reference's global generator seeded
  as clods-bench seeds its own); two calls in a row; the learned levels' kept nodes, the outputs and the gradients
  of a random projection of them with respect to the latents, the world positions and every parameter.

The reference's rest positions are the 2-D mesh positions with a zero third coordinate (its flag data pads them);
the weights that read that coordinate are left out of the map, and their gradient is checked to be exactly zero.

    PYTHONPATH=. python examples/studies/dhmp_same_weights.py /path/to/EvoMesh --out results/studies/dhmp_same_weights/result.json
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
from clods_bench.plugins.simulators.learned.dhmp import DhmpProcessor
from clods_bench.plugins.simulators.learned.graph import EdgeSet
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.unet_configs import DhmpConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))
from same_weights_common import check_checkout, fail, max_differences, study_meshes, write_result  # noqa: E402

REFERENCE = "github.com/hbell99/EvoMesh"
COMMIT = "28a5d96d1e1fca86535219094a521ce9b6b5d4d5"
PAD_COLUMN = 2
"""Column of the reference's edge-MLP input holding the zero third rest coordinate (its fibre: rest difference (3),
world difference (3), the two norms, then the latents)."""
BATCH_NOTE = """The batch of two flags runs with learned levels only: clods-bench numbers a component's nodes from 0 where
the authors' code breaks ties in its top-up by the Python-set order of mesh-wide indices, so that a mesh in a
batch gets the fixed levels it gets alone (the authors batch copies of one mesh and never meet the case)."""
CONFIGS = [  # the ci preset's shape, the small preset's, the authors' default depth (on the FLAGSIMPLE-size mesh only)
    dict(levels=1, fixed=0, bottom=1, latent=64, hidden=2, meshes="all"),
    dict(levels=4, fixed=2, bottom=1, latent=32, hidden=2, meshes="all"),
    dict(levels=7, fixed=3, bottom=1, latent=32, hidden=2, meshes="FLAGSIMPLE"),
]


def import_reference(path: Path) -> tuple[Any, Any]:
    """(core_model, helpers_bistride) modules from the checkout's src/."""
    sys.path.insert(0, str(path / "src"))
    try:
        core = importlib.import_module("core_model")
        bistride = importlib.import_module("helpers_bistride")
    except ImportError as e:
        fail(f"{path / 'src'}: cannot import the reference's modules ({e}); install what its src/ imports")
    if Path(core.__file__).resolve().parent != (path / "src").resolve():
        fail(f"{core.__file__}: imported instead of {path / 'src' / 'core_model.py'}")
    return core, bistride


def reference_name(name: str, levels: int, fixed: int) -> str:
    """The reference's name of one of clods-bench's tensors (ValueError when there is no rule for it)."""
    m = re.fullmatch(r"(down|up|bottom)\.(\d+)\.(edge\.mlp|weight|node|score)\.(\d+)\.(weight|bias)", name)
    if m is None:
        raise ValueError(name)
    part, index, mlp, layer, kind = m.groups()
    i = int(index)
    block = {"down": f"down_gmps.{i}", "up": f"up_gmps.{levels - 1 - i}", "bottom": f"bottom_gmp.{i}"}[part]
    learned = part == "down" and i >= fixed  # EvoMesh's `amp`: its weight MLP is not wrapped in a Sequential
    sub = {"edge.mlp": "mlp_edge_info", "node": "mlp_node_delta", "score": "mlp_gumbel.0",
           "weight": "mlp_edge_weight" if learned else "mlp_edge_weight.0"}[mlp]  # fmt: skip
    return f"{block}.{sub}.seq.{layer}.{kind}"


def is_first_edge_layer(name: str) -> bool:
    return name.endswith("edge.mlp.0.weight")


def copy_weights(ref: torch.nn.Module, ours: torch.nn.Module, levels: int, fixed: int) -> dict[str, str]:
    """Copy every reference tensor into ours (the pad column left out); the map (ours -> reference)."""
    ref_state = ref.state_dict()
    mapping, used = {}, set()
    for name, tensor in ours.named_parameters():
        try:
            rname = reference_name(name, levels, fixed)
        except ValueError:
            fail(f"{name}: no reference tensor maps to this clods-bench tensor")
        source = ref_state.get(rname)
        if source is not None and is_first_edge_layer(name):
            source = torch.cat([source[:, :PAD_COLUMN], source[:, PAD_COLUMN + 1 :]], dim=1)
        if source is None or source.shape != tensor.shape:
            fail(f"{name}: reference tensor {rname} is {'missing' if source is None else tuple(source.shape)}, ours {tuple(tensor.shape)}")
        with torch.no_grad():
            tensor.copy_(source)
        mapping[name] = rname
        used.add(rname)
    left = sorted(set(ref_state) - used)
    if left:
        fail(f"{left[0]}: reference tensor not mapped to clods-bench ({len(left)} left)")
    return mapping


def compare_fixed_levels(helpers: Any, s: np.ndarray, r: np.ndarray, mesh_pos: np.ndarray, fixed: int) -> tuple[dict, list, list]:
    """Kept nodes and coarse edges of both builders as sets of mesh-node indices (exits at a difference); the
    reference's levels (kept index lists, edge lists) for its processor, and whether its lists came in ascending order."""
    n = len(mesh_pos)
    m_gs, m_ids = helpers.generate_multi_layer_stride(np.stack([s, r]), fixed, helpers.SeedingHeuristic.MinAve, n, pos_mesh=mesh_pos)
    ours = build_bistride(s, r, n, None, fixed, rule="min_average")
    ref_fine, our_fine, ascending = np.arange(n), np.arange(n), True
    for level in range(fixed):
        ids = np.asarray(m_ids[level], dtype=np.int64)
        ascending &= bool(np.all(np.diff(ids) > 0))
        ref_fine, our_fine = ref_fine[ids], our_fine[ours.kept[level].numpy()]
        if set(ref_fine.tolist()) != set(our_fine.tolist()):
            fail(f"fixed level {level + 1}: kept nodes differ from the reference's")
        e = np.asarray(m_gs[level + 1], dtype=np.int64)
        want = {(int(ref_fine[a]), int(ref_fine[b])) for a, b in e.T}
        got = {(int(our_fine[a]), int(our_fine[b])) for a, b in zip(ours.senders[level + 1], ours.receivers[level + 1])}
        if want != got or e.shape[1] != len(got):
            fail(f"fixed level {level + 1}: coarse edges differ from the reference's")
    row = {"fixed_nodes_per_level": ours.num_nodes, "fixed_levels_identical_as_sets": True, "reference_lists_ascending": ascending}
    if not ascending:
        fail("the reference's kept lists are not in ascending order: the two models would number coarse nodes differently")
    ids = [torch.as_tensor(np.asarray(i, dtype=np.int64)) for i in m_ids]
    return row, ids, [torch.as_tensor(np.asarray(g, dtype=np.int64)) for g in m_gs]


def compare_processor(core: Any, s: np.ndarray, r: np.ndarray, mesh_pos: np.ndarray, world: np.ndarray, cfg: dict, m_ids: list, m_gs: list) -> dict:
    """Two training calls of both processors with the same weights and noise, float64."""
    torch.manual_seed(0)
    ref = core.EvoMesh(cfg["levels"], cfg["fixed"], cfg["bottom"], cfg["latent"], cfg["hidden"], 3, True, True, False).double()
    config = DhmpConfig(latent_size=cfg["latent"], levels=cfg["levels"], fixed_levels=cfg["fixed"], bottom_blocks=cfg["bottom"], position_scale="raw")
    ours = DhmpProcessor(cfg["latent"], cfg["hidden"], ["mesh"], config).double().train()
    mapping = copy_weights(ref, ours, cfg["levels"], cfg["fixed"])
    recorded: list[torch.Tensor] = []
    pool_edge = ref.pool_edge

    def recording_pool_edge(g: torch.Tensor, idx: torch.Tensor, num_nodes: int) -> torch.Tensor:
        recorded.append(idx)
        return pool_edge(g, idx, num_nodes)

    ref.pool_edge = recording_pool_edge  # records each learned level's kept nodes; calls the reference's own
    n = len(mesh_pos)
    mp, wp = torch.as_tensor(mesh_pos), torch.as_tensor(world)  # rest positions float32 (as in the model), world float64
    inputs_edges = {"mesh": EdgeSet(torch.zeros(len(s), 1, dtype=torch.float64), torch.as_tensor(s), torch.as_tensor(r))}
    ref_params, our_params = dict(ref.named_parameters()), dict(ours.named_parameters())
    rows = []
    for call in range(2):
        g = torch.Generator().manual_seed(10 + call)
        nodes = torch.randn(n, cfg["latent"], generator=g, dtype=torch.float64)
        probe = torch.randn(n, cfg["latent"], generator=g, dtype=torch.float64)
        tau, seed = ours.temperature, (int(ours.noise_seed) << 20) + int(ours.calls)

        x, w = nodes.clone().requires_grad_(True), wp.clone().requires_grad_(True)
        pos = torch.cat([mp.double(), torch.zeros(n, 1, dtype=torch.float64), w], 1).unsqueeze(0)
        recorded.clear()
        torch.manual_seed(seed)
        ref_out = ref(x.unsqueeze(0), m_ids, m_gs, pos, tau)[0]
        ref_grads = torch.autograd.grad((ref_out * probe).sum(), [x, w, *ref_params.values()])
        ref_grad = dict(zip(ref_params, ref_grads[2:]))
        ref_kept = [k.clone() for k in recorded]

        x, w = nodes.clone().requires_grad_(True), wp.clone().requires_grad_(True)
        out = ours(x, ProcessorInputs(inputs_edges, w, mp, "study"))
        grads = torch.autograd.grad((out * probe).sum(), [x, w, *our_params.values()])
        pad = max((float(ref_grad[mapping[k]][:, PAD_COLUMN].abs().max()) for k in our_params if is_first_edge_layer(k)), default=0.0)
        worst = (0.0, "")
        for k, grad in zip(our_params, grads[2:]):
            want = ref_grad[mapping[k]]
            if is_first_edge_layer(k):
                want = torch.cat([want[:, :PAD_COLUMN], want[:, PAD_COLUMN + 1 :]], dim=1)
            worst = max(worst, (max_differences(grad, want)[0], mapping[k]))
        learned = ours.last_kept[cfg["fixed"] + 1 :]
        sizes_ref = [len(k) for k in ref_kept]
        same_nodes = len(ref_kept) == len(learned) and all(
            torch.equal(ours.last_kept[cfg["fixed"] + i][k], learned[i]) for i, k in enumerate(ref_kept)
        )
        if not same_nodes:
            fail(f"call {call + 1}: the learned levels keep other nodes (reference sizes {sizes_ref}, ours {[len(k) for k in learned]})")
        rows.append({
            "call": call + 1, "temperature": tau, "learned_nodes_per_level": sizes_ref, "learned_levels_identical": True,
            "output_max_abs_diff": max_differences(out, ref_out)[0], "output_max_rel_diff": max_differences(out, ref_out)[1],
            "grad_latents_max_abs_diff": max_differences(grads[0], ref_grads[0])[0],
            "grad_world_pos_max_abs_diff": max_differences(grads[1], ref_grads[1])[0],
            "grad_parameters_max_abs_diff": worst[0], "grad_parameters_worst_tensor": worst[1],
            "reference_pad_column_grad_max_abs": pad,
            "largest_reference_gradient": max(float(t.abs().max()) for t in ref_grads),
        })  # fmt: skip
    return {"config": cfg, "parameters": sum(p.numel() for p in ours.parameters()), "calls": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", type=Path, help="a git checkout of github.com/hbell99/EvoMesh")
    parser.add_argument("--out", type=Path, help="write the result file here (JSON)")
    args = parser.parse_args()
    check_checkout(args.reference, "src/core_model.py", REFERENCE, COMMIT)
    core, helpers = import_reference(args.reference)
    rows, worst = [], 0.0
    for name, s, r, mesh_pos, world in study_meshes():
        mesh_pos = mesh_pos.astype(np.float32)  # as the model holds rest positions (exact seed ties follow their rounding)
        for cfg in CONFIGS:
            if (cfg["meshes"] != "all" and cfg["meshes"] not in name) or (cfg["fixed"] and "batch" in name):
                continue  # a batch's fixed levels are each mesh's own (see BATCH_NOTE)
            levels, m_ids, m_gs = compare_fixed_levels(helpers, s, r, mesh_pos, cfg["fixed"])
            row = {"mesh": name, **levels, **compare_processor(core, s, r, mesh_pos, world, cfg, m_ids, m_gs)}
            rows.append(row)
            for call in row["calls"]:
                diffs = [v for k, v in call.items() if k.endswith("max_abs_diff")]
                worst = max(worst, *diffs, call["reference_pad_column_grad_max_abs"])
                print(f"{name:38s} levels {cfg['levels']} ({cfg['fixed']} fixed) call {call['call']}: "
                      f"fixed {row['fixed_nodes_per_level']} learned {call['learned_nodes_per_level']}  "
                      f"output {diffs[0]:.2e}  grads {max(diffs[1:]):.2e}")  # fmt: skip
    print(f"max absolute difference over all meshes, outputs and gradients: {worst:.3e} (target 1e-10)")
    if args.out:
        command = f"PYTHONPATH=. python examples/studies/dhmp_same_weights.py <EvoMesh checkout> --out {args.out}"
        write_result(args.out, REFERENCE, COMMIT, command, {"max_abs_diff": worst, "batch_note": BATCH_NOTE, "rows": rows})
    if worst > 1e-10:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
