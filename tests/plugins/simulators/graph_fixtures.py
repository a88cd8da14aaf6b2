"""Small meshes and processor inputs shared by the hierarchy / BSMS / HCMT tests."""

from __future__ import annotations

import numpy as np
import torch

from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.plugins.simulators.learned.processor import ProcessorInputs
from clods_bench.plugins.simulators.learned.graph import EdgeSet, mesh_edges


def jittered_mesh(nx: int, ny: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(senders, receivers, mesh_pos) of an nx x ny flag whose rest positions are jittered (no symmetric ties)."""
    mesh = make_flag_mesh(nx, ny)
    rng = np.random.default_rng(seed)
    pos = mesh.mesh_pos.astype(np.float64) + rng.uniform(-0.02, 0.02, mesh.mesh_pos.shape)
    s, r = mesh_edges(mesh.cells)
    return s, r, pos


def make_inputs(
    s: np.ndarray, r: np.ndarray, mesh_pos: np.ndarray, latent: int, seed: int, key: str,
    world: tuple[np.ndarray, np.ndarray] | None = None, dtype: torch.dtype = torch.float32,
) -> tuple[torch.Tensor, ProcessorInputs]:
    """Random node latents and encoded edge latents for a graph, as a processor would see them."""
    g = torch.Generator().manual_seed(seed)
    n = mesh_pos.shape[0]
    mp = torch.as_tensor(mesh_pos, dtype=dtype)
    pos = torch.cat([mp[:, :1], 0.1 * torch.randn(n, 1, generator=g, dtype=dtype), mp[:, 1:]], dim=1)
    sets = {"mesh": EdgeSet(torch.randn(len(s), latent, generator=g, dtype=dtype), torch.as_tensor(s), torch.as_tensor(r))}
    if world is not None:
        ws, wr = world
        sets["world"] = EdgeSet(torch.randn(len(ws), latent, generator=g, dtype=dtype), torch.as_tensor(ws), torch.as_tensor(wr))
    nodes = torch.randn(n, latent, generator=g, dtype=dtype)
    return nodes, ProcessorInputs(sets, pos, mp, key)


def permute_inputs(nodes: torch.Tensor, inputs: ProcessorInputs, perm: torch.Tensor, key: str) -> tuple[torch.Tensor, ProcessorInputs]:
    """The same graph with node i of the result being node perm[i] of the input (edges relabelled)."""
    inv = torch.empty_like(perm)
    inv[perm] = torch.arange(len(perm))
    sets = {k: EdgeSet(es.features, inv[es.senders], inv[es.receivers]) for k, es in inputs.edge_sets.items()}
    return nodes[perm], ProcessorInputs(sets, inputs.pos[perm], inputs.mesh_pos[perm], key)


def union_inputs(a: tuple[torch.Tensor, ProcessorInputs], b: tuple[torch.Tensor, ProcessorInputs], key: str) -> tuple[torch.Tensor, ProcessorInputs]:
    """Disjoint union of two graphs (b's node indices offset by a's node count), as a batch."""
    (na, ia), (nb, ib) = a, b
    off = na.shape[0]
    sets = {
        k: EdgeSet(
            torch.cat([ia.edge_sets[k].features, ib.edge_sets[k].features]),
            torch.cat([ia.edge_sets[k].senders, ib.edge_sets[k].senders + off]),
            torch.cat([ia.edge_sets[k].receivers, ib.edge_sets[k].receivers + off]),
        )
        for k in ia.edge_sets
    }
    return torch.cat([na, nb]), ProcessorInputs(sets, torch.cat([ia.pos, ib.pos]), torch.cat([ia.mesh_pos, ib.mesh_pos]), key)
