"""LIP-style particle simulator: GNS encode-process-decode over a radius graph, with no mesh topology.

LIP (Zhu et al., latent intuitive physics) represents the cloth as a point cloud and simulates it with a
particle model; the CloDS paper adapts it to CDG and finds that without mesh topology the cloth shape collapses.
This model keeps that property (particles, no mesh edge) in the shared learned-simulator frame: node features are
the last velocity and the one-hot node type, edges are rebuilt at every step from the current world positions
(pairs closer than `radius_factor` times the rest spacing, at most `max_neighbours` per node) with the relative
position over the radius and its norm as features, all normalised online; `message_passing_steps` residual
GraphNetBlocks (the interaction networks of GNS) then a decoder give the acceleration, handle nodes follow their
prescribed positions. The trajectories' cells are used ONLY to satisfy the shared interfaces (topology cache
keys, checkpoint mesh digests, the unused mesh-edge tensors of `Topology`); they never become graph edges and
no mesh-space feature reaches the network. The rest positions (`mesh_pos`) set one number per mesh: the
length unit of the radius.

It is not the authors' network. LIP's code (github.com/xherdan76/LIP at 2f08a708f19d690ef22df2c6899d277e5dcf58b5,
`models/transmodel.py`, `models/encoder.py`, `trainer/trainer_e2e_lip.py`) simulates with continuous convolutions
(Ummenhofer et al. 2020, open3d's `ContinuousConv`: 4x4x4 kernels, ball-to-cube volume-preserving mapping, poly6
window, layers of 32, 64, 64 and 3 channels with dense bypasses), integrates gravity explicitly and adds a learned
position correction, and conditions every particle on a latent drawn from a GRU prior over a continuous-convolution
encoder, fitted to a latent inferred through a neural renderer. Here: message passing over a radius graph, an
acceleration output, no latent.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from clods_bench.benchmark.core.interfaces import FitContext, RolloutInput
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.graph import GraphSpec, Topology
from clods_bench.plugins.simulators.learned.lip_config import LipConfig
from clods_bench.plugins.simulators.learned.mgn import MgnProcessor
from clods_bench.plugins.simulators.learned.radius_graph import radius_edges
from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator

WHERE = "sim_config.lip.radius_factor"


def lip_spec(config: LipConfig) -> GraphSpec:
    """The particle graph of `config`: one radius edge set, no mesh or world edges."""
    return GraphSpec(radius_factor=float(config.radius_factor), max_neighbours=config.max_neighbours)


def check_connected(topo: Topology, pos: np.ndarray, spec: GraphSpec, where: str) -> None:
    """Raise ClodsError naming the radius factor when no node of `pos` (V,3) has a neighbour within the radius:
    such a particle graph has no edges, and every node would fall as if alone."""
    if spec.radius_factor is None:
        raise ClodsError("the graph spec has no radius (a mesh graph)", where="lip check_connected", hint="use lip_spec(config)")
    radius = spec.radius_factor * topo.rest_spacing
    x = torch.as_tensor(np.asarray(pos, dtype=np.float32), device=topo.rest_spacing.device)
    senders, _ = radius_edges(x, topo.sample, radius, spec.max_neighbours)
    if senders.numel() == 0:
        d = torch.cdist(x, x).fill_diagonal_(float("inf")).min(dim=1).values
        raise ClodsError(
            f"no node has a neighbour within the radius {float(radius.max()):.4g} m "
            f"(= {spec.radius_factor} x rest spacing {float(topo.rest_spacing.max()):.4g} m; nearest pair at {float(d.min()):.4g} m) "
            f"in {where}",
            where=WHERE,
            hint="raise it: the particle graph must connect neighbouring nodes (about 1.5 reaches the diagonal of a grid)",
        )


class LipSimulator(LearnedSimulator):
    """The `lip` plugin object: the shared learned simulator on a radius graph, checked to have edges."""

    def __init__(self, config: LipConfig, scene: object) -> None:
        steps = config.message_passing_steps
        super().__init__("lip", config, scene, lambda latent, hidden, names: MgnProcessor(latent, hidden, names, steps), lip_spec(config))

    def fit(self, train: Sequence[Trajectory], ctx: FitContext) -> dict[str, float]:
        """Train as the other learned simulators do, after checking every trajectory's first frame has edges."""
        for i, traj in enumerate(train):
            _, topo = self.cache.get(traj.cells, traj.mesh_pos, traj.node_type)
            check_connected(topo, traj.world_pos[0], self.spec, f"frame 0 of training trajectory {i}")
        return super().fit(train, ctx)

    def rollout(self, inp: RolloutInput) -> np.ndarray:
        """Roll out as the other learned simulators do, after checking the start frame has edges."""
        if self.model is not None:
            _, topo = self.cache.get(inp.cells, inp.mesh_pos, inp.node_type)
            check_connected(topo, inp.init_pos[1], self.spec, "the rollout's start frame")
        return super().rollout(inp)


def build_lip(config: LipConfig, ctx: object) -> LipSimulator:
    """The `lip` plugin object for a BuildContext's scene (obstacle nodes, if any, are particles of the same graph)."""
    return LipSimulator(config, getattr(ctx, "scene"))
