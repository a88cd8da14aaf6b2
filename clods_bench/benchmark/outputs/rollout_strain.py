"""Edge strain per face and the divergence frame of a saved rollout, for the report's videos and 3D views.

Strain is the stability monitors' |l/l0 - 1| (`scoring.monitors`), against the scene's rest shape rebuilt from the
sample's topology (`cloth_monitor`); a face shows its most strained edge, obstacle faces none. A sample saved
without its topology falls back to the truth's first frame as the rest shape (said in the caption).

The divergence frame is the run's own: a stability record's failure frame and reason for the watched trajectory
(`extra.diverged`, `extra.reasons`), a CDG record's first non-finite frame (`extra.diverged`); for CDG the video
applies the stability task's monitors as well (default thresholds: edge strain 0.5, kinetic energy 10x the
truth's largest), so a rollout that tears without going non-finite is marked too, with its reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from clods_bench.benchmark.outputs.rollout_samples import RolloutSample
from clods_bench.benchmark.scoring.monitors import MeshMonitor, cloth_monitor, first_failure

STRAIN_MAX = 0.5
"""Top of the fixed colour scale (strain 0 to 0.5; larger strains take the top colour): the tear threshold."""
TEAR_STRAIN = 0.5
"""The stability task's default strain threshold (`StabilityConfig.strain_threshold`), applied to CDG rollouts."""
ENERGY_FACTOR = 10.0
"""The stability task's default energy factor (`StabilityConfig.energy_factor`), applied to CDG rollouts."""


@dataclass(frozen=True)
class Divergence:
    """The first failing frame of a rollout and why (the monitors' reason), and which rule found it."""

    frame: int
    reason: str
    source: str

    def caption(self) -> str:
        """'diverged at frame k: reason'."""
        return f"diverged at frame {self.frame}: {self.reason}"


@dataclass(frozen=True)
class StrainModel:
    """Edges (global node indices), their rest lengths, each face's three edges (-1: an obstacle face), the monitor."""

    edges: np.ndarray
    rest: np.ndarray
    face_edges: np.ndarray
    monitor: MeshMonitor
    rest_source: str


def strain_model(sample: RolloutSample, scene: Any | None) -> StrainModel:
    """The strain model of a sample: the scene's rest shape when the sample has its topology, else the truth's (or the
    prediction's) frame 0."""
    if sample.mesh_pos is not None and sample.node_type is not None:
        monitor = cloth_monitor(scene, sample.cells, sample.mesh_pos, sample.node_type, float(getattr(getattr(scene, "params", None), "density", 1.0)),
                                sample.dt)  # fmt: skip
        has_rest = scene is not None and getattr(scene, "build_mesh", None) is not None
        source = "the scene's rest mesh" if has_rest else "the flat rest shape of the mesh coordinates"
    else:
        ref = sample.truth if sample.truth is not None else sample.pred
        monitor = MeshMonitor.from_rest(sample.cells, ref[0], 1.0, sample.dt)
        source = "frame 0 (the sample has no rest mesh)"
    nodes = monitor.nodes if monitor.nodes is not None else np.arange(sample.pred.shape[1])
    edges = np.asarray(nodes, np.int64)[monitor.edges]
    return StrainModel(edges, monitor.rest_length, _face_edges(sample.cells, edges, sample.pred.shape[1]), monitor, source)


def _face_edges(cells: np.ndarray, edges: np.ndarray, num_nodes: int) -> np.ndarray:
    """(F,3) index into `edges` of each face's edges, -1 where an edge is not among them (obstacle faces)."""
    key = np.minimum(edges[:, 0], edges[:, 1]) * num_nodes + np.maximum(edges[:, 0], edges[:, 1])
    order = np.argsort(key)
    out = np.full((len(cells), 3), -1, np.int64)
    c = np.asarray(cells, np.int64)
    for k, (a, b) in enumerate(((0, 1), (1, 2), (2, 0))):
        fk = np.minimum(c[:, a], c[:, b]) * num_nodes + np.maximum(c[:, a], c[:, b])
        pos = np.clip(np.searchsorted(key[order], fk), 0, len(key) - 1)
        hit = key[order][pos] == fk
        out[hit, k] = order[pos[hit]]
    return out


def face_strain(model: StrainModel, frames: np.ndarray) -> np.ndarray:
    """(T,F) largest edge strain of each face per frame; NaN on obstacle faces and non-finite frames."""
    x = np.asarray(frames, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        length = np.linalg.norm(x[:, model.edges[:, 0]] - x[:, model.edges[:, 1]], axis=-1)
        strain = np.abs(length / model.rest[None] - 1.0)
    strain = np.concatenate([strain, np.full((len(x), 1), np.nan)], axis=1)  # index -1: no edge
    per_face = strain[:, model.face_edges]
    out = np.where(np.isfinite(per_face).all(axis=2), per_face.max(axis=2, initial=0.0, where=np.isfinite(per_face)), np.nan)
    out[:, (model.face_edges < 0).any(axis=1)] = np.nan
    return out


def rollout_divergence(sample: RolloutSample, model: StrainModel, task: str, seed_result: dict[str, Any] | None) -> Divergence | None:
    """The rollout's divergence frame: the record's own (see the module docstring), else None."""
    extra = (seed_result or {}).get("extra") or {}
    recorded = (extra.get("diverged") or {}).get(sample.trajectory)
    if task == "stability" and seed_result is not None:  # the run watched this rollout itself
        if recorded is None:
            return None
        return Divergence(int(recorded), str((extra.get("reasons") or {}).get(sample.trajectory, "failed")), "the stability run's monitors")
    truth_energy = float(np.nanmax(model.monitor.kinetic_energy(sample.truth))) if sample.truth is not None else float("inf")
    failure, _, _ = first_failure(sample.pred, model.monitor, TEAR_STRAIN, ENERGY_FACTOR * truth_energy)
    found = Divergence(failure.frame, failure.reason, f"the stability monitors (strain > {TEAR_STRAIN:g})") if failure else None
    if recorded is not None and (found is None or int(recorded) < found.frame):
        return Divergence(int(recorded), "non-finite positions (NaN/Inf)", "the CDG run")
    return found
