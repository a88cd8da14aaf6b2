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

Steps 1 and 5 are in `sheet_uv` and `sheet_flatten`.

Limits. With "plane" the sheet is a height field over one plane: cloth that turns over itself relative to the plane
(a curled free end, a drape hanging on both sides of a bar) has several layers over one (u, v) point and they are
averaged into one. "isomap" unrolls such a sheet as long as its layers stay further apart than the neighbour
graph's edges (about 3 point spacings after the voxel thinning below); layers closer than that short-circuit the
geodesics and are merged again. A closed or tubular cloth (no disk topology) is not a sheet either way and needs a
surface-based remesher.
"""

from __future__ import annotations

import numpy as np

from clods_bench.benchmark.clods.sheet_flatten import flatten_geodesic, signed_areas
from clods_bench.benchmark.clods.sheet_uv import (
    ISOMAP_POINTS,
    PARAMETERIZATIONS,
    align_to_plane,
    best_plane,
    check_points,
    extend_uv,
    geodesic_uv,
    voxel_thin,
)
from clods_bench.datasets.cloths import validate_cloth_mesh
from clods_bench.datasets.types import HANDLE, NORMAL, ClothMesh, boundary_nodes
from clods_bench.errors import ClodsError


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
    area0 = signed_areas(nodes_uv, cells)
    out = nodes_uv.copy()
    scale = np.ones(b.size)
    for _ in range(6):  # halve the moves of nodes whose triangles would get too thin
        out[b] = nodes_uv[b] + scale[:, None] * step
        thin = signed_areas(out, cells) < min_area * area0
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
    p = check_points(points)
    if isinstance(num_nodes, bool) or not isinstance(num_nodes, (int, np.integer)) or num_nodes < 4:
        raise ClodsError(f"num_nodes must be an integer >= 4, got {num_nodes!r}", where="num_nodes")
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise ClodsError(f"radius must be a positive number of metres, got {radius}", where="radius")
    if int(closing) != closing or closing < 0:
        raise ClodsError(f"closing must be a non-negative integer, got {closing}", where="closing")
    if parameterization not in PARAMETERIZATIONS:
        raise ClodsError(f"unknown parameterization {parameterization!r}; one of {', '.join(PARAMETERIZATIONS)}", where="parameterization")
    centre, axes = best_plane(p)
    q = (p - centre) @ axes.T
    uv, h = q[:, :2], q[:, 2]
    span = uv.max(axis=0) - uv.min(axis=0)
    if span[1] <= 1e-9 * max(span[0], 1e-300):
        raise ClodsError("the points lie on a line, not a sheet", where="points")
    if parameterization == "isomap":
        thin = voxel_thin(p, max(ISOMAP_POINTS, 8 * int(num_nodes)))
        kept, geo = geodesic_uv(thin)
        thin = thin[kept]
        p, uv = extend_uv(thin, align_to_plane(geo, ((thin - centre) @ axes.T)[:, :2]), p)
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
    if np.any(signed_areas(mesh_pos, cells) <= 0.0):  # folded layout despite the hinge: keep the start's (u, v)
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
