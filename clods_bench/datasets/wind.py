"""Wind: a smooth turbulent velocity field and ArcSim-style aerodynamic forces on cloth faces.

Per face with unit normal n, current area A and relative air velocity v = wind(t, c) - u
(c the centroid, u the mean velocity of its 3 nodes): v_n = (v.n) n, v_t = v - v_n and
    f = air_density * A * |v.n| * v_n + drag * A * v_t,
split equally over the face's 3 nodes. The velocity Jacobian (n held fixed) is
    df_a/du_b = -(1/9) A (2 air_density |v.n| n n^T + drag (I - n n^T)),
negative semi-definite, so the integrator treats the wind semi-implicitly in velocity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from clods_bench.datasets.fixed_order import dot3


@dataclass(frozen=True)
class WindField:
    """Mean wind plus a sum of travelling sinusoids: U + sum_k a_k sin(w_k t - k_k . p + phi_k)."""

    mean: np.ndarray  # (3,) m/s
    amps: np.ndarray  # (K,3) m/s, amplitude vector of each mode
    omegas: np.ndarray  # (K,) rad/s
    wavevecs: np.ndarray  # (K,3) rad/m
    phases: np.ndarray  # (K,) rad

    def __call__(self, t: float, points: np.ndarray) -> np.ndarray:
        """Wind velocity (N,3) at time t and points (N,3)."""
        points = np.asarray(points, dtype=np.float64)
        arg = self.omegas[None, :] * t - dot3(points[:, None, :], self.wavevecs[None, :, :]) + self.phases[None, :]
        out = np.repeat(self.mean[None, :], points.shape[0], axis=0)
        for k in range(self.omegas.shape[0]):  # mode by mode, as wind_kernel sums them (no BLAS: see fixed_order)
            out += np.sin(arg[:, k])[:, None] * self.amps[k][None, :]
        return out


def make_wind_field(
    mean: tuple[float, float, float] | np.ndarray,
    amplitude: float,
    time_scale: float,
    rng: np.random.Generator,
    num_modes: int = 4,
) -> WindField:
    """Turbulent wind with RMS fluctuation `amplitude` (m/s, per component) and time scale `time_scale` (s).

    Mode frequencies are 2*pi/time_scale times a factor in [0.5, 1.5]; modes travel with the
    mean wind (frozen turbulence) plus a random transverse part, so nearby points are correlated.
    """
    mean = np.asarray(mean, dtype=np.float64).reshape(3)
    k = num_modes if amplitude > 0 else 0
    dirs = rng.standard_normal((k, 3))
    dirs /= np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-12)
    amps = dirs * amplitude * math.sqrt(2.0 / max(k, 1)) * math.sqrt(3.0)
    omegas = 2.0 * math.pi / max(time_scale, 1e-6) * rng.uniform(0.5, 1.5, k)
    speed = float(np.linalg.norm(mean))
    along = mean / speed if speed > 1e-9 else np.array([1.0, 0.0, 0.0])
    advect = max(speed, 1.0)
    trans = rng.standard_normal((k, 3))
    trans -= dot3(trans, along)[:, None] * along[None, :]
    wavevecs = (omegas / advect)[:, None] * (along[None, :] + 0.5 * trans)
    phases = rng.uniform(0.0, 2.0 * math.pi, k)
    return WindField(mean, amps, omegas, wavevecs, phases)


def ramp_factor(t: float, ramp_time: float) -> float:
    """Smoothstep from 0 at t=0 to 1 at t=ramp_time (1 when ramp_time is 0): wind starts gently."""
    if ramp_time <= 0 or t >= ramp_time:
        return 1.0
    s = max(t, 0.0) / ramp_time
    return s * s * (3.0 - 2.0 * s)


@numba.njit(cache=True)
def wind_kernel(x, v, cells, t, mean, amps, omegas, wavevecs, phases, air_density, drag, forces, blocks, tri_map, scale):
    """Add aerodynamic forces to `forces` and -scale * (force velocity Jacobian) blocks to `blocks`."""
    nk = omegas.shape[0]
    for f in range(cells.shape[0]):
        i0, i1, i2 = cells[f, 0], cells[f, 1], cells[f, 2]
        ax, ay, az = x[i1, 0] - x[i0, 0], x[i1, 1] - x[i0, 1], x[i1, 2] - x[i0, 2]
        bx, by, bz = x[i2, 0] - x[i0, 0], x[i2, 1] - x[i0, 1], x[i2, 2] - x[i0, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        if nn < 1e-300:
            continue
        area = 0.5 * nn
        n = (nx / nn, ny / nn, nz / nn)
        rel = np.empty(3)
        for d in range(3):
            rel[d] = mean[d] - (v[i0, d] + v[i1, d] + v[i2, d]) / 3.0
        if nk > 0:
            c = np.empty(3)
            for d in range(3):
                c[d] = (x[i0, d] + x[i1, d] + x[i2, d]) / 3.0
            for k in range(nk):
                s = math.sin(omegas[k] * t - (wavevecs[k, 0] * c[0] + wavevecs[k, 1] * c[1] + wavevecs[k, 2] * c[2]) + phases[k])
                for d in range(3):
                    rel[d] += amps[k, d] * s
        vn = rel[0] * n[0] + rel[1] * n[1] + rel[2] * n[2]
        cn = air_density * area * abs(vn)
        for d in range(3):
            fd = cn * vn * n[d] + drag * area * (rel[d] - vn * n[d])
            fd /= 3.0
            forces[i0, d] += fd
            forces[i1, d] += fd
            forces[i2, d] += fd
        if scale == 0.0:
            continue
        w = scale * area / 9.0
        for a in range(3):
            for b in range(3):
                blk = blocks[tri_map[f, a, b]]
                for d in range(3):
                    for e in range(3):
                        nne = n[d] * n[e]
                        eye = 1.0 if d == e else 0.0
                        blk[d, e] += w * (2.0 * air_density * abs(vn) * nne + drag * (eye - nne))
