"""Rigid obstacles the ground-truth cloth collides with: sphere, capsule, box, triangle mesh, recorded mesh.

An obstacle answers two questions. `query(x, t)`: for points x (N,3) at time t, the signed distance to its
surface (negative inside), the unit outward normal at the closest surface point and the surface velocity
there; the cloth solver's contact uses it (`clods_bench.datasets.cloth_solver`). `surface(t)`: a triangle
mesh of the surface with the same topology at every t, so a dataset can store it as OBSTACLE nodes per
frame. Analytic shapes (Sphere, Capsule, Box) have exact signed distances; the triangle mesh finds the
closest point by brute force (numba; `obstacle_meshes`) and signs it with the angle-weighted pseudo-normal
of the closest feature (Baerentzen & Aanaes 2005), exact for closed meshes; for an open mesh the side the
face normals point away from counts as inside.

Obstacles move rigidly along an optional `ObstaclePath` (smoothed piecewise-linear translation, so their
velocity is continuous); `TriangleMeshObstacle.from_frames` replays recorded vertex positions instead.
Like scene cloths, obstacles are frozen dataclasses holding data only: picklable to generation workers and
hashed field by field into the dataset identity.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from clods_bench.datasets.fixed_order import dot3
from clods_bench.datasets.obstacle_meshes import (
    cached_edge_ids,
    icosphere,
    mesh_arrays,
    mesh_query,
    orient_outward,
    unit_vectors,
    validate_mesh,
)
from clods_bench.errors import ClodsError

Vec3 = tuple[float, float, float]


def _vec3(value, where: str) -> np.ndarray:
    try:
        vec = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ClodsError(f"must be 3 finite numbers, got {value!r}", where=where) from None
    if vec.shape != (3,) or not np.isfinite(vec).all():
        raise ClodsError(f"must be 3 finite numbers, got {value!r}", where=where)
    return vec


def _positive(value, where: str) -> None:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value > 0):
        raise ClodsError(f"must be a positive finite number, got {value!r}", where=where)


def _points(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ClodsError(f"points must have shape (N, 3), got {x.shape}", where="Obstacle.query")
    return x


@dataclass(frozen=True)
class ObstaclePath:
    """Prescribed rigid translation: piecewise linear offsets at increasing times, smoothed (C1) so velocity has no
    jumps; held constant after the last time and before the first.

    Between times[i] and times[i+1] the offset blends from offsets[i] to offsets[i+1] with the smoothstep
    w(s) = 3 s^2 - 2 s^3, s the fraction of the segment: the velocity is zero at every time in `times` and
    continuous everywhere; the largest speed in a segment is 1.5 times its mean speed."""

    times: tuple[float, ...]
    offsets: tuple[Vec3, ...]

    def _segment(self, t: float) -> tuple[int, float] | None:
        times = self.times
        if len(times) < 2 or t <= times[0] or t >= times[-1]:
            return None
        i = int(np.searchsorted(np.asarray(times, dtype=np.float64), t, side="right")) - 1
        return i, (t - times[i]) / (times[i + 1] - times[i])

    def offset(self, t: float) -> np.ndarray:
        """The translation (3,) at time t."""
        offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        seg = self._segment(float(t))
        if seg is None:
            return offsets[0].copy() if t <= self.times[0] else offsets[-1].copy()
        i, s = seg
        return offsets[i] + (s * s * (3.0 - 2.0 * s)) * (offsets[i + 1] - offsets[i])

    def velocity(self, t: float) -> np.ndarray:
        """The analytic derivative (3,) of `offset` at time t (zero outside [times[0], times[-1]])."""
        seg = self._segment(float(t))
        if seg is None:
            return np.zeros(3)
        i, s = seg
        offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        return (6.0 * s * (1.0 - s) / (self.times[i + 1] - self.times[i])) * (offsets[i + 1] - offsets[i])

    def validate(self, where: str) -> None:
        """ClodsError naming the field: lengths differ or are 0, times not finite or not strictly increasing, bad offsets."""
        if len(self.times) < 1 or len(self.times) != len(self.offsets):
            raise ClodsError(
                f"times and offsets need the same length >= 1, got {len(self.times)} and {len(self.offsets)}", where=f"{where}.times"
            )
        times = np.asarray(self.times, dtype=np.float64)
        if times.ndim != 1 or not np.isfinite(times).all():
            raise ClodsError(f"must be finite numbers, got {self.times!r}", where=f"{where}.times")
        if np.any(np.diff(times) <= 0):
            raise ClodsError(f"must be strictly increasing, got {self.times!r}", where=f"{where}.times")
        for i, off in enumerate(self.offsets):
            _vec3(off, f"{where}.offsets[{i}]")


class Obstacle(abc.ABC):
    """A rigid obstacle; subclasses are frozen dataclasses holding data only (picklable; hashed into dataset identity)."""

    path: ObstaclePath | None = None  # every subclass declares it as a field

    @abc.abstractmethod
    def query(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For points x (N,3) at time t: signed distance (N,) to the surface (negative inside), unit outward normal
        (N,3) at the closest surface point, and the obstacle's surface velocity (N,3) there."""

    @abc.abstractmethod
    def surface(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """A triangle mesh of the surface at t: vertices (M,3) float64, faces (F,3) int32, outward CCW; same topology at every t."""

    def validate(self, where: str) -> None:
        """ClodsError naming `where` and the field for out-of-range values."""
        if self.path is not None:
            if not isinstance(self.path, ObstaclePath):
                raise ClodsError(f"is a {type(self.path).__name__}, expected an ObstaclePath or None", where=f"{where}.path")
            self.path.validate(f"{where}.path")


class MovingShape(Obstacle):
    """An obstacle of fixed shape translated along its `path`: subclasses give the shape's signed distance and surface
    in its own (unmoved) frame; `query` and `surface` translate by the path's offset and report the path's velocity."""

    def _offset(self, t: float) -> np.ndarray:
        return np.zeros(3) if self.path is None else self.path.offset(t)

    def query(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Signed distance, outward normal and surface velocity of points x (N,3) at time t (see `Obstacle.query`)."""
        x = _points(x)
        d, n = self._local_query(x - self._offset(t))
        vel = np.zeros((x.shape[0], 3)) if self.path is None else np.tile(self.path.velocity(t), (x.shape[0], 1))
        return d, n, vel

    def surface(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The shape's surface mesh translated to time t (see `Obstacle.surface`)."""
        verts, faces = self._local_surface()
        return verts + self._offset(t)[None, :], faces

    @abc.abstractmethod
    def _local_query(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance and outward normal of points y (N,3) given in the unmoved obstacle's frame."""

    @abc.abstractmethod
    def _local_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """The surface mesh of the unmoved obstacle."""


@dataclass(frozen=True)
class Sphere(MovingShape):
    """A ball; its surface mesh is an icosphere of `subdivisions` (2: 320 triangles)."""

    center: Vec3
    radius: float
    path: ObstaclePath | None = None
    subdivisions: int = 2

    def _local_query(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = y - np.asarray(self.center, dtype=np.float64)[None, :]
        return np.linalg.norm(rel, axis=1) - self.radius, unit_vectors(rel, np.array([0.0, 0.0, 1.0]))

    def _local_surface(self) -> tuple[np.ndarray, np.ndarray]:
        verts, faces = icosphere(self.subdivisions)
        return verts * self.radius + np.asarray(self.center, dtype=np.float64)[None, :], faces

    def validate(self, where: str) -> None:
        _vec3(self.center, f"{where}.center")
        _positive(self.radius, f"{where}.radius")
        if not (isinstance(self.subdivisions, (int, np.integer)) and 0 <= self.subdivisions <= 5):
            raise ClodsError(f"must be an integer in 0..5, got {self.subdivisions!r}", where=f"{where}.subdivisions")
        super().validate(where)


def _perpendicular(e: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to the unit vector e."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(e[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(e, helper)
    return u / np.linalg.norm(u)


@dataclass(frozen=True)
class Capsule(MovingShape):
    """All points within `radius` of the segment a-b; surface: a 16-sided cylinder closed by two hemispheres (4 rings each)."""

    a: Vec3
    b: Vec3
    radius: float
    path: ObstaclePath | None = None

    AROUND = 16
    RINGS = 4  # per hemisphere, the equator included

    def _axis(self) -> tuple[np.ndarray, np.ndarray, float]:
        a = np.asarray(self.a, dtype=np.float64)
        ab = np.asarray(self.b, dtype=np.float64) - a
        length = float(np.linalg.norm(ab))
        return a, (ab / length if length > 0 else np.array([0.0, 0.0, 1.0])), length

    def _closest_on_axis(self, y: np.ndarray) -> np.ndarray:
        a, e, length = self._axis()
        s = np.clip(dot3(y - a[None, :], e), 0.0, length)
        return a[None, :] + s[:, None] * e[None, :]

    def _local_query(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = y - self._closest_on_axis(y)
        _, e, _ = self._axis()
        return np.linalg.norm(rel, axis=1) - self.radius, unit_vectors(rel, _perpendicular(e))

    def _local_surface(self) -> tuple[np.ndarray, np.ndarray]:
        a, e, length = self._axis()
        u = _perpendicular(e)
        w = np.cross(e, u)
        theta = 2.0 * math.pi * np.arange(self.AROUND) / self.AROUND
        around = np.cos(theta)[:, None] * u[None, :] + np.sin(theta)[:, None] * w[None, :]
        r, nr = float(self.radius), self.RINGS
        rings = []
        for j in range(1, nr + 1):  # hemisphere at a, from its pole to the equator
            phi = 0.5 * math.pi * j / nr
            rings.append(a - r * math.cos(phi) * e + r * math.sin(phi) * around)
        b = a + length * e
        for j in range(nr, 0, -1):  # hemisphere at b, from the equator to its pole
            phi = 0.5 * math.pi * j / nr
            rings.append(b + r * math.cos(phi) * e + r * math.sin(phi) * around)
        verts = np.concatenate([(a - r * e)[None], *rings, (b + r * e)[None]])
        n, k = self.AROUND, np.arange(self.AROUND)
        k1 = (k + 1) % n
        faces = [np.stack([np.zeros(n, int), 1 + k1, 1 + k], axis=1)]
        for i in range(2 * nr - 1):
            lo, hi = 1 + i * n, 1 + (i + 1) * n
            faces += [np.stack([lo + k, lo + k1, hi + k1], axis=1), np.stack([lo + k, hi + k1, hi + k], axis=1)]
        top, last = verts.shape[0] - 1, 1 + (2 * nr - 1) * n
        faces.append(np.stack([np.full(n, top), last + k, last + k1], axis=1))
        return verts, orient_outward(verts, np.concatenate(faces), self._closest_on_axis)

    def validate(self, where: str) -> None:
        _vec3(self.a, f"{where}.a")
        _vec3(self.b, f"{where}.b")
        _positive(self.radius, f"{where}.radius")
        super().validate(where)


@dataclass(frozen=True)
class Box(MovingShape):
    """An axis-aligned box: exact signed distance; surface of 12 triangles."""

    center: Vec3
    half_extents: Vec3
    path: ObstaclePath | None = None

    def _local_query(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = y - np.asarray(self.center, dtype=np.float64)[None, :]
        sign = np.where(rel >= 0, 1.0, -1.0)
        q = np.abs(rel) - np.asarray(self.half_extents, dtype=np.float64)[None, :]
        out = np.maximum(q, 0.0)
        outside = np.linalg.norm(out, axis=1)
        inside = np.minimum(q.max(axis=1), 0.0)
        # outside: the gradient of the distance (face, edge or corner); inside: the nearest face
        face = np.zeros_like(q)
        face[np.arange(q.shape[0]), np.argmax(q, axis=1)] = 1.0
        is_out = outside > 0
        normal = np.where(is_out[:, None], out / np.where(is_out, outside, 1.0)[:, None], face) * sign
        return outside + inside, normal

    def _local_surface(self) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(self.center, dtype=np.float64)
        h = np.asarray(self.half_extents, dtype=np.float64)
        corners = np.array([[(i >> 0) & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64) * 2 - 1
        verts = c[None, :] + corners * h[None, :]
        quads = [(0, 2, 6, 4), (1, 3, 7, 5), (0, 1, 5, 4), (2, 3, 7, 6), (0, 1, 3, 2), (4, 5, 7, 6)]
        faces = np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))], dtype=np.int32)
        return verts, orient_outward(verts, faces, lambda cen: np.broadcast_to(c, cen.shape))

    def validate(self, where: str) -> None:
        _vec3(self.center, f"{where}.center")
        h = _vec3(self.half_extents, f"{where}.half_extents")
        if not (h > 0).all():
            raise ClodsError(f"must be 3 positive numbers, got {self.half_extents!r}", where=f"{where}.half_extents")
        super().validate(where)


@dataclass(frozen=True, eq=False)
class TriangleMeshObstacle(MovingShape):
    """A rigid triangle mesh, outward CCW faces; closed meshes are solid, open ones are solid behind their faces."""

    vertices: np.ndarray  # (M,3)
    faces: np.ndarray  # (F,3)
    path: ObstaclePath | None = None

    def _edges(self) -> np.ndarray:
        return cached_edge_ids(self)

    def _local_query(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        verts, faces = mesh_arrays(self.vertices, self.faces)
        d, n, _, _ = mesh_query(y, verts, faces, self._edges())
        return d, n

    def _local_surface(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.vertices, dtype=np.float64), np.array(self.faces, dtype=np.int32)

    def validate(self, where: str) -> None:
        verts = np.asarray(self.vertices)
        if verts.ndim != 2 or verts.shape[1] != 3 or verts.shape[0] < 3:
            raise ClodsError(f"must be an (M, 3) array with M >= 3, got shape {verts.shape}", where=f"{where}.vertices")
        validate_mesh(verts.astype(np.float64), np.asarray(self.faces), where, "vertices")
        super().validate(where)

    @classmethod
    def from_frames(cls, frames: np.ndarray, faces: np.ndarray, dt: float, start_time: float = 0.0) -> "FrameMeshObstacle":
        """An obstacle whose vertices follow recorded positions `frames` (T,M,3), frame k at start_time + k dt.

        Positions are interpolated linearly in time and held before the first and after the last frame; the
        surface velocity is the finite difference of the frames (the derivative of that interpolation)."""
        return FrameMeshObstacle(np.asarray(frames, dtype=np.float64), np.asarray(faces), float(dt), start_time=float(start_time))


@dataclass(frozen=True, eq=False)
class FrameMeshObstacle(Obstacle):
    """A triangle mesh replaying recorded vertex positions (see `TriangleMeshObstacle.from_frames`); `path` adds a translation."""

    frames: np.ndarray  # (T,M,3)
    faces: np.ndarray  # (F,3)
    dt: float
    path: ObstaclePath | None = None
    start_time: float = 0.0

    def _state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Vertex positions (M,3) and velocities (M,3) at time t (path included)."""
        frames = np.asarray(self.frames, dtype=np.float64)
        u = (float(t) - self.start_time) / self.dt
        last = frames.shape[0] - 1
        if u < 0 or last == 0:
            pos, vel = frames[0].copy(), np.zeros_like(frames[0])
        elif u >= last:
            pos, vel = frames[last].copy(), np.zeros_like(frames[0])
        else:
            k = min(int(math.floor(u)), last - 1)
            s = u - k
            pos = (1.0 - s) * frames[k] + s * frames[k + 1]
            vel = (frames[k + 1] - frames[k]) / self.dt
        if self.path is not None:
            pos += self.path.offset(t)[None, :]
            vel += self.path.velocity(t)[None, :]
        return pos, vel

    def _edges(self) -> np.ndarray:
        return cached_edge_ids(self)

    def query(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = _points(x)
        pos, vel = self._state(t)
        verts, faces = mesh_arrays(pos, self.faces)
        d, n, face, bary = mesh_query(x, verts, faces, self._edges())
        return d, n, np.einsum("nk,nki->ni", bary, vel[faces[face]])

    def surface(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        pos, _ = self._state(t)
        return pos, np.array(self.faces, dtype=np.int32)

    def validate(self, where: str) -> None:
        frames = np.asarray(self.frames)
        if frames.ndim != 3 or frames.shape[2] != 3 or frames.shape[0] < 1 or frames.shape[1] < 3:
            raise ClodsError(f"must be a (T, M, 3) array with T >= 1, M >= 3, got shape {frames.shape}", where=f"{where}.frames")
        validate_mesh(frames.astype(np.float64), np.asarray(self.faces), where, "frames")
        _positive(self.dt, f"{where}.dt")
        if not math.isfinite(self.start_time):
            raise ClodsError(f"must be finite, got {self.start_time!r}", where=f"{where}.start_time")
        super().validate(where)


def overlap(obstacles: Sequence[Obstacle], x: np.ndarray, t: float, margin: float = 0.0) -> np.ndarray:
    """(N,) bool: points x (N,3) closer than `margin` to (or inside) any obstacle at time t."""
    x = _points(x)
    out = np.zeros(x.shape[0], dtype=bool)
    for obstacle in obstacles:
        d, _, _ = obstacle.query(x, t)
        out |= d < margin
    return out
