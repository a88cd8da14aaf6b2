"""Cloth energies: StVK membrane triangles (stretch + shear) and the quadratic bending model.

Membrane: per triangle, F = Ds Dm^-1 maps the 2D rest triangle to 3D, Green strain
E = (F^T F - I)/2, energy A (mu tr(E^2) + lambda/2 tr(E)^2) with mu, lambda in N/m. The rest
triangle is the one of `rest_pos` laid flat in its own plane: for a flat mesh this is the
mesh-space triangle; it also stays right across uv seams (cylinder) where `mesh_pos` jumps.
Its Hessian is J^T C J (Gauss-Newton, PSD) plus the geometric term (g_a^T S g_b) I; with
`project` the 2x2 stress S is clamped to its positive part so the whole Hessian is PSD.

Bending (Bergou et al. 2006, "A quadratic bending model for inextensible surfaces"): per
interior edge, K = cotangent stencil over its 4 nodes, Q_e = 3/(A0+A1) K K^T, energy
(k/2) x^T Q x. The rest shape is flat (zero rest curvature, as for fabric cut flat), the
Hessian k Q is constant. For a sheet bent to radius R this is about (k/2) area / R^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from clods_bench.datasets.types import ClothMesh
from clods_bench.errors import ClodsError


@dataclass
class RestGeometry:
    """Precomputed rest quantities of a cloth mesh used by the energies."""

    cells: np.ndarray  # (F,3) int64
    dm_inv: np.ndarray  # (F,2,2) inverse rest edge matrices
    area: np.ndarray  # (F,) rest areas
    hinges: np.ndarray  # (H,4) int64: edge nodes x0, x1, opposite nodes x2, x3
    hinge_k: np.ndarray  # (H,4) cotangent stencils K
    hinge_w: np.ndarray  # (H,) weights 3/(A0+A1)


def rest_geometry(mesh: ClothMesh) -> RestGeometry:
    """Rest triangles laid flat, their inverse edge matrices and areas, plus the bending hinges."""
    cells = np.asarray(mesh.cells, dtype=np.int64)
    x = np.asarray(mesh.rest_pos, dtype=np.float64)
    e1 = x[cells[:, 1]] - x[cells[:, 0]]
    e2 = x[cells[:, 2]] - x[cells[:, 0]]
    a = np.linalg.norm(e1, axis=1)
    cross = np.linalg.norm(np.cross(e1, e2), axis=1)
    bad = np.flatnonzero(~(cross > 1e-12 * np.maximum(a, 1e-300) ** 2))
    if bad.size:
        raise ClodsError(f"{bad.size} degenerate rest triangles (zero area), first is face {bad[0]}", where="mesh.rest_pos")
    dm = np.zeros((cells.shape[0], 2, 2))
    dm[:, 0, 0] = a
    dm[:, 0, 1] = np.einsum("fi,fi->f", e2, e1) / a
    dm[:, 1, 1] = cross / a
    hinges = find_hinges(cells)
    hinge_k, hinge_w = bending_stencils(x, hinges)
    # dm is upper triangular: its inverse written out (np.linalg.inv calls LAPACK, whose kernels differ per CPU)
    dm_inv = np.zeros_like(dm)
    dm_inv[:, 0, 0] = 1.0 / dm[:, 0, 0]
    dm_inv[:, 0, 1] = -dm[:, 0, 1] / (dm[:, 0, 0] * dm[:, 1, 1])
    dm_inv[:, 1, 1] = 1.0 / dm[:, 1, 1]
    return RestGeometry(cells, dm_inv, 0.5 * cross, hinges, hinge_k, hinge_w)


def find_hinges(cells: np.ndarray) -> np.ndarray:
    """(H,4) [x0, x1, x2, x3] for every edge shared by exactly two triangles (x2, x3 opposite)."""
    cells = np.asarray(cells, dtype=np.int64)
    e = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]], axis=0)
    opp = np.concatenate([cells[:, 2], cells[:, 0], cells[:, 1]])
    lo, hi = e.min(axis=1), e.max(axis=1)
    code = lo * (int(cells.max()) + 1) + hi
    order = np.argsort(code, kind="stable")
    _, first, count = np.unique(code[order], return_index=True, return_counts=True)
    s = order[first[count == 2]]
    s2 = order[first[count == 2] + 1]
    return np.stack([e[s, 0], e[s, 1], opp[s], opp[s2]], axis=1)


def _cot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("hi,hi->h", u, v) / np.linalg.norm(np.cross(u, v), axis=1)


def bending_stencils(x: np.ndarray, hinges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cotangent stencils K (H,4) and weights 3/(A0+A1) (H,) of the quadratic bending model."""
    x0, x1, x2, x3 = (x[hinges[:, i]] for i in range(4))
    e0, e1, e2, e3, e4 = x1 - x0, x2 - x0, x3 - x0, x2 - x1, x3 - x1
    c01, c02 = _cot(e0, e1), _cot(e0, e2)
    c03, c04 = _cot(-e0, e3), _cot(-e0, e4)
    k = np.stack([c03 + c04, c01 + c02, -c01 - c03, -c02 - c04], axis=1)
    areas = 0.5 * (np.linalg.norm(np.cross(e0, e1), axis=1) + np.linalg.norm(np.cross(e0, e2), axis=1))
    return k, 3.0 / areas


