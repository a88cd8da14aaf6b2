"""MeshGraphNets cloth graph: per-topology edge sets (cached) and per-step node/edge features.

Facts from DeepMind's `cloth_model.py` / `common.py`: node features are the velocity
x_t - x_{t-1} and a one-hot node type of width NODE_TYPE_SIZE; mesh edges come from the
triangles, made unique and bidirectional; edge features are sender minus receiver in world
space (3) and its norm, then in mesh space (2) and its norm. World (contact) edges, as in
MGN's obstacle domains, are built only when the scene has obstacles (`GraphSpec`).
A particle simulator's spec (`radius_factor` set) replaces all of these by one 'radius' edge set
rebuilt from the world positions at every step (`radius_graph`): relative position over the
radius and its norm, with no mesh edge and no mesh-space feature.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch

from clods_bench.datasets.types import NODE_TYPE_SIZE, NORMAL, OBSTACLE, edges_from_cells
from clods_bench.plugins.simulators.learned.radius_graph import radius_edges, rest_spacing

VELOCITY_SIZE = 3
NODE_FEATURE_SIZE = VELOCITY_SIZE + NODE_TYPE_SIZE  # velocity + one-hot node type
WORLD_REL_SIZE = 3 + 1  # relative world position + its norm
MESH_REL_SIZE = 2 + 1  # relative mesh position + its norm
MESH_EDGE_FEATURE_SIZE = WORLD_REL_SIZE + MESH_REL_SIZE
WORLD_EDGE_FEATURE_SIZE = WORLD_REL_SIZE
RADIUS_EDGE_FEATURE_SIZE = WORLD_REL_SIZE  # relative world position / radius + its norm
OUTPUT_SIZE = 3  # acceleration


@dataclass(frozen=True)
class GraphSpec:
    """Which edge sets the graph has: mesh edges always, world (contact) edges only with obstacles; or, with
    `radius_factor` set, only a radius graph over world positions (a particle simulator)."""

    world_edges: bool = False
    world_radius: float = 0.05
    radius_factor: float | None = None
    """Particle graph: connectivity radius = this times the mesh's rest spacing (`Topology.rest_spacing`)."""
    max_neighbours: int | None = None
    """Particle graph: each node receives from at most this many nearest nodes within the radius (None: all)."""

    @classmethod
    def for_scene(cls, scene: object, world_radius: float) -> "GraphSpec":
        """The graph a scene needs: world edges iff `scene.has_obstacles`."""
        return cls(world_edges=bool(getattr(scene, "has_obstacles")), world_radius=world_radius)

    @property
    def edge_widths(self) -> dict[str, int]:
        """Feature width of each edge set built, by name."""
        if self.radius_factor is not None:
            return {"radius": RADIUS_EDGE_FEATURE_SIZE}
        widths = {"mesh": MESH_EDGE_FEATURE_SIZE}
        if self.world_edges:
            widths["world"] = WORLD_EDGE_FEATURE_SIZE
        return widths


class EdgeSet(NamedTuple):
    """One edge set: features (E,D), senders (E,), receivers (E,)."""

    features: torch.Tensor
    senders: torch.Tensor
    receivers: torch.Tensor


@dataclass(frozen=True)
class Topology:
    """Everything static about a mesh (possibly several meshes concatenated), on one device."""

    senders: torch.Tensor  # (E,) int64, mesh edges, both directions
    receivers: torch.Tensor  # (E,) int64
    mesh_rel: torch.Tensor  # (E, MESH_REL_SIZE) relative mesh position and its norm
    node_type_onehot: torch.Tensor  # (V, NODE_TYPE_SIZE) float32
    normal: torch.Tensor  # (V,) bool: simulated nodes
    obstacle: torch.Tensor  # (V,) bool
    mesh_pos: torch.Tensor  # (V, 2) float32 rest-space positions (for processors that build coarse edges)
    sample: torch.Tensor  # (V,) int64 index of the mesh a node belongs to in a batched union (all 0 for one mesh)
    rest_spacing: torch.Tensor  # (V,) float32 median nearest-neighbour distance of the node's mesh in rest space

    @property
    def num_nodes(self) -> int:
        """Number of nodes V."""
        return int(self.normal.shape[0])


