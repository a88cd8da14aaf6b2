"""From a point cloud of a cloth to a simulation-ready sheet mesh: the step the paper's appendix leaves out.

TSDF fusion + marching cubes (`tsdf`) gives a surface, but not a cloth mesh: a thin cloth fuses to a thin closed
shell or a two-sided surface, with thousands of irregular triangles, sliver faces and no rest coordinates. A
learned cloth simulator needs one open manifold sheet with a chosen number of nodes, well-shaped triangles,
`mesh_pos` rest coordinates that measure its edges, and handle nodes. `sheet_from_points` builds it:

1. coordinates (u, v) on the sheet. `parameterization="isomap"` (the default): the sheet unrolled by its own
   geodesic distances (landmark Isomap: a k-nearest-neighbour graph over the points, shortest paths from
   farthest-point landmarks, classical MDS of the landmarks and the landmark triangulation of every other point;
   de Silva & Tenenbaum 2004), turned onto the best-fit plane of the points (PCA axes e1, e2 of most variance,
   normal n = e1 x e2) so a flat sheet gets the plane's axes and handedness. A flag whose free end curls over
   itself unrolls to one layer. `parameterization="plane"`: the plane's (u, v) alone, with a height h along n;
2. a regular (u, v) grid over the points' extent, its spacing chosen (a few fixed-point iterations) so the kept
   part has about `num_nodes` nodes; a grid cell is kept when points fall in it: a 2D occupancy mask, closed
   morphologically (gaps between sparse points), reduced to its largest 4-connected component, and completed
   where two kept cells touch only at a corner (a node joining two fans is not manifold); the mask's edge is a
   staircase, so boundary nodes further than the point spacing from every point are pulled onto the points'
   boundary (by at most one cell, never thinning a triangle below 15 % of its area);
3. each node's position from the points within `radius` of it in (u, v). "plane": its height h, a weighted
   least-squares quadratic (linear, then the median, when few points) after dropping points further than 3 robust
   deviations from the local median, clamped to the kept heights' range (no wild extrapolation at the boundary).
   "isomap": the same fit made local (`_positions`): a weighted affine map (u, v) -> xyz gives the tangent plane at
   the node, and the clamped quadratic height is taken along that plane's normal. Either way the node lands on the
   mid-surface of a two-sided shell, with no curvature bias;
4. kept cells split along alternating diagonals (like `make_flag_mesh`), counter-clockwise in (u, v);
5. `rest_pos` = the 3D nodes; `mesh_pos` = a geodesic-preserving flattening: the 2D layout whose edge lengths
   best match the 3D rest edges (nonlinear least squares started from the (u, v) grid, so it stays a valid
   embedding). Not `mesh_io.flatten_rest`: its plane projection shortens edges by cos(slope) (13 % where a
   flag is tilted 30 degrees from the plane), which a simulator would read as a pre-stretched cloth. A developable
   sheet (any bent, unfolded cloth) flattens with edges kept to rounding; a doubly curved one keeps the
   least-squares compromise;
6. every node NORMAL; `handles_from_tracks` + `with_handles` mark the pinned nodes from meshes tracked over the
   first frames.

Limits. With "plane" the sheet is a height field over one plane: cloth that turns over itself relative to the plane
(a curled free end, a drape hanging on both sides of a bar) has several layers over one (u, v) point and they are
averaged into one. "isomap" unrolls such a sheet as long as its layers stay further apart than the neighbour
graph's edges (about 3 point spacings after the voxel thinning below); layers closer than that short-circuit the
geodesics and are merged again. A closed or tubular cloth (no disk topology) is not a sheet either way and needs a
surface-based remesher.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from clods_bench.datasets.cloths import validate_cloth_mesh
from clods_bench.datasets.types import HANDLE, NORMAL, ClothMesh, boundary_nodes, edges_from_cells
from clods_bench.errors import ClodsError


def _check_points(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3 or not np.issubdtype(p.dtype, np.number):
        raise ClodsError(f"shape {tuple(p.shape)} and dtype {p.dtype}, expected (N, 3) numbers", where="points")
    p = p.astype(np.float64)
    if not np.isfinite(p).all():
        raise ClodsError(f"{int(np.sum(~np.isfinite(p).all(axis=1)))} points hold NaN/Inf", where="points")
    if p.shape[0] < 10:
        raise ClodsError(f"{p.shape[0]} points; a sheet needs at least 10", where="points")
    return p


def _frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (3,) and right-handed axes (3,3): rows e1 (most variance), e2, n = e1 x e2 (least variance)."""
    c = points.mean(axis=0)
    q = points - c
    _, vecs = np.linalg.eigh(q.T @ q)
    e1, n = vecs[:, 2], vecs[:, 0]
    e1 = e1 * (1.0 if e1[np.argmax(np.abs(e1))] > 0 else -1.0)  # deterministic signs
    n = n * (1.0 if n[np.argmax(np.abs(n))] > 0 else -1.0)
    e2 = np.cross(n, e1)
    if np.linalg.norm(np.cross(e1, e2) - n) > 1e-6:  # pragma: no cover - eigh returns orthonormal vectors
        raise ClodsError("the PCA axes are not orthonormal", where="points")
    return c, np.stack([e1, e2, n])