@numba.njit(cache=True)
def _stress_positive_part(s00: float, s01: float, s11: float) -> tuple[float, float, float]:
    """Clamp the eigenvalues of the symmetric 2x2 stress to >= 0."""
    mid = 0.5 * (s00 + s11)
    rad = np.sqrt(0.25 * (s00 - s11) ** 2 + s01 * s01)
    l1, l2 = mid + rad, mid - rad
    if l2 >= 0.0:
        return s00, s01, s11
    if l1 <= 0.0:
        return 0.0, 0.0, 0.0
    # eigenvector of l1
    vx, vy = s01, l1 - s00
    wx, wy = l1 - s11, s01
    if wx * wx + wy * wy > vx * vx + vy * vy:
        vx, vy = wx, wy
    n2 = vx * vx + vy * vy
    if n2 <= 0.0:
        return max(s00, 0.0), 0.0, max(s11, 0.0)
    return l1 * vx * vx / n2, l1 * vx * vy / n2, l1 * vy * vy / n2


@numba.njit(cache=True)
def membrane_kernel(x, cells, dm_inv, area, mu, lam, forces, blocks, tri_map, scale, hessian, project):
    """Add membrane forces to `forces` and scale * Hessian blocks to `blocks`; return the energy."""
    energy = 0.0
    g = np.empty((3, 2))
    fcol = np.empty((2, 3))
    jac = np.empty((3, 3, 3))  # node, strain component (E00, E11, 2E01), xyz
    cj = np.empty((3, 3, 3))
    c = np.array([[2 * mu + lam, lam, 0.0], [lam, 2 * mu + lam, 0.0], [0.0, 0.0, mu]])
    for f in range(cells.shape[0]):
        bm = dm_inv[f]
        g[1, 0], g[1, 1], g[2, 0], g[2, 1] = bm[0, 0], bm[0, 1], bm[1, 0], bm[1, 1]
        g[0, 0], g[0, 1] = -g[1, 0] - g[2, 0], -g[1, 1] - g[2, 1]
        for j in range(2):
            for d in range(3):
                fcol[j, d] = g[0, j] * x[cells[f, 0], d] + g[1, j] * x[cells[f, 1], d] + g[2, j] * x[cells[f, 2], d]
        e00 = 0.5 * (fcol[0, 0] ** 2 + fcol[0, 1] ** 2 + fcol[0, 2] ** 2 - 1.0)
        e11 = 0.5 * (fcol[1, 0] ** 2 + fcol[1, 1] ** 2 + fcol[1, 2] ** 2 - 1.0)
        e01 = 0.5 * (fcol[0, 0] * fcol[1, 0] + fcol[0, 1] * fcol[1, 1] + fcol[0, 2] * fcol[1, 2])
        tr = e00 + e11
        s00, s11, s01 = 2 * mu * e00 + lam * tr, 2 * mu * e11 + lam * tr, 2 * mu * e01
        a = area[f]
        energy += a * (mu * (e00 * e00 + e11 * e11 + 2 * e01 * e01) + 0.5 * lam * tr * tr)
        for n in range(3):
            for d in range(3):
                p0 = fcol[0, d] * s00 + fcol[1, d] * s01
                p1 = fcol[0, d] * s01 + fcol[1, d] * s11
                forces[cells[f, n], d] -= a * (p0 * g[n, 0] + p1 * g[n, 1])
        if not hessian:
            continue
        for n in range(3):
            for d in range(3):
                jac[n, 0, d] = g[n, 0] * fcol[0, d]
                jac[n, 1, d] = g[n, 1] * fcol[1, d]
                jac[n, 2, d] = g[n, 0] * fcol[1, d] + g[n, 1] * fcol[0, d]
            for p in range(3):
                for d in range(3):
                    cj[n, p, d] = c[p, 0] * jac[n, 0, d] + c[p, 1] * jac[n, 1, d] + c[p, 2] * jac[n, 2, d]
        if project:
            s00, s01, s11 = _stress_positive_part(s00, s01, s11)
        w = scale * a
        for na in range(3):
            for nb in range(3):
                blk = blocks[tri_map[f, na, nb]]
                geo = g[na, 0] * (s00 * g[nb, 0] + s01 * g[nb, 1]) + g[na, 1] * (s01 * g[nb, 0] + s11 * g[nb, 1])
                for d in range(3):
                    blk[d, d] += w * geo
                    for e in range(3):
                        blk[d, e] += w * (jac[na, 0, d] * cj[nb, 0, e] + jac[na, 1, d] * cj[nb, 1, e] + jac[na, 2, d] * cj[nb, 2, e])
    return energy


