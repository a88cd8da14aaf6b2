"""Step 1 of `sheet_mesh.sheet_from_points`: (u, v) coordinates on the sheet a cloth's point cloud samples.

`parameterization="isomap"` unrolls the sheet by its own geodesic distances (landmark Isomap over a k-nearest-neighbour
graph of voxel-thinned points; de Silva & Tenenbaum 2004), turned onto the points' best-fit plane; "plane" takes the
plane's axes alone (`best_plane`). See `sheet_mesh` for the whole construction and its limits.
"""

from __future__ import annotations

import numpy as np

from clods_bench.errors import ClodsError


def check_points(points: np.ndarray) -> np.ndarray:
    """`points` as (N,3) float64, at least 10 and finite; else a ClodsError naming them."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3 or not np.issubdtype(p.dtype, np.number):
        raise ClodsError(f"shape {tuple(p.shape)} and dtype {p.dtype}, expected (N, 3) numbers", where="points")
    p = p.astype(np.float64)
    if not np.isfinite(p).all():
        raise ClodsError(f"{int(np.sum(~np.isfinite(p).all(axis=1)))} points hold NaN/Inf", where="points")
    if p.shape[0] < 10:
        raise ClodsError(f"{p.shape[0]} points; a sheet needs at least 10", where="points")
    return p


def best_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def extend_uv(thin: np.ndarray, thin_uv: np.ndarray, points: np.ndarray, neighbours: int = 8) -> tuple[np.ndarray, np.ndarray]:
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


def align_to_plane(uv: np.ndarray, plane_uv: np.ndarray) -> np.ndarray:
    """`uv` mirrored (if need be) and turned to best match `plane_uv`: the plane's axes and handedness (orthogonal
    Procrustes, the mirror chosen by the sign of the least-squares linear map between the two)."""
    a, b = uv - uv.mean(axis=0), plane_uv - plane_uv.mean(axis=0)
    lin = np.linalg.lstsq(a, b, rcond=None)[0]
    if np.linalg.det(lin) < 0:
        a[:, 1] = -a[:, 1]
    U, _, Vt = np.linalg.svd(a.T @ b)
    D = np.diag([1.0, np.sign(np.linalg.det(U @ Vt))])
    return a @ (U @ D @ Vt) + plane_uv.mean(axis=0)
