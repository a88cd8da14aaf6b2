"""OBJ/PLY sequences of the meshes a run saved: the reconstructed initial mesh, stage 2's extracted cloth, a rollout.

Runs save their mesh samples as `seed_N/*.npz` (`mesh_pictures.save_mesh_sample`: `initial_mesh.npz`,
`extraction_meshes.npz`, `rollout_meshes.npz`); this writes each sequence in one as a folder of one mesh file per
frame (`datasets.mesh_io.export_sequence`), for Blender or MeshLab. Mesh-space UVs come from the first frame's
best-fit plane, since a sample keeps positions and cells only.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from clods_bench.benchmark.outputs.mesh_pictures import load_mesh_sample
from clods_bench.datasets.mesh_io import export_sequence, flatten_rest
from clods_bench.datasets.types import NORMAL, Trajectory
from clods_bench.errors import ClodsError


def folder_name(name: str) -> str:
    """A file-system-safe folder name for a sequence's column name ("extracted (stage 2)" -> "extracted_stage_2")."""
    return re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_") or "mesh"


def export_mesh_sample(sample: Path, out: Path, fmt: str = "obj") -> dict[str, list[Path]]:
    """Write every sequence of the mesh sample `sample` (and its ground truth, as `truth/`) under `out`, one folder
    each; returns the files per sequence name. A non-finite frame is refused with its sequence and frame named."""
    sample = Path(sample)
    if not sample.is_file():
        raise ClodsError("no such mesh sample (runs save them as seed_N/*.npz)", where=str(sample))
    try:
        cells, meshes, truth, _, _ = load_mesh_sample(sample)
    except (OSError, KeyError, ValueError) as exc:
        raise ClodsError(f"not a mesh sample ({type(exc).__name__}: {exc})", where=str(sample)) from None
    sequences = dict(meshes)
    if truth is not None:
        sequences["truth"] = truth
    written: dict[str, list[Path]] = {}
    for name, frames in sequences.items():
        frames = np.asarray(frames, np.float64)
        bad = np.flatnonzero(~np.isfinite(frames).all(axis=(1, 2)))
        if bad.size:
            raise ClodsError(f"sequence '{name}' has non-finite positions at frame {int(bad[0])}", where=str(sample))
        mesh_pos = flatten_rest(frames[0], np.asarray(cells, np.int64), None).astype(np.float32)
        traj = Trajectory(np.asarray(cells, np.int32), mesh_pos, np.full(frames.shape[1], NORMAL, np.int32), frames.astype(np.float32), 1.0)
        written[name] = export_sequence(traj, Path(out) / folder_name(name), fmt)  # type: ignore[arg-type]
    return written
