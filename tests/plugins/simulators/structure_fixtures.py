"""A fixed float64 evaluation of a learned simulator's whole model at the ci widths, for structure-drift tests.

The model is built from a seed (torch's generator gives the same weights on every CPU), runs in float64 on the ci
flag mesh (16 x 8 nodes) at a fixed state after one accumulation of its normalisers, and is summarised by the sum
of its output times a fixed probe. Float64 results differ between x86 instruction sets by ~1e-15 relative, so a
tolerance of 1e-9 relative catches any change of the function and no change of CPU.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.plugins.simulators.learned.graph import build_topology

PINNED = SimpleNamespace(name="test-pinned", has_obstacles=False, has_handles=True)
CI_WIDTHS = dict(latent_size=64, hidden_layers=2)


def mlp_parameters(in_size: int, latent: int, hidden_layers: int, out_size: int, affine_norm: bool) -> int:
    """Weights and biases of `make_mlp`'s MLP, plus the LayerNorm's scale and offset when it has them."""
    sizes = [in_size] + [latent] * hidden_layers + [out_size]
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:])) + (2 * out_size if affine_norm else 0)


def shared_parameters(latent: int, hidden: int, encoded_edges: bool) -> int:
    """The shared encoder/decoder: node encoder (3 + 9 -> latent), mesh edge encoder (7 -> latent) when used, decoder."""
    enc = mlp_parameters(12, latent, hidden, latent, True) + (mlp_parameters(7, latent, hidden, latent, True) if encoded_edges else 0)
    return enc + mlp_parameters(latent, latent, hidden, 3, False)


def fixed_evaluation(simulator: object, seed: int = 0) -> tuple[int, float]:
    """(parameter count, sum(output * probe)) of `simulator.build_model(seed)` in float64 on the ci flag."""
    mesh = make_flag_mesh(16, 8)
    topo = build_topology(mesh.cells, mesh.mesh_pos, mesh.node_type)
    model = simulator.build_model(seed).double().eval()  # type: ignore[attr-defined]
    mp = torch.as_tensor(mesh.mesh_pos, dtype=torch.float64)
    pos = torch.stack([mp[:, 0], 0.1 * torch.sin(3.0 * mp[:, 0] + 2.0 * mp[:, 1]), mp[:, 1] - 0.05 * mp[:, 0] ** 2], 1)
    prev = pos - 0.01 * torch.stack([torch.cos(mp[:, 1]), mp[:, 0] * mp[:, 1], 0.5 * mp[:, 0]], 1)
    out = model(topo, "ci-flag", pos, prev, accumulate=True)
    probe = torch.linspace(-1.0, 1.0, out.numel(), dtype=torch.float64).reshape(out.shape)
    count = sum(p.numel() for p in model.parameters())
    return count, float((out * probe).sum().detach())


def assert_close(value: float, committed: float, rtol: float = 1e-9) -> None:
    """Relative comparison against a committed value (see the module docstring for the tolerance)."""
    assert np.isfinite(value) and abs(value - committed) <= rtol * abs(committed), (value, committed)
