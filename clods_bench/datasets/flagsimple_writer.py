"""Write trajectories in the DeepMind meshgraphnets format (meta.json + <split>.tfrecord).

The inverse of `flagsimple.read_flagsimple`: lets our generated data be read by meshgraphnets
code, and gives the reader's tests a real TFRecord file. Needs the `crc32c` package
(a dependency of `tfrecord`; its writer checksums every record).
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from clods_bench.atomic import atomic_path, write_json
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError


def flag_meta(trajectory_length: int, dt: float = 0.02) -> dict:
    """meta.json content for flag-type data with `trajectory_length` frames per record."""
    return {
        "simulator": "clods-bench",
        "dt": dt,
        "collision_radius": None,
        "field_names": ["cells", "mesh_pos", "node_type", "world_pos"],
        "features": {
            "cells": {"type": "static", "shape": [1, -1, 3], "dtype": "int32"},
            "mesh_pos": {"type": "static", "shape": [1, -1, 2], "dtype": "float32"},
            "node_type": {"type": "static", "shape": [1, -1, 1], "dtype": "int32"},
            "world_pos": {"type": "dynamic", "shape": [trajectory_length, -1, 3], "dtype": "float32"},
        },
        "trajectory_length": trajectory_length,
    }


def trajectory_record(traj: Trajectory) -> dict[str, bytes]:
    """The raw little-endian field bytes of one trajectory, as meshgraphnets stores them."""
    return {
        "cells": np.ascontiguousarray(traj.cells[None], dtype="<i4").tobytes(),
        "mesh_pos": np.ascontiguousarray(traj.mesh_pos[None], dtype="<f4").tobytes(),
        "node_type": np.ascontiguousarray(traj.node_type.reshape(1, -1, 1), dtype="<i4").tobytes(),
        "world_pos": np.ascontiguousarray(traj.world_pos, dtype="<f4").tobytes(),
    }


def write_records(path: str | Path, records: Iterable[Mapping[str, bytes]]) -> None:
    """Write tf.train.Example records of bytes features to a TFRecord file, atomically."""
    from tfrecord.writer import TFRecordWriter

    with atomic_path(path) as tmp:
        writer = TFRecordWriter(str(tmp))
        try:
            for record in records:
                writer.write({name: (value, "byte") for name, value in record.items()})
        finally:
            writer.close()


def write_flagsimple(out_dir: str | Path, trajectories: list[Trajectory], split: str = "train") -> Path:
    """Write `meta.json` and `<split>.tfrecord` for trajectories of equal length and dt; returns the tfrecord path."""
    if not trajectories:
        raise ClodsError("no trajectories to write", where=str(out_dir))
    length, dt = trajectories[0].num_steps, trajectories[0].dt
    for i, traj in enumerate(trajectories):
        traj.validate(where=f"trajectory {i}")
        if traj.num_steps != length or traj.dt != dt:
            raise ClodsError(f"{traj.num_steps} frames, dt {traj.dt}; trajectory 0 has {length}, dt {dt} (the format needs one length)",
                             where=f"trajectory {i}")
    out = Path(out_dir)
    write_json(out / "meta.json", flag_meta(length, dt))
    path = out / f"{split}.tfrecord"
    write_records(path, (trajectory_record(t) for t in trajectories))
    return path
