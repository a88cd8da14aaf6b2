"""Pinhole cameras in the OpenCV convention and camera rigs around the cloth.

Convention (the only one in clods-bench): camera x right, y down, z forward;
`R`, `t` map world to camera, x_cam = R @ x_world + t. Pixel (row r, col c)
covers [c, c+1) x [r, r+1) in image coordinates, so its centre is (c+0.5, r+0.5);
a camera point projects to u = fx*x/z + cx, v = fy*y/z + cy. With cx = W/2 the
optical axis goes through the image centre.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from clods_bench.datasets.fixed_order import apply3
from clods_bench.errors import ClodsError


_VALID: "OrderedDict[bytes, None]" = OrderedDict()  # value keys of cameras that passed `Camera.validate`
_VALID_SIZE = 256


@dataclass(frozen=True)
class Camera:
    """Intrinsics K (3,3), world-to-camera rotation R (3,3) and translation t (3,), image size."""

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    def validate(self, where: str = "camera") -> None:
        """Raise ClodsError if intrinsics or extrinsics are unusable (a camera of values that passed before is not
        checked again: renderers validate their cameras on every call, e.g. every stage-2 iteration)."""
        key = self._value_key()
        if key is not None and key in _VALID:
            _VALID.move_to_end(key)
            return
        self._check(where)
        if key is not None:
            _VALID[key] = None
            while len(_VALID) > _VALID_SIZE:
                _VALID.popitem(last=False)

    def _value_key(self) -> bytes | None:
        """The camera's values as bytes (None when they are not numeric arrays, which `_check` then reports)."""
        try:
            parts = [np.ascontiguousarray(x, dtype=np.float64) for x in (self.K, self.R, self.t)]
            size = np.array([self.width, self.height], dtype=np.float64)
        except (TypeError, ValueError):
            return None
        return b"|".join([str([p.shape for p in parts]).encode(), *(p.tobytes() for p in parts), size.tobytes()])

    def _check(self, where: str) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all():
            raise ClodsError(f"K must be a finite 3x3 matrix, got shape {K.shape}", where=f"{where}.K")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ClodsError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}", where=f"{where}.K")
        if self.width <= 0 or self.height <= 0:
            raise ClodsError(f"image size must be positive, got {self.width}x{self.height}", where=where)
        R = np.asarray(self.R, dtype=np.float64)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
            raise ClodsError("R must be a proper rotation matrix", where=f"{where}.R")
        if np.asarray(self.t).shape != (3,) or not np.isfinite(self.t).all():
            raise ClodsError("t must be a finite 3-vector", where=f"{where}.t")

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return -apply3(self.R.T, self.t[None, :])[0]

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """(N,3) world points to (N,3) camera coordinates."""
        return apply3(self.R, points) + self.t  # not `@`: the same bits on every CPU (fixed_order)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) world points to (N,2) pixel coordinates (u, v) and (N,) depths z."""
        pc = self.world_to_camera(np.asarray(points, dtype=np.float64))
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.K[0, 0] * pc[:, 0] / z + self.K[0, 2]
            v = self.K[1, 1] * pc[:, 1] / z + self.K[1, 2]
        return np.stack([u, v], axis=1), z

    def to_dict(self) -> dict:
        return {"K": self.K.tolist(), "R": self.R.tolist(), "t": self.t.tolist(), "width": self.width, "height": self.height}

    @staticmethod
    def from_dict(d: dict) -> "Camera":
        return Camera(np.asarray(d["K"], float), np.asarray(d["R"], float), np.asarray(d["t"], float), int(d["width"]), int(d["height"]))


def intrinsics_from_fov(fov_deg: float, width: int, height: int) -> np.ndarray:
    """K for a horizontal field of view in degrees, square pixels, principal point at the centre."""
    if not (0.0 < fov_deg < 180.0):
        raise ClodsError(f"field of view must be in (0, 180) degrees, got {fov_deg}", where="camera.fov_deg")
    fx = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[fx, 0.0, width / 2.0], [0.0, fx, height / 2.0], [0.0, 0.0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) for a camera at `eye` looking at `target`, image 'up' roughly along `up`."""
    eye = np.asarray(eye, float)
    forward = np.asarray(target, float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-8:  # looking along `up`: pick any perpendicular
        right = np.cross(forward, np.array([1.0, 0.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward], axis=0)
    return R, -apply3(R, eye[None, :])[0]


def camera_rig(
    num_cameras: int,
    target: np.ndarray,
    radius: float,
    width: int,
    height: int,
    fov_deg: float = 30.0,
    elevations_deg: tuple[float, ...] = (15.0, -10.0),
    up: np.ndarray = np.array([0.0, 0.0, 1.0]),
    phase_deg: float = 0.0,
) -> list[Camera]:
    """`num_cameras` cameras on a sphere of `radius` around `target`, all looking at it.

    Azimuths are spread evenly (golden-angle offset between rings), elevations cycle
    through `elevations_deg`, so views cover the cloth from all sides like the paper's rig.
    """
    if num_cameras < 1:
        raise ClodsError(f"need at least one camera, got {num_cameras}", where="data.num_cameras")
    K = intrinsics_from_fov(fov_deg, width, height)
    target = np.asarray(target, float)
    cams = []
    for i in range(num_cameras):
        az = math.radians(phase_deg + 360.0 * i / num_cameras)
        el = math.radians(elevations_deg[i % len(elevations_deg)])
        offset = radius * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        R, t = look_at(target + offset, target, up)
        cams.append(Camera(K.copy(), R, t, width, height))
    return cams
