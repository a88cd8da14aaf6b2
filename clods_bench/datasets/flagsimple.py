"""Reader for the real FLAGSIMPLE release (DeepMind meshgraphnets format), without TensorFlow.

A dataset directory holds `meta.json` and `train.tfrecord` / `valid.tfrecord` / `test.tfrecord`.
Each record is a tf.train.Example with one bytes feature per field holding the raw little-endian
array bytes; `meta.json` gives each field's dtype, shape (-1 for the variable dimension) and type
('static': leading dim 1, same for every frame; 'dynamic': leading dim = trajectory length).
flag_simple: cells [1,F,3] int32, mesh_pos [1,V,2] float32, node_type [1,V,1] int32 (static),
world_pos [401,V,3] float32 (dynamic), 0.02 s between frames.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import Trajectory
from clods_bench.errors import ClodsError

DEFAULT_DT = 0.02
SOURCE_SPLITS = ("train", "valid", "test")
REQUIRED_FIELDS = ("cells", "mesh_pos", "node_type", "world_pos")


def read_meta(src_dir: str | Path) -> dict[str, Any]:
    """Parse and check `meta.json` of a meshgraphnets dataset directory."""
    path = Path(src_dir) / "meta.json"
    if not path.is_file():
        raise ClodsError("meta.json not found", where=str(path), hint="point at the downloaded flag_simple directory")
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ClodsError(f"malformed JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}", where=str(path)) from None
    features = meta.get("features") if isinstance(meta, dict) else None
    if not isinstance(features, dict):
        raise ClodsError("missing or not an object", where=f"{path}.features")
    meta.setdefault("field_names", list(features))
    for name in REQUIRED_FIELDS:
        if name not in features:
            raise ClodsError(f"no field '{name}' (not a cloth dataset?)", where=f"{path}.features")
    for name, spec in features.items():
        where = f"{path}.features.{name}"
        if not isinstance(spec, dict) or not {"type", "shape", "dtype"} <= set(spec):
            raise ClodsError("needs type, shape and dtype", where=where)
        spec["dtype"] = _dtype_name(spec["dtype"], where)
        if sum(1 for d in spec["shape"] if d == -1) > 1:
            raise ClodsError(f"shape {spec['shape']} has more than one -1", where=where)
    return meta


def read_flagsimple(src_dir: str | Path, split: str = "train", limit: int | None = None, dt: float | None = None) -> Iterator[Trajectory]:
    """Yield the trajectories of one split in record order (at most `limit`), as our Trajectory.

    `dt` defaults to meta.json's 'dt' if present, else 0.02 s (FLAGSIMPLE's time step).
    """
    from tfrecord.reader import tfrecord_loader

    if split not in SOURCE_SPLITS:
        raise ClodsError(f"unknown split '{split}', expected one of {SOURCE_SPLITS}", where="flagsimple.split")
    meta = read_meta(src_dir)
    path = Path(src_dir) / f"{split}.tfrecord"
    if not path.is_file():
        raise ClodsError(f"{split}.tfrecord not found", where=str(path))
    step = float(dt if dt is not None else meta.get("dt") or DEFAULT_DT)
    if limit is not None and limit <= 0:
        return
    records = iter(tfrecord_loader(str(path), None, description=None))
    number = 0
    while True:
        try:
            features = next(records)
        except StopIteration:
            return
        except Exception as exc:  # truncated file (RuntimeError), undecodable proto (DecodeError), ...
            raise ClodsError(f"cannot read record {number}: {type(exc).__name__}: {exc}", where=str(path)) from None
        where = f"{path} record {number}"
        arrays = {name: _decode(features, name, meta["features"][name], f"{where} field '{name}'") for name in meta["field_names"]}
        traj = Trajectory(
            cells=_static(arrays["cells"], f"{where} field 'cells'"),
            mesh_pos=_static(arrays["mesh_pos"], f"{where} field 'mesh_pos'"),
            node_type=_static(arrays["node_type"], f"{where} field 'node_type'").reshape(-1),
            world_pos=arrays["world_pos"],
            dt=step,
            meta={"source": "flagsimple", "source_dir": str(src_dir), "split": split, "record": number},
        )
        traj.validate(where=where)
        yield traj
        number += 1
        if limit is not None and number >= limit:
            return


def import_flagsimple(
    src_dir: str | Path,
    out_root: str | Path,
    split: str = "train",
    limit: int | None = None,
    num_train: int | None = None,
    num_steps: int | None = None,
    dt: float | None = None,
    force: bool = False,
) -> DatasetStore:
    """Copy records 0..limit-1 of a FLAGSIMPLE split into a DatasetStore (meshes only, no frames).

    Record i becomes store index i; indices < num_train get split 'train', the rest 'test'
    (num_train None: all 'train'); `num_steps` keeps the first frames only. Resumable:
    indices already complete in the store are skipped.
    """
    config = {"source": "flagsimple", "source_split": split, "limit": limit, "num_train": num_train, "num_steps": num_steps, "dt": dt}
    store = DatasetStore.create(Path(out_root), "flagsimple", config, cameras=[], force=force)
    done = store.completed_indices()
    for i, traj in enumerate(read_flagsimple(src_dir, split, limit, dt)):
        if i in done:
            continue
        if num_steps is not None:
            if traj.num_steps < num_steps:
                raise ClodsError(f"record {i} has {traj.num_steps} frames, fewer than num_steps={num_steps}", where=f"{src_dir}/{split}.tfrecord")
            traj = traj.slice(0, num_steps)
        store_split = "train" if num_train is None or i < num_train else "test"
        store.write_trajectory(i, store_split, i, traj, None)
    return store


def _dtype_name(value: Any, where: str) -> str:
    """'float32' from 'float32' or from TensorFlow's repr "<dtype: 'float32'>" (seen in some meta.json files)."""
    found = re.search(r"(float|int|uint)(8|16|32|64)", str(value))
    if not found:
        raise ClodsError(f"unsupported dtype {value!r}", where=f"{where}.dtype")
    return found.group(0)


