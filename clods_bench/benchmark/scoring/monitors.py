"""Rollout health monitors: edge strain, kinetic energy, first failing frame; and the scene's rest mesh.

A rollout fails at the first frame t >= 2 (frames 0 and 1 are given) where a position is
NaN/Inf, where the largest edge strain max_e |l_e(t)/l0_e - 1| exceeds a threshold, or where
the kinetic energy 1/2 sum_i m_i |(x_i(t) - x_i(t-1))/dt|^2 exceeds a threshold. Only the cloth's
nodes are monitored: a scene's obstacle nodes are rigid and prescribed (`cloth_monitor`). A strain
failure names where the cloth tore: the edge's distance in mesh edges from the nearest handle
(a tear at the pinned nodes points at how handles are treated; one far from them, at error
accumulating over the free cloth).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from clods_bench.datasets.obstacle_nodes import split_cloth
from clods_bench.datasets.types import HANDLE, ClothMesh, edges_from_cells


def _divisor_pairs(n: int) -> list[tuple[int, int]]:
    return [(a, n // a) for a in range(2, n // 2 + 1) if n % a == 0 and n // a >= 2]


def scene_rest_mesh(scene: object, cells: np.ndarray, mesh_pos: np.ndarray) -> ClothMesh | None:
    """The scene's own mesh whose topology and mesh_pos equal the given ones (its true 3D rest shape), or None.

    A rollout input carries cells and 2D mesh_pos but not the 3D rest shape (a cylinder's
    mesh_pos is unrolled and jumps at its seam), so the scene's builder is tried at its default
    resolution, 'flagsimple' and every (a, b) with a * b = V nodes.
    """
    build = getattr(scene, "build_mesh", None)
    if build is None:
        return None
    n = int(mesh_pos.shape[0])
    candidates: list[object] = [getattr(scene, "default_resolution", None), "flagsimple", *_divisor_pairs(n)]
    tried: list[object] = []
    for res in candidates:
        if res is None or res in tried:
            continue
        tried.append(res)
        try:
            mesh = build(res)
        except Exception:  # noqa: BLE001 - a resolution the builder rejects is simply not a match
            continue
        if (
            mesh.num_nodes == n
            and mesh.cells.shape == cells.shape
            and np.array_equal(mesh.cells, cells)
            and np.allclose(mesh.mesh_pos, mesh_pos, atol=1e-5)
        ):
            return mesh
    return None


def flat_rest_pos(mesh_pos: np.ndarray) -> np.ndarray:
    """(V,3) rest shape of a flat flag from its mesh coordinates: (u, 0, v), the flag builders' convention."""
    rest = np.zeros((mesh_pos.shape[0], 3))
    rest[:, 0] = mesh_pos[:, 0]
    rest[:, 2] = mesh_pos[:, 1]
    return rest


def lumped_mass(rest_pos: np.ndarray, cells: np.ndarray, density: float) -> np.ndarray:
    """(V,) node masses: density times a third of each adjacent triangle's rest area (as the solver lumps them)."""
    x = np.asarray(rest_pos, np.float64)
    c = np.asarray(cells, np.int64)
    area = 0.5 * np.linalg.norm(np.cross(x[c[:, 1]] - x[c[:, 0]], x[c[:, 2]] - x[c[:, 0]]), axis=1)
    mass = np.zeros(x.shape[0])
    np.add.at(mass, c.ravel(), np.repeat(density * area / 3.0, 3))
    return mass


@dataclass(frozen=True)
class MeshMonitor:
    """Precomputed edges, rest lengths and masses of one mesh, to score rollouts frame by frame."""

    edges: np.ndarray  # (E,2) int64 undirected
    rest_length: np.ndarray  # (E,)
    mass: np.ndarray  # (V,)
    dt: float
    nodes: np.ndarray | None = None
    """Indices of the monitored (cloth) nodes in the frames' node list; None: all of them (no obstacle nodes)."""
    handle_hops: np.ndarray | None = None
    """(V_monitored,) mesh-edge hops from each monitored node to the nearest handle node (-1: none reachable); None: no handles."""

    def _frames(self, frames: np.ndarray) -> np.ndarray:
        x = np.asarray(frames, np.float64)
        return x if self.nodes is None else x[:, self.nodes]

    @classmethod
    def from_rest(cls, cells: np.ndarray, rest_pos: np.ndarray, density: float, dt: float) -> "MeshMonitor":
        """Monitor of the mesh `cells` whose rest shape is `rest_pos` (V,3)."""
        edges = edges_from_cells(np.asarray(cells))
        rest = np.asarray(rest_pos, np.float64)
        length = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
        return cls(edges, length, lumped_mass(rest, cells, density), float(dt))

    def max_strain(self, frames: np.ndarray) -> np.ndarray:
        """(T,) largest |l/l0 - 1| over edges per frame (NaN where a frame is not finite)."""
        x = self._frames(frames)
        with np.errstate(over="ignore", invalid="ignore"):
            length = np.linalg.norm(x[:, self.edges[:, 0]] - x[:, self.edges[:, 1]], axis=2)
            strain = np.abs(length / self.rest_length[None, :] - 1.0)
            out = strain.max(axis=1)
        out[~np.isfinite(x).all(axis=(1, 2))] = np.nan
        return out

    def worst_edge(self, frame: np.ndarray) -> tuple[int, float]:
        """(index into `edges`, strain) of the most strained edge of one frame (V,3) (its finite edges only)."""
        x = self._frames(np.asarray(frame)[None])[0]
        with np.errstate(over="ignore", invalid="ignore"):
            strain = np.abs(np.linalg.norm(x[self.edges[:, 0]] - x[self.edges[:, 1]], axis=1) / self.rest_length - 1.0)
        strain = np.where(np.isfinite(strain), strain, -1.0)
        e = int(np.argmax(strain))
        return e, float(strain[e])

    def edge_hops_to_handle(self, edge: int) -> int | None:
        """Mesh-edge hops from an edge's nearer end to the nearest handle node (0: the edge touches one); None when
        the mesh has no handle or none is reachable."""
        if self.handle_hops is None:
            return None
        hops = [int(h) for h in self.handle_hops[self.edges[edge]] if h >= 0]
        return min(hops) if hops else None

    def kinetic_energy(self, frames: np.ndarray) -> np.ndarray:
        """(T,) kinetic energy (J) from backward differences; frame 0 gets 0 (no previous frame)."""
        x = self._frames(frames)
        out = np.zeros(x.shape[0])
        with np.errstate(over="ignore", invalid="ignore"):
            v = (x[1:] - x[:-1]) / self.dt
            out[1:] = 0.5 * np.einsum("v,tvd->t", self.mass, v * v)
        return out