PARAMETERIZATIONS = ("isomap", "plane")
ISOMAP_POINTS = 2500
"""Points the isomap parameterisation keeps at least (voxel-thinned to about max(this, 8 x num_nodes)): an even
density for the neighbour graph, and a bounded cost (its shortest paths run from each landmark)."""


def voxel_thin(points: np.ndarray, target: int) -> np.ndarray:
    """About `target` points: the centroids of the occupied cells of a cubic grid whose cell is sized to give that
    many (a few fixed-point steps); `points` itself when it holds no more than `target`."""
    p = np.asarray(points, np.float64)
    if p.shape[0] <= target:
        return p
    lo = p.min(axis=0)
    cell = float(np.ptp(p, axis=0).max()) / np.sqrt(target)
    best: tuple[int, np.ndarray, np.ndarray] | None = None
    for _ in range(16):
        _, inv, cnt = np.unique(np.floor((p - lo) / cell).astype(np.int64), axis=0, return_inverse=True, return_counts=True)
        if best is None or abs(cnt.size - target) < abs(best[1].size - target):
            best = (cnt.size, cnt, inv.reshape(-1))
        if abs(cnt.size - target) <= 0.05 * target:
            break
        cell *= float(np.sqrt(cnt.size / target))  # a sheet's cell count goes as 1 / cell^2
    m, cnt, inv = best  # type: ignore[misc]
    out = np.zeros((m, 3))
    np.add.at(out, inv, p)
    return out / cnt[:, None]


def landmark_mds(sq_dist: np.ndarray, landmarks: np.ndarray, dims: int = 2) -> np.ndarray:
    """(N, dims) coordinates of N points from their squared distances `sq_dist` (L, N) to L of them (`landmarks`,
    indices into N): classical MDS of the landmarks, every point placed by distance triangulation (de Silva &
    Tenenbaum 2004, landmark MDS). Exact, up to a rigid motion, for Euclidean distances of points in `dims`-space."""
    delta = np.asarray(sq_dist, np.float64)
    lm = delta[:, landmarks]
    n = lm.shape[0]
    centring = np.eye(n) - 1.0 / n
    vals, vecs = np.linalg.eigh(-0.5 * centring @ lm @ centring)
    vals, vecs = vals[::-1][:dims], vecs[:, ::-1][:, :dims]
    if not np.all(vals > 1e-12 * max(float(vals[0]), 1e-300)):
        raise ClodsError(f"the geodesic distances span {int(np.sum(vals > 0))} dimension(s), not {dims}", where="points")
    pseudo = vecs.T / np.sqrt(vals)[:, None]  # (dims, L)
    return (-0.5 * pseudo @ (delta - lm.mean(axis=1)[:, None])).T