def _decode(features: dict[str, Any], name: str, spec: dict[str, Any], where: str) -> np.ndarray:
    """Raw little-endian bytes of one field -> array of the meta shape (one -1 dim inferred)."""
    if name not in features:
        raise ClodsError(f"field missing from the record (present: {sorted(features)})", where=where)
    value = features[name]
    if isinstance(value, np.ndarray) and value.dtype.kind == "S":
        value = b"".join(value.tolist())
    if not isinstance(value, (bytes, bytearray, memoryview)):
        raise ClodsError("not stored as a bytes feature (expected raw array bytes)", where=where)
    if spec["type"] not in ("static", "dynamic"):
        raise ClodsError(f"field type '{spec['type']}' is not supported (only static and dynamic)", where=where)
    dtype = np.dtype(spec["dtype"]).newbyteorder("<")
    raw = bytes(value)
    shape = list(spec["shape"])
    known = math.prod(d for d in shape if d != -1)
    count, rest = divmod(len(raw), dtype.itemsize)
    if rest or known == 0 or count % known or (-1 not in shape and count != known):
        expected = f"{known * dtype.itemsize} bytes" if -1 not in shape else f"a multiple of {known * dtype.itemsize} bytes"
        raise ClodsError(f"{len(raw)} bytes do not fit {spec['dtype']} shape {spec['shape']} (expected {expected})", where=where)
    shape = [count // known if d == -1 else d for d in shape]
    return np.frombuffer(raw, dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="))


def _static(arr: np.ndarray, where: str) -> np.ndarray:
    """Drop the leading length-1 axis of a static field."""
    if arr.ndim < 2 or arr.shape[0] != 1:
        raise ClodsError(f"static field has shape {arr.shape}, expected a leading dimension of 1", where=where)
    return arr[0]
