"""Step 5 of `sheet_mesh.sheet_from_points`: the sheet's `mesh_pos`, a 2D layout whose edge lengths best match the
3D rest edges (nonlinear least squares from the (u, v) grid, a hinge per triangle against folding over).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from clods_bench.datasets.types import edges_from_cells


def signed_areas(uv: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Signed area of each triangle of `cells` in the 2D layout `uv` (positive: counter-clockwise)."""
    a, b, c = uv[cells[:, 0]], uv[cells[:, 1]], uv[cells[:, 2]]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


FOLD_MIN = 0.1
"""`flatten_geodesic` keeps every triangle's signed area above this fraction of its 3D area (a hinge residual)."""
FLATTEN_MAX_EVALUATIONS = 5000
"""Residual evaluations of the flattening's least squares at most (about 3 s for 128 nodes)."""
FOLD_WEIGHT = 10.0
"""Weight of that hinge against the relative edge-length residuals."""


def flatten_problem(rest: np.ndarray, cells: np.ndarray) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], Any]]:
    """(residual, sparse Jacobian) of `flatten_geodesic` over the flattened (V*2,) layout: relative edge-length
    errors, then the fold hinge FOLD_WEIGHT * min(0, signed area / 3D area - FOLD_MIN) per triangle."""
    from scipy.sparse import csr_matrix

    edges = edges_from_cells(cells)
    length = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    tri = rest[cells]
    area3 = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    n_e, n_v, n_f = edges.shape[0], rest.shape[0], cells.shape[0]
    rows = np.concatenate([np.repeat(np.arange(n_e), 4), n_e + np.repeat(np.arange(n_f), 6)])
    cols = np.concatenate([
        np.stack([2 * edges[:, 0], 2 * edges[:, 0] + 1, 2 * edges[:, 1], 2 * edges[:, 1] + 1], 1).ravel(),
        np.stack([2 * cells[:, 0], 2 * cells[:, 0] + 1, 2 * cells[:, 1], 2 * cells[:, 1] + 1, 2 * cells[:, 2], 2 * cells[:, 2] + 1], 1).ravel(),
    ])  # fmt: skip

    def residual(x: np.ndarray) -> np.ndarray:
        m = x.reshape(n_v, 2)
        edge = (np.linalg.norm(m[edges[:, 0]] - m[edges[:, 1]], axis=1) - length) / length
        fold = FOLD_WEIGHT * np.minimum(signed_areas(m, cells) / area3 - FOLD_MIN, 0.0)
        return np.concatenate([edge, fold])

    def jac(x: np.ndarray) -> csr_matrix:
        m = x.reshape(n_v, 2)
        dvec = m[edges[:, 0]] - m[edges[:, 1]]
        g = dvec / (np.linalg.norm(dvec, axis=1, keepdims=True) * length[:, None])
        a, b, c = m[cells[:, 0]], m[cells[:, 1]], m[cells[:, 2]]
        d_area = 0.5 * np.stack([b[:, 1] - c[:, 1], c[:, 0] - b[:, 0], c[:, 1] - a[:, 1], a[:, 0] - c[:, 0],
                                 a[:, 1] - b[:, 1], b[:, 0] - a[:, 0]], axis=1)  # fmt: skip
        active = signed_areas(m, cells) / area3 < FOLD_MIN
        d_area *= (FOLD_WEIGHT * active / area3)[:, None]
        vals = np.concatenate([np.concatenate([g, -g], axis=1).ravel(), d_area.ravel()])
        return csr_matrix((vals, (rows, cols)), shape=(n_e + n_f, 2 * n_v))

    return residual, jac


def flatten_geodesic(rest: np.ndarray, cells: np.ndarray, init: np.ndarray) -> np.ndarray:
    """(V,2) layout whose edge lengths best match `rest`'s (least squares), started from `init` (V,2), aligned to it.

    A hinge residual per triangle (`flatten_problem`; signed area, counter-clockwise in `init` positive) keeps
    triangles from turning over where noisy rest positions make a thin one: the edge lengths alone are as happy
    with a folded layout as with a flat one."""
    from scipy.optimize import least_squares

    n_v = rest.shape[0]
    residual, jac = flatten_problem(rest, cells)
    # tolerances 1e-8: a refined (doubly curved) sheet crawls to 1e-10 over ~25,000 evaluations (20-35 s at ci) to a
    # cost equal to 6 digits; max_nfev bounds the time where the fold hinge's kink slows the trust region
    sol = least_squares(residual, init.ravel(), jac=jac, method="trf", tr_solver="lsmr", x_scale="jac", xtol=1e-8, ftol=1e-8,
                        max_nfev=FLATTEN_MAX_EVALUATIONS)  # fmt: skip
    m = sol.x.reshape(n_v, 2)
    # rigid alignment (rotation, no reflection) onto the start, so the layout keeps the grid's orientation
    mc, ic = m - m.mean(axis=0), init - init.mean(axis=0)
    U, _, Vt = np.linalg.svd(mc.T @ ic)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    return mc @ (U @ D @ Vt) + init.mean(axis=0)