def geodesic_uv(points: np.ndarray, neighbours: int = 8, landmarks: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the points kept, (M,2) coordinates): the points' surface unrolled by geodesic distances.

    The geodesics are shortest paths over the symmetric `neighbours`-nearest-neighbour graph (its largest connected
    component is kept: a stray cluster is dropped); `landmarks` of them chosen by farthest-point sampling along the
    graph, then `landmark_mds`, scaled so that graph neighbours keep their 3D distances (median). Shortest paths run
    from the landmarks only, so the cost grows linearly with the points."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components, dijkstra
    from scipy.spatial import cKDTree

    p = np.asarray(points, np.float64)
    k = min(int(neighbours), p.shape[0] - 1)
    dist, idx = cKDTree(p).query(p, k=k + 1)
    n = p.shape[0]
    rows = np.repeat(np.arange(n), k)
    graph = csr_matrix((np.maximum(dist[:, 1:].ravel(), 1e-12), (rows, idx[:, 1:].ravel())), shape=(n, n))
    graph = graph.maximum(graph.T).tocsr()
    _, label = connected_components(graph, directed=False)
    kept = np.flatnonzero(label == np.argmax(np.bincount(label)))
    if kept.size < 10:
        raise ClodsError(f"the neighbour graph's largest piece holds {kept.size} points; a sheet needs at least 10", where="points")
    graph = graph[kept][:, kept]
    count = min(int(landmarks), kept.size)
    first = int(np.argmax(dijkstra(graph, indices=0)))  # an extreme point: the farthest from an arbitrary one
    chosen, rows_d = [first], [dijkstra(graph, indices=first)]
    nearest = rows_d[0].copy()
    while len(chosen) < count:
        nxt = int(np.argmax(nearest))
        if nearest[nxt] <= 0.0:
            break
        chosen.append(nxt)
        rows_d.append(dijkstra(graph, indices=nxt))
        np.minimum(nearest, rows_d[-1], out=nearest)
    uv = landmark_mds(np.stack(rows_d) ** 2, np.asarray(chosen))
    # graph paths zigzag, a few % longer than the surface's geodesics: rescale so neighbours keep their 3D distance
    pairs = graph.tocoo()
    flat = np.linalg.norm(uv[pairs.row] - uv[pairs.col], axis=1)
    ok = flat > 0
    return kept, uv * float(np.median(pairs.data[ok] / flat[ok]))