def hop_distance(edges: np.ndarray, num_nodes: int, sources: np.ndarray) -> np.ndarray:
    """(num_nodes,) breadth-first distance in edges from the nearest of `sources` (-1 where none is reachable)."""
    edges = np.asarray(edges, np.int64)
    dist = np.full(int(num_nodes), -1, np.int64)
    frontier = np.unique(np.asarray(sources, np.int64))
    dist[frontier] = 0
    both = np.concatenate([edges, edges[:, ::-1]])
    d = 0
    while frontier.size:
        d += 1
        reached = np.zeros(int(num_nodes), bool)
        reached[frontier] = True
        nxt = np.unique(both[reached[both[:, 0]], 1])
        frontier = nxt[dist[nxt] < 0]
        dist[frontier] = d
    return dist


def cloth_monitor(scene: object, cells: np.ndarray, mesh_pos: np.ndarray, node_type: np.ndarray, density: float, dt: float) -> MeshMonitor:
    """Monitor of a trajectory's cloth (its obstacle nodes left out) against the scene's rest shape, else the flat flag's."""
    part = split_cloth(cells, mesh_pos, node_type)
    mesh = scene_rest_mesh(scene, part.cells, part.mesh_pos)
    rest = mesh.rest_pos if mesh is not None else flat_rest_pos(part.mesh_pos)
    monitor = MeshMonitor.from_rest(part.cells, rest, density, dt)
    handles = np.flatnonzero(np.asarray(part.node_type) == HANDLE)
    if handles.size:
        monitor = dataclasses.replace(monitor, handle_hops=hop_distance(monitor.edges, len(rest), handles))
    return monitor if part.obstacle_nodes.size == 0 else dataclasses.replace(monitor, nodes=part.nodes)


def _tear_site(hops: int | None) -> str:
    """', k hops from a handle' for a torn edge `hops` edges from the nearest handle ('' when the mesh has none)."""
    if hops is None:
        return ""
    return ", at a handle" if hops == 0 else f", {hops} hop{'s' if hops > 1 else ''} from a handle"


@dataclass(frozen=True)
class Failure:
    """Where and why a rollout failed: the first failing frame and a short reason."""

    frame: int
    reason: str
    tear_hops_to_handle: int | None = None
    """For a strain failure: mesh-edge hops from the most strained edge to the nearest handle (None: no handle)."""


def first_failure(
    frames: np.ndarray, monitor: MeshMonitor, strain_threshold: float, energy_threshold: float
) -> tuple[Failure | None, np.ndarray, np.ndarray]:
    """(first failure or None, per-frame max strain, per-frame kinetic energy) of a rollout (T,V,3).

    Frames 0 and 1 are given, so checks start at frame 2; at one frame the order of reasons is
    non-finite, then strain, then energy.
    """
    strain = monitor.max_strain(frames)
    energy = monitor.kinetic_energy(frames)
    finite = np.isfinite(np.asarray(frames)).all(axis=(1, 2))
    for t in range(2, frames.shape[0]):
        if not finite[t]:
            return Failure(t, "non-finite positions (NaN/Inf)"), strain, energy
        if strain[t] > strain_threshold:
            hops = monitor.edge_hops_to_handle(monitor.worst_edge(frames[t])[0])
            return Failure(t, f"edge strain {strain[t]:.3g} > {strain_threshold:g}" + _tear_site(hops), hops), strain, energy
        if not np.isfinite(energy[t]) or energy[t] > energy_threshold:
            return Failure(t, f"kinetic energy {energy[t]:.3g} J > {energy_threshold:.3g} J"), strain, energy
    return None, strain, energy
