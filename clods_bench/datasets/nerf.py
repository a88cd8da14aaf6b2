"""NeRF-style multi-view layout (`transforms.json` + PNG folders): the camera conversion and `data export --format nerf`.

Axis conventions, stated once. clods-bench cameras are OpenCV-style world-to-camera (`cameras.py`): camera x right,
y down, z forward, x_cam = R x_world + t. NeRF / nerfstudio `transform_matrix` is camera-to-world in the OpenGL
convention: camera x right, y up, z backward (the camera looks along -z). So

    c2w_gl = [[R^T, -R^T t], [0, 1]] @ diag(1, -1, -1, 1)        (flip the camera's y and z axes)
    R = (c2w_gl[:3, :3] @ diag(1, -1, -1))^T,   t = -R @ c2w_gl[:3, 3].

Intrinsics map one to one: fl_x = K[0,0], fl_y = K[1,1], cx = K[0,2], cy = K[1,2], w = width, h = height; both
conventions put pixel (col c, row r)'s centre at (c + 0.5, r + 0.5), so no half-pixel shift is needed. World
coordinates are left as they are (metres, z up in the built-in scenes): no recentring or rescaling.

Export layout, one folder per trajectory:
    traj_0000/transforms.json           every image one entry of `frames` (nerfstudio-compatible) plus fps, dt
    traj_0000/images/cam_00/frame_0000.png
    traj_0000/meshes/frame_0000.obj     (--meshes obj|ply) plus topology.npz: cells, mesh_pos, node_type
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Literal, Sequence

import numpy as np

from clods_bench.atomic import write_json, write_npz
from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError

CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
"""Right-multiplying a camera-to-world matrix by this flips the camera's y and z axes (OpenCV <-> OpenGL); it is its own inverse."""
TRANSFORMS = "transforms.json"
TOPOLOGY = "topology.npz"
FORMAT_VERSION = 1


def camera_to_c2w_gl(cam: Camera) -> np.ndarray:
    """(4,4) camera-to-world matrix in the OpenGL axes of NeRF / nerfstudio, from an OpenCV world-to-camera camera."""
    R, t = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64)
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = -R.T @ t
    return c2w @ CV_TO_GL


def intrinsics_dict(cam: Camera) -> dict[str, float | int]:
    """fl_x, fl_y, cx, cy, w, h of a camera (NeRF / nerfstudio keys)."""
    K = np.asarray(cam.K, np.float64)
    return {"fl_x": float(K[0, 0]), "fl_y": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
            "w": int(cam.width), "h": int(cam.height)}  # fmt: skip


def check_c2w(matrix: Any, where: str) -> np.ndarray:
    """A transform_matrix as a (4,4) float64 rigid camera-to-world matrix; ClodsError naming `where` otherwise."""
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise ClodsError("not a 4x4 matrix of numbers", where=where) from None
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise ClodsError(f"expected a finite 4x4 matrix, got shape {m.shape}", where=where)
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ClodsError(f"last row must be [0, 0, 0, 1], got {m[3].tolist()}", where=where)
    det = float(np.linalg.det(m[:3, :3]))
    if abs(det) < 1e-9:
        raise ClodsError(f"matrix is not invertible (det of the rotation block {det:.3g})", where=where)
    rot = m[:3, :3]
    if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-5) or det < 0:
        raise ClodsError("rotation block is not a proper rotation (scaled, sheared or mirrored)", where=where,
                         hint="camera-to-world matrices must be rigid; undo any scene scaling in the translations only")  # fmt: skip
    return m


def camera_from_c2w_gl(c2w: np.ndarray, intr: dict[str, Any], where: str) -> Camera:
    """An OpenCV world-to-camera `Camera` from an OpenGL camera-to-world matrix and fl_x, fl_y, cx, cy, w, h."""
    m = check_c2w(c2w, where) @ CV_TO_GL
    R = m[:3, :3].T
    t = -R @ m[:3, 3]
    K = np.array([[intr["fl_x"], 0.0, intr["cx"]], [0.0, intr["fl_y"], intr["cy"]], [0.0, 0.0, 1.0]], np.float64)
    cam = Camera(K, R, t, int(intr["w"]), int(intr["h"]))
    cam.validate(where)
    return cam