def _extend_uv(thin: np.ndarray, thin_uv: np.ndarray, points: np.ndarray, neighbours: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(points kept, their (u, v)): every point placed from its nearest thinned point by that point's local affine map
    from 3D to (u, v) (least squares over its neighbours, the sheet's normal direction cut off), so the fit keeps
    every point's density and a boundary point lands outside the thinned points rather than among them. Points whose
    nearest thinned point is further than 2 thinned spacings (a stray cluster the graph dropped) are left out."""
    from scipy.spatial import cKDTree

    tree = cKDTree(thin)
    dist, nb = tree.query(thin, k=min(neighbours, thin.shape[0] - 1) + 1)
    spacing = float(np.median(dist[:, 1]))
    dx = thin[nb[:, 1:]] - thin[:, None]
    du = thin_uv[nb[:, 1:]] - thin_uv[:, None]
    jac = np.linalg.pinv(dx, rcond=0.1) @ du  # (M,3,2): dx @ jac ~ du; the out-of-sheet direction is below rcond
    d, j = tree.query(points)
    near = d <= 2.0 * spacing
    q, j = points[near], j[near]
    return q, thin_uv[j] + np.einsum("nx,nxu->nu", q - thin[j], jac[j])


def _align_to_plane(uv: np.ndarray, plane_uv: np.ndarray) -> np.ndarray:
    """`uv` mirrored (if need be) and turned to best match `plane_uv`: the plane's axes and handedness (orthogonal
    Procrustes, the mirror chosen by the sign of the least-squares linear map between the two)."""
    a, b = uv - uv.mean(axis=0), plane_uv - plane_uv.mean(axis=0)
    lin = np.linalg.lstsq(a, b, rcond=None)[0]
    if np.linalg.det(lin) < 0:
        a[:, 1] = -a[:, 1]
    U, _, Vt = np.linalg.svd(a.T @ b)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    return a @ (U @ D @ Vt) + plane_uv.mean(axis=0)


def _occupancy(uv: np.ndarray, lo: np.ndarray, nx: int, ny: int, du: float, dv: float, closing: int) -> np.ndarray:
    """(nx-1, ny-1) bool kept cells: occupied, closed, largest 4-connected component, no corner-only contacts."""
    from scipy import ndimage

    ci = np.clip(((uv[:, 0] - lo[0]) / du).astype(np.int64), 0, nx - 2)
    cj = np.clip(((uv[:, 1] - lo[1]) / dv).astype(np.int64), 0, ny - 2)
    occ = np.zeros((nx - 1, ny - 1), dtype=bool)
    occ[ci, cj] = True
    if closing > 0:
        pad = closing + 1
        big = np.pad(occ, pad)
        big = ndimage.binary_closing(big, structure=np.ones((3, 3), bool), iterations=closing)
        occ = big[pad:-pad, pad:-pad] | occ
    labels, count = ndimage.label(occ)  # default structure: 4-connectivity
    if count > 1:
        sizes = np.bincount(labels.ravel())[1:]
        occ = labels == (1 + int(np.argmax(sizes)))
    while True:  # a node shared by two diagonal cells only joins two fans: add a cell at that corner
        a, b, c, d = occ[:-1, :-1], occ[1:, :-1], occ[:-1, 1:], occ[1:, 1:]
        diag1 = a & d & ~b & ~c
        diag2 = b & c & ~a & ~d
        if not (diag1.any() or diag2.any()):
            return occ
        i, j = np.nonzero(diag1 | diag2)
        occ[i + 1, j] = True  # one of the two empty cells of each such 2x2 block


def _grid(uv: np.ndarray, spacing: float, closing: int) -> tuple[int, int, float, float, np.ndarray]:
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    span = np.maximum(hi - lo, 1e-9)
    nx = max(2, int(round(span[0] / spacing)) + 1)
    ny = max(2, int(round(span[1] / spacing)) + 1)
    du, dv = span[0] / (nx - 1), span[1] / (ny - 1)
    occ = _occupancy(uv, lo, nx, ny, du, dv, closing)
    return nx, ny, du, dv, occ


def _node_mask(occ: np.ndarray) -> np.ndarray:
    nodes = np.zeros((occ.shape[0] + 1, occ.shape[1] + 1), dtype=bool)
    for a in (0, 1):
        for b in (0, 1):
            nodes[a : a + occ.shape[0], b : b + occ.shape[1]] |= occ
    return nodes


def _heights(uv: np.ndarray, h: np.ndarray, nodes_uv: np.ndarray, radius: float) -> np.ndarray:
    """Height at each node: robust local quadratic / linear fit / median of the points near it (see the module docstring)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(uv)
    near = tree.query_ball_point(nodes_uv, radius)
    k = min(12, uv.shape[0])
    out = np.empty(nodes_uv.shape[0])
    for i, idx in enumerate(near):
        if len(idx) < 6:
            idx = tree.query(nodes_uv[i], k=k)[1]
        idx = np.asarray(idx)
        hh = h[idx]
        med = np.median(hh)
        mad = 1.4826 * np.median(np.abs(hh - med))
        keep = np.abs(hh - med) <= max(3.0 * mad, 1e-9 + 1e-6 * radius)
        d = uv[idx[keep]] - nodes_uv[i]
        y = hh[keep]
        w = np.exp(-2.0 * np.sum(d**2, axis=1) / radius**2)
        out[i] = _fit_at_node(d / radius, y, w) if y.size >= 4 else med
    return out


def _fit_at_node(s: np.ndarray, y: np.ndarray, w: np.ndarray) -> float:
    """Value at s = 0 of a weighted least-squares quadratic in the scaled offsets `s` (K,2) (linear below 12 points),
    clamped to the range of `y`: a one-sided neighbourhood (a boundary node) must not extrapolate wildly; the median of
    `y` when the design is rank-deficient. Needs at least 4 points."""
    cols = [np.ones_like(y), s[:, 0], s[:, 1]]
    if y.size >= 12:
        cols += [s[:, 0] ** 2, s[:, 0] * s[:, 1], s[:, 1] ** 2]
    A = np.column_stack(cols)
    sw = np.sqrt(w)
    coef, _, rank, _ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
    return float(np.clip(coef[0], y.min(), y.max())) if rank == A.shape[1] else float(np.median(y))


WELL_POSED = 0.1
"""`_positions`: relative singular value below which a node's local affine fit counts as degenerate."""


def _positions(uv: np.ndarray, xyz: np.ndarray, nodes_uv: np.ndarray, radius: float) -> np.ndarray:
    """3D node positions over an isomap (u, v): the plane method's height fit, made local. Per node, the points
    within `radius` (else its 12 nearest) give a weighted affine map (u, v) -> xyz, the tangent plane there; points
    further than 3 robust deviations from it along its normal are dropped and the map refitted; the node sits on the
    map plus a robust quadratic height along the normal, clamped to the kept points' heights. A boundary node thus
    extrapolates along the tangent plane only, never along the normal. Where the neighbours are nearly collinear in
    (u, v) (singular values of the scaled design below WELL_POSED of the largest: a thin strip of points at the rim)
    or the fit lands further than `radius` from every neighbour, the node takes their Gaussian-weighted mean."""
    from scipy.spatial import cKDTree

    tree = cKDTree(uv)
    near = tree.query_ball_point(nodes_uv, radius)
    k = min(12, uv.shape[0])
    out = np.empty((nodes_uv.shape[0], 3))
    for i, idx in enumerate(near):
        if len(idx) < 6:
            idx = tree.query(nodes_uv[i], k=k)[1]
        idx = np.asarray(idx)
        q, s = xyz[idx], (uv[idx] - nodes_uv[i]) / radius
        w = np.exp(-2.0 * np.sum(s**2, axis=1))
        keep = np.ones(idx.size, dtype=bool)
        coef = None
        for _ in range(2):  # the tangent plane, then again without the points far off it
            lin = np.column_stack([np.ones(int(keep.sum())), s[keep]])
            sw = np.sqrt(w[keep])[:, None]
            coef, _, rank, _ = np.linalg.lstsq(lin * sw, q[keep] * sw, rcond=WELL_POSED)
            if rank < 3:
                coef = None
                break
            normal = np.cross(coef[1], coef[2])
            normal /= max(float(np.linalg.norm(normal)), 1e-300)
            height = (q - np.column_stack([np.ones(idx.size), s]) @ coef) @ normal
            med = np.median(height[keep])
            mad = 1.4826 * np.median(np.abs(height[keep] - med))
            keep = np.abs(height - med) <= max(3.0 * mad, 1e-9 + 1e-6 * radius)
            if keep.sum() < 4:
                coef = None
                break
        if coef is None:  # too few or degenerate points: their weighted mean
            out[i] = np.sum(w[:, None] * q, axis=0) / np.sum(w)
            continue
        out[i] = coef[0] + _fit_at_node(s[keep], height[keep], w[keep]) * normal
        if np.min(np.linalg.norm(q[keep] - out[i], axis=1)) > radius:  # extrapolated off its neighbours: among them
            out[i] = np.sum(w[:, None] * q, axis=0) / np.sum(w)
    return out


def _signed_areas(uv: np.ndarray, cells: np.ndarray) -> np.ndarray:
    a, b, c = uv[cells[:, 0]], uv[cells[:, 1]], uv[cells[:, 2]]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def _snap_boundary(
    uv: np.ndarray, nodes_uv: np.ndarray, cells: np.ndarray, cell: float, max_move: float = 1.0, min_area: float = 0.15
) -> np.ndarray:
    """Boundary nodes further than the point spacing from every point move towards the nearest point (by at most
    `max_move` cells), as long as every triangle keeps `min_area` of its area; interior nodes stay."""
    from scipy.spatial import cKDTree

    tree = cKDTree(uv)
    spacing = float(np.median(tree.query(uv, k=2)[0][:, 1]))
    boundary = boundary_nodes(cells)
    dist, idx = tree.query(nodes_uv[boundary])
    far = dist > spacing
    b, q, dist = boundary[far], uv[idx[far]], dist[far]
    if b.size == 0:
        return nodes_uv
    step = np.minimum(dist - spacing, max_move * cell)[:, None] * (q - nodes_uv[b]) / dist[:, None]
    area0 = _signed_areas(nodes_uv, cells)
    out = nodes_uv.copy()
    scale = np.ones(b.size)
    for _ in range(6):  # halve the moves of nodes whose triangles would get too thin
        out[b] = nodes_uv[b] + scale[:, None] * step
        thin = _signed_areas(out, cells) < min_area * area0
        if not thin.any():
            return out
        bad_nodes = np.unique(cells[thin])
        scale[np.isin(b, bad_nodes)] *= 0.5
    scale[np.isin(b, np.unique(cells[thin]))] = 0.0  # still too thin: those stay where the grid put them
    out[b] = nodes_uv[b] + scale[:, None] * step
    return out


def _triangulate(occ: np.ndarray, nx: int) -> np.ndarray:
    """(F,3) grid-node triangles of the kept cells, counter-clockwise in (u, v), alternating diagonals."""
    i, j = np.nonzero(occ)
    a, b, c, d = i + nx * j, i + 1 + nx * j, i + 1 + nx * (j + 1), i + nx * (j + 1)
    alt = (i + j) % 2 == 1
    t1 = np.where(alt[:, None], np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    t2 = np.where(alt[:, None], np.stack([b, c, d], 1), np.stack([a, c, d], 1))
    return np.concatenate([t1, t2], axis=0).astype(np.int64)


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
        fold = FOLD_WEIGHT * np.minimum(_signed_areas(m, cells) / area3 - FOLD_MIN, 0.0)
        return np.concatenate([edge, fold])

    def jac(x: np.ndarray) -> csr_matrix:
        m = x.reshape(n_v, 2)
        dvec = m[edges[:, 0]] - m[edges[:, 1]]
        g = dvec / (np.linalg.norm(dvec, axis=1, keepdims=True) * length[:, None])
        a, b, c = m[cells[:, 0]], m[cells[:, 1]], m[cells[:, 2]]
        d_area = 0.5 * np.stack([b[:, 1] - c[:, 1], c[:, 0] - b[:, 0], c[:, 1] - a[:, 1], a[:, 0] - c[:, 0],
                                 a[:, 1] - b[:, 1], b[:, 0] - a[:, 0]], axis=1)  # fmt: skip
        active = _signed_areas(m, cells) / area3 < FOLD_MIN
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


def sheet_from_points(
    points: np.ndarray,
    num_nodes: int,
    radius: float | None = None,
    closing: int = 1,
    snap: bool = True,
    parameterization: str = "isomap",
) -> ClothMesh:
    """One open manifold cloth sheet of about `num_nodes` nodes fitted to `points` (N,3) (see the module docstring).

    `radius`: the neighbourhood (metres, in (u, v)) of each node's position fit; None: 1.5 grid spacings.
    `parameterization`: "isomap" (geodesic, unrolls a sheet that turns over itself) or "plane" (a height field).
    `closing`: iterations of the morphological closing of the occupancy mask (fills gaps of about that many cells).
    `snap`: pull boundary nodes that overshoot the points (a grid's staircase edge) back onto the points' boundary.
    Raises ClodsError for bad input or when the points do not make a sheet.
    """
    p = _check_points(points)
    if isinstance(num_nodes, bool) or not isinstance(num_nodes, (int, np.integer)) or num_nodes < 4:
        raise ClodsError(f"num_nodes must be an integer >= 4, got {num_nodes!r}", where="num_nodes")
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise ClodsError(f"radius must be a positive number of metres, got {radius}", where="radius")
    if int(closing) != closing or closing < 0:
        raise ClodsError(f"closing must be a non-negative integer, got {closing}", where="closing")
    if parameterization not in PARAMETERIZATIONS:
        raise ClodsError(f"unknown parameterization {parameterization!r}; one of {', '.join(PARAMETERIZATIONS)}", where="parameterization")
    centre, axes = _frame(p)
    q = (p - centre) @ axes.T
    uv, h = q[:, :2], q[:, 2]
    span = uv.max(axis=0) - uv.min(axis=0)
    if span[1] <= 1e-9 * max(span[0], 1e-300):
        raise ClodsError("the points lie on a line, not a sheet", where="points")
    if parameterization == "isomap":
        thin = voxel_thin(p, max(ISOMAP_POINTS, 8 * int(num_nodes)))
        kept, geo = geodesic_uv(thin)
        thin = thin[kept]
        p, uv = _extend_uv(thin, _align_to_plane(geo, ((thin - centre) @ axes.T)[:, :2]), p)
        span = uv.max(axis=0) - uv.min(axis=0)

    target = int(num_nodes)
    spacing = float(np.sqrt(span[0] * span[1] / target))
    best = None
    for _ in range(12):
        nx, ny, du, dv, occ = _grid(uv, spacing, int(closing))
        count = int(_node_mask(occ).sum())
        if best is None or abs(count - target) < abs(best[0] - target):
            best = (count, nx, ny, du, dv, occ)
        if abs(count - target) <= 0.02 * target:
            break
        spacing *= float(np.sqrt(max(count, 1) / target))
    count, nx, ny, du, dv, occ = best  # type: ignore[misc]
    if occ.sum() == 0:
        raise ClodsError("no grid cell holds points", where="points")

    lo = uv.min(axis=0)
    nodes = _node_mask(occ)  # (nx, ny)
    gi, gj = np.nonzero(nodes)
    keep = gi + nx * gj  # grid index i + nx*j of each kept node (make_flag_mesh's numbering)
    order = np.argsort(keep)
    keep, gi, gj = keep[order], gi[order], gj[order]
    grid_uv = np.stack([lo[0] + du * gi, lo[1] + dv * gj], axis=1)
    remap = np.full(nx * ny, -1, dtype=np.int64)
    remap[keep] = np.arange(keep.size)
    cells = remap[_triangulate(occ, nx)]
    if snap:
        grid_uv = _snap_boundary(uv, grid_uv, cells, min(du, dv))
    r = 1.5 * max(du, dv) if radius is None else float(radius)
    if parameterization == "isomap":
        rest = _positions(uv, p, grid_uv, r)
    else:
        heights = _heights(uv, h, grid_uv, r)
        rest = centre + grid_uv[:, :1] * axes[0] + grid_uv[:, 1:] * axes[1] + heights[:, None] * axes[2]

    return _sheet(rest, cells, grid_uv - grid_uv.min(axis=0), "sheet_from_points")


def _sheet(rest: np.ndarray, cells: np.ndarray, layout: np.ndarray, where: str) -> ClothMesh:
    """The validated sheet of nodes `rest` whose `mesh_pos` flattens their edge lengths, started from `layout`."""
    mesh_pos = flatten_geodesic(rest, cells, layout)
    if np.any(_signed_areas(mesh_pos, cells) <= 0.0):  # folded layout despite the hinge: keep the start's (u, v)
        mesh_pos = np.array(layout, dtype=np.float64)
    mesh_pos -= mesh_pos.min(axis=0)
    mesh = ClothMesh(cells.astype(np.int32), mesh_pos.astype(np.float32), np.full(rest.shape[0], NORMAL, np.int32), rest)
    validate_cloth_mesh(mesh, where, has_handles=False)
    return mesh


def with_rest_positions(mesh: ClothMesh, rest: np.ndarray) -> ClothMesh:
    """The same sheet (cells, no handles) at new node positions `rest` (V,3), `mesh_pos` re-flattened from them."""
    rest = np.asarray(rest, np.float64)
    if rest.shape != (mesh.num_nodes, 3):
        raise ClodsError(f"positions of shape {rest.shape}, expected ({mesh.num_nodes}, 3)", where="with_rest_positions")
    return _sheet(rest, np.asarray(mesh.cells, np.int64), np.asarray(mesh.mesh_pos, np.float64), "with_rest_positions")


def handles_from_tracks(tracks: np.ndarray, tol: float) -> np.ndarray:
    """Indices (int64, increasing) of the nodes of `tracks` (T,V,3) that stay within `tol` metres of their frame-0 position.

    The tracks are the reconstructed mesh followed over the first frames (for instance with
    `cross_topology.attach` / `follow`, or from stage-2 extraction); pinned nodes do not move.
    """
    x = np.asarray(tracks)
    if x.ndim != 3 or x.shape[2] != 3 or not np.issubdtype(x.dtype, np.number):
        raise ClodsError(f"shape {tuple(x.shape)}, expected (T, V, 3) positions", where="tracks")
    if x.shape[0] < 2:
        raise ClodsError(f"{x.shape[0]} frames; handles need at least 2 to show they do not move", where="tracks")
    if not np.isfinite(x).all():
        raise ClodsError("tracks hold NaN/Inf", where="tracks")
    if not (np.isfinite(tol) and tol >= 0):
        raise ClodsError(f"tol must be a non-negative number of metres, got {tol}", where="tol")
    moved = np.linalg.norm(x.astype(np.float64) - x[:1].astype(np.float64), axis=2).max(axis=0)
    return np.flatnonzero(moved <= tol).astype(np.int64)


def with_handles(mesh: ClothMesh, indices: np.ndarray) -> ClothMesh:
    """A copy of `mesh` whose nodes `indices` are HANDLE (the others keep their type)."""
    idx = np.asarray(indices).reshape(-1)
    if idx.size and not np.issubdtype(idx.dtype, np.integer):
        raise ClodsError(f"indices must be integers, got dtype {idx.dtype}", where="indices")
    bad = idx[(idx < 0) | (idx >= mesh.num_nodes)]
    if bad.size:
        raise ClodsError(f"{bad.size} indices out of range [0, {mesh.num_nodes}), first is {int(bad[0])}", where="indices")
    node_type = np.asarray(mesh.node_type, dtype=np.int32).copy()
    node_type[idx.astype(np.int64)] = HANDLE
    return ClothMesh(mesh.cells.copy(), mesh.mesh_pos.copy(), node_type, np.asarray(mesh.rest_pos).copy(),
                     None if mesh.uv is None else mesh.uv.copy())  # fmt: skip