def lame_from_young(young: float, poisson: float) -> tuple[float, float]:
    """Plane-stress Lamé parameters (mu, lambda) in N/m from a 2D Young modulus and Poisson ratio."""
    return young / (2.0 * (1.0 + poisson)), young * poisson / (1.0 - poisson**2)


def membrane_energy_forces(x: np.ndarray, geo: RestGeometry, mu: float, lam: float) -> tuple[float, np.ndarray]:
    """Membrane energy and forces (V,3) at positions x, for checks and diagnostics."""
    forces = np.zeros_like(x, dtype=np.float64)
    dummy = np.zeros((1, 3, 3))
    tri_map = np.zeros((1, 3, 3), dtype=np.int64)
    e = membrane_kernel(np.asarray(x, np.float64), geo.cells, geo.dm_inv, geo.area, mu, lam, forces, dummy, tri_map, 0.0, False, False)
    return float(e), forces


def membrane_hessian_dense(x: np.ndarray, geo: RestGeometry, mu: float, lam: float, project: bool) -> np.ndarray:
    """Dense (3V,3V) membrane Hessian (exact when project=False) for tests on small meshes."""
    v = x.shape[0]
    f = geo.cells.shape[0]
    blocks = np.zeros((f * 9, 3, 3))
    tri_map = np.arange(f * 9, dtype=np.int64).reshape(f, 3, 3)
    membrane_kernel(np.asarray(x, np.float64), geo.cells, geo.dm_inv, geo.area, mu, lam, np.zeros((v, 3)), blocks, tri_map, 1.0, True, project)
    h = np.zeros((v, 3, v, 3))
    for fi in range(f):
        for a in range(3):
            for b in range(3):
                h[geo.cells[fi, a], :, geo.cells[fi, b], :] += blocks[tri_map[fi, a, b]]
    return h.reshape(3 * v, 3 * v)


def bending_matrix(geo: RestGeometry, num_nodes: int):  # -> scipy.sparse.csr_matrix
    """The (V,V) scalar matrix Q with bending energy (k/2) sum_d x[:,d]^T Q x[:,d]."""
    import scipy.sparse as sp

    h = geo.hinges
    vals = geo.hinge_w[:, None, None] * geo.hinge_k[:, :, None] * geo.hinge_k[:, None, :]
    rows = np.repeat(h, 4, axis=1).ravel()
    cols = np.tile(h, (1, 4)).ravel()
    return sp.csr_matrix((vals.ravel(), (rows, cols)), shape=(num_nodes, num_nodes))


def bending_energy(x: np.ndarray, q) -> float:
    """Quadratic bending energy (without the stiffness factor k): x^T Q x / 2 summed over xyz."""
    return 0.5 * float(np.einsum("vd,vd->", x, q @ x))