def mesh_edges(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique bidirectional mesh edges (senders, receivers) from triangles."""
    und = edges_from_cells(np.asarray(cells))
    return np.concatenate([und[:, 0], und[:, 1]]), np.concatenate([und[:, 1], und[:, 0]])


def cells_hash(cells: np.ndarray) -> str:
    """Short content hash of a triangle array (identifies a mesh in checkpoints)."""
    return hashlib.sha1(np.ascontiguousarray(cells, dtype=np.int64).tobytes()).hexdigest()[:16]


def _rel_with_norm(rel: torch.Tensor) -> torch.Tensor:
    return torch.cat([rel, torch.linalg.vector_norm(rel, dim=-1, keepdim=True)], dim=-1)


def build_topology(cells: np.ndarray, mesh_pos: np.ndarray, node_type: np.ndarray, device: str = "cpu") -> Topology:
    """Static graph parts of one mesh: edges, relative mesh features, node-type one-hot, masks."""
    snd, rcv = mesh_edges(cells)
    s = torch.as_tensor(snd, dtype=torch.int64, device=device)
    r = torch.as_tensor(rcv, dtype=torch.int64, device=device)
    mp = torch.as_tensor(np.asarray(mesh_pos, dtype=np.float32), device=device)
    nt = torch.as_tensor(np.asarray(node_type, dtype=np.int64), device=device)
    onehot = torch.nn.functional.one_hot(nt, NODE_TYPE_SIZE).to(torch.float32)
    v = int(nt.shape[0])
    sample = torch.zeros(v, dtype=torch.int64, device=device)
    cloth = np.asarray(node_type) != OBSTACLE  # obstacle nodes all sit at one mesh_pos: they would make the spacing 0
    spacing = torch.full((v,), rest_spacing(np.asarray(mesh_pos)[cloth]), dtype=torch.float32, device=device)
    return Topology(s, r, _rel_with_norm(mp[s] - mp[r]), onehot, nt == NORMAL, nt == OBSTACLE, mp, sample, spacing)


class TopologyCache:
    """Topologies keyed by the content of (cells, mesh_pos, node_type), and batched copies of them.

    Batched unions are kept for the `max_batched` most recently used key tuples: with several
    meshes the number of distinct tuples grows combinatorially.
    """

    def __init__(self, device: str = "cpu", max_batched: int = 64) -> None:
        self.device = device
        self.max_batched = max_batched
        self._single: dict[str, Topology] = {}
        self._batched: OrderedDict[tuple[str, ...], Topology] = OrderedDict()

    def key(self, cells: np.ndarray, mesh_pos: np.ndarray, node_type: np.ndarray) -> str:
        """Content key of one mesh."""
        h = hashlib.sha1()
        for a, dt in ((cells, np.int64), (mesh_pos, np.float32), (node_type, np.int64)):
            h.update(np.ascontiguousarray(a, dtype=dt).tobytes())
        return h.hexdigest()

    def get(self, cells: np.ndarray, mesh_pos: np.ndarray, node_type: np.ndarray) -> tuple[str, Topology]:
        """(key, topology) of one mesh, built once."""
        k = self.key(cells, mesh_pos, node_type)
        if k not in self._single:
            self._single[k] = build_topology(cells, mesh_pos, node_type, self.device)
        return k, self._single[k]

    def batch(self, keys: tuple[str, ...]) -> Topology:
        """The disjoint union of the given topologies (node indices offset), built once per key tuple."""
        if len(keys) == 1:
            return self._single[keys[0]]
        if keys in self._batched:
            self._batched.move_to_end(keys)
        else:
            self._batched[keys] = concat_topologies([self._single[k] for k in keys])
            if len(self._batched) > self.max_batched:
                self._batched.popitem(last=False)
        return self._batched[keys]

    @staticmethod
    def batch_key(keys: tuple[str, ...]) -> str:
        """One key for a batch of topologies (the single key when there is one), for processor caches."""
        if len(keys) == 1:
            return keys[0]
        return hashlib.sha1("+".join(keys).encode()).hexdigest()


def concat_topologies(topos: list[Topology]) -> Topology:
    """Disjoint union of several topologies: one graph holding several samples."""
    offsets = np.cumsum([0] + [t.num_nodes for t in topos[:-1]])
    sample_offsets = np.cumsum([0] + [int(t.sample.max()) + 1 if t.num_nodes else 0 for t in topos[:-1]])
    cat = torch.cat
    return Topology(
        cat([t.senders + int(o) for t, o in zip(topos, offsets)]),
        cat([t.receivers + int(o) for t, o in zip(topos, offsets)]),
        cat([t.mesh_rel for t in topos]),
        cat([t.node_type_onehot for t in topos]),
        cat([t.normal for t in topos]),
        cat([t.obstacle for t in topos]),
        cat([t.mesh_pos for t in topos]),
        cat([t.sample + int(o) for t, o in zip(topos, sample_offsets)]),
        cat([t.rest_spacing for t in topos]),
    )


def world_edges(topo: Topology, pos: torch.Tensor, radius: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Contact edges, both directions, between obstacle and non-obstacle nodes closer than `radius`."""
    obs = torch.nonzero(topo.obstacle).squeeze(1)
    cloth = torch.nonzero(~topo.obstacle).squeeze(1)
    if obs.numel() == 0 or cloth.numel() == 0:
        empty = torch.zeros(0, dtype=torch.int64, device=pos.device)
        return empty, empty
    close = torch.cdist(pos[obs], pos[cloth]) < radius
    io, ic = torch.nonzero(close, as_tuple=True)
    a, b = obs[io], cloth[ic]
    return torch.cat([a, b]), torch.cat([b, a])


def build_features(
    topo: Topology, pos: torch.Tensor, prev: torch.Tensor, spec: GraphSpec
) -> tuple[torch.Tensor, dict[str, EdgeSet]]:
    """Raw (unnormalised) node features (V, NODE_FEATURE_SIZE) and edge sets for positions x_t, x_{t-1}."""
    nodes = torch.cat([pos - prev, topo.node_type_onehot], dim=-1)
    if spec.radius_factor is not None:
        radius = spec.radius_factor * topo.rest_spacing
        rs, rr = radius_edges(pos, topo.sample, radius, spec.max_neighbours)
        return nodes, {"radius": EdgeSet(_rel_with_norm((pos[rs] - pos[rr]) / radius[rr].unsqueeze(1)), rs, rr)}
    s, r = topo.senders, topo.receivers
    mesh = torch.cat([_rel_with_norm(pos[s] - pos[r]), topo.mesh_rel], dim=-1)
    sets = {"mesh": EdgeSet(mesh, s, r)}
    if spec.world_edges:
        ws, wr = world_edges(topo, pos, spec.world_radius)
        sets["world"] = EdgeSet(_rel_with_norm(pos[ws] - pos[wr]), ws, wr)
    return nodes, sets