def export_nerf(store: Any, out: Path, meshes: Literal["obj", "ply", "none"] = "none",
                trajectories: Sequence[int] | None = None, num_views_test: int | None = None,
                interp_steps: int | None = None) -> list[Path]:  # fmt: skip
    """Write trajectories of `store` (a DatasetStore; default all) in the NeRF layout under `out`; the folders written.

    Each trajectory folder is written into a temporary sibling and renamed into place when complete, so an
    interrupted export leaves whole folders only (a rerun replaces them). `num_views_test` and `interp_steps`
    (the dataset's split sizes) are recorded in transforms.json so that `import-video` restores them by default.
    """
    import imageio.v3 as iio

    if meshes not in ("obj", "ply", "none"):
        raise ClodsError(f"unknown mesh format '{meshes}'; known: obj, ply, none", where="--meshes")
    if meshes != "none":
        store.require_meshes("--meshes " + meshes)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cams = store.cameras()
    names = [f"cam_{n:02d}" for n in range(len(cams))]
    intr = [intrinsics_dict(c) for c in cams]
    shared = all(i == intr[0] for i in intr)
    ids = sorted(store.completed_indices()) if trajectories is None else list(trajectories)
    written = []
    for index in ids:
        entry = store.entry(index)
        frames = store.frames(index)
        dt = store.dt(index)
        target = out / f"traj_{index:04d}"
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=out))
        try:
            entries = []
            for t in range(frames.shape[0]):
                step = frames.read([t], slice(None))[0]
                for n, name in enumerate(names):
                    rel = f"images/{name}/frame_{t:04d}.png"
                    (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
                    iio.imwrite(tmp / rel, step[n], extension=".png")
                    item: dict[str, Any] = {"file_path": rel, "camera": name, "frame": t, "time": t * dt,
                                            "transform_matrix": camera_to_c2w_gl(cams[n]).tolist()}  # fmt: skip
                    if not shared:
                        item.update(intr[n])
                    entries.append(item)
            doc: dict[str, Any] = {"camera_model": "OPENCV", **(intr[0] if shared else {}), "fps": 1.0 / dt, "dt": dt,
                                   "num_frames": int(frames.shape[0]), "split": entry["split"],
                                   "clods_bench": {"format": FORMAT_VERSION, "trajectory": index, "seed": entry["seed"]}}  # fmt: skip
            if num_views_test is not None:
                doc["num_views_test"] = int(num_views_test)
            if interp_steps is not None:
                doc["interp_steps"] = int(interp_steps)
            if meshes != "none":
                from clods_bench.datasets.mesh_io import export_sequence

                traj = store.load_trajectory(index)
                export_sequence(traj, tmp / "meshes", meshes)
                write_npz(tmp / "meshes" / TOPOLOGY, cells=traj.cells, mesh_pos=traj.mesh_pos, node_type=traj.node_type)
                doc["mesh_path"] = "meshes"
            doc["frames"] = entries
            write_json(tmp / TRANSFORMS, doc)
            if target.exists():
                shutil.rmtree(target)
            os.replace(tmp, target)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp)
        written.append(target)
    return written


def read_transforms(path: Path) -> dict[str, Any]:
    """Parse a transforms.json; ClodsError naming the file when it is missing or not a JSON object."""
    path = Path(path)
    if not path.is_file():
        raise ClodsError("file not found", where=str(path))
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ClodsError(f"not valid JSON: {exc}", where=str(path)) from None
    if not isinstance(doc, dict):
        raise ClodsError(f"expected a JSON object at the top level, got {type(doc).__name__}", where=str(path))
    return doc
