"""Frame-0 reconstruction: TSDF fusion of depth maps, marching cubes, the open sheet mesh fitted to the points,
handle nodes from tracks, and the whole chain from rendered depth maps to a simulable cloth mesh."""

from __future__ import annotations

import time

import numpy as np
import pytest
import trimesh

from clods_bench.benchmark.clods.sheet_flatten import FOLD_MIN, flatten_geodesic, flatten_problem
from clods_bench.benchmark.clods.sheet_mesh import handles_from_tracks, sheet_from_points, with_handles
from clods_bench.benchmark.clods.sheet_uv import geodesic_uv, landmark_mds, voxel_thin
from clods_bench.benchmark.clods.tsdf import backproject, extract_surface, fuse_depth_maps, trim_to_support
from clods_bench.benchmark.scoring.cross_topology import attach, attached_rmse, chamfer, follow
from clods_bench.datasets.cameras import Camera, camera_rig, look_at
from clods_bench.datasets.cloths import validate_cloth_mesh
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.rasterizer import render_depth
from clods_bench.datasets.scenes import get_scene, simulate_scene
from clods_bench.datasets.types import HANDLE, NORMAL, ClothMesh, edges_from_cells
from clods_bench.errors import ClodsError

VOXEL = 0.02


@pytest.fixture(scope="module")
def flag_run() -> dict:
    """The ci-like flag (16 x 8 nodes, 2 x 1 m) simulated for 8 frames: mesh and world positions."""
    scene = get_scene("flag")
    mesh = scene.build_mesh((16, 8))
    traj = simulate_scene(scene, mesh, 8, seed=0)
    return {"mesh": mesh, "frames": np.asarray(traj.world_pos, np.float64)}


def rig(target: np.ndarray, n: int, size: int = 64) -> list[Camera]:
    return camera_rig(n, target, 5.0, size, size, fov_deg=30.0, phase_deg=30.0)


def depth_maps(verts: np.ndarray, cells: np.ndarray, cams: list[Camera]) -> np.ndarray:
    return np.stack([render_depth(verts, cells, c) for c in cams])


def sample_surface(verts: np.ndarray, cells: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """n points uniformly (by area) on the triangles."""
    rng = np.random.default_rng(seed)
    tri = verts[cells]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    f = rng.choice(len(cells), n, p=area / area.sum())
    b = rng.dirichlet(np.ones(3), n)
    return np.einsum("nkx,nk->nx", tri[f], b)


def mesh_pos_error(mesh: ClothMesh) -> float:
    """Median relative difference of mesh_pos and rest_pos edge lengths."""
    e = edges_from_cells(np.asarray(mesh.cells))
    l3 = np.linalg.norm(mesh.rest_pos[e[:, 0]] - mesh.rest_pos[e[:, 1]], axis=1)
    l2 = np.linalg.norm(mesh.mesh_pos[e[:, 0]].astype(np.float64) - mesh.mesh_pos[e[:, 1]], axis=1)
    return float(np.median(np.abs(l2 / l3 - 1.0)))


# ---------------------------------------------------------------- TSDF


def test_sphere_surface_lies_within_a_voxel_and_covers_it() -> None:
    sphere = trimesh.creation.icosphere(4, radius=0.5)
    cams = camera_rig(8, np.zeros(3), 3.0, 64, 64, fov_deg=30.0)
    depths = depth_maps(sphere.vertices, sphere.faces, cams)
    vol = fuse_depth_maps(depths, cams, None, VOXEL)
    assert vol.trunc == pytest.approx(3 * VOXEL)
    verts, faces = extract_surface(vol)
    assert faces.shape[1] == 3 and faces.max() < len(verts)
    err = np.abs(np.linalg.norm(verts, axis=1) - 0.5)
    assert err.max() < VOXEL  # no inner shell where unobserved voxels meet observed ones
    assert err.mean() < 0.25 * VOXEL
    truth = sample_surface(sphere.vertices, sphere.faces, 20000)
    assert chamfer(verts, truth) < 0.5 * VOXEL


def test_backprojected_depths_lie_on_the_mesh(flag_run: dict) -> None:
    x0, cells = flag_run["frames"][0], flag_run["mesh"].cells
    cams = rig(0.5 * (x0.min(0) + x0.max(0)), 4)
    depths = depth_maps(x0, cells, cams)
    pts = backproject(depths, cams)
    assert len(pts) == int(np.isfinite(depths).sum())
    assert attach(pts, x0, cells).distance.max() < 1e-6


def test_thin_flag_surface_oriented_fusion_lies_on_the_cloth(flag_run: dict) -> None:
    x0, cells = flag_run["frames"][0], flag_run["mesh"].cells
    cams = rig(0.5 * (x0.min(0) + x0.max(0)), 8)
    depths = depth_maps(x0, cells, cams)
    truth = sample_surface(x0, cells, 20000)
    oriented = extract_surface(fuse_depth_maps(depths, cams, None, VOXEL, orient=True))
    verts, faces = trim_to_support(*oriented, backproject(depths, cams), 1.5 * VOXEL)
    att = attach(verts, x0, cells)
    dist = att.distance
    print(f"\noriented TSDF of the flag: distance to the cloth p50/p95/p99/max "
          f"{np.percentile(dist, [50, 95, 99, 100]).round(4).tolist()} m, {len(verts)} vertices")  # fmt: skip
    # within a voxel of the cloth inside; past the cloth's border the level set runs on up to the trimming distance
    foot = np.einsum("nkx,nk->nx", np.asarray(flag_run["mesh"].mesh_pos, np.float64)[cells[att.face]], att.bary)
    inside = (foot.min(axis=1) > 0.03) & (foot[:, 0] < 2.0 - 0.03) & (foot[:, 1] < 1.0 - 0.03)
    assert np.percentile(dist[inside], 99) < 0.75 * VOXEL and dist[inside].max() < VOXEL
    assert np.percentile(dist, 95) < 0.75 * VOXEL and dist.max() < 1.5 * VOXEL
    assert chamfer(verts, truth) < 0.5 * VOXEL
    # the plain TSDF of a thin sheet seen from both sides is a noisy two-sided shell: still near, but further off
    plain_verts, _ = extract_surface(fuse_depth_maps(depths, cams, None, VOXEL))
    plain = attach(plain_verts, x0, cells).distance
    assert plain.max() < 4 * VOXEL
    assert plain.mean() > 2 * dist.mean()


def test_a_plane_seen_from_one_camera_gives_a_plane() -> None:
    normal = np.array([0.0, np.sin(0.5), np.cos(0.5)])  # tilted 29 degrees from the camera axis
    u = np.cross(normal, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(normal, u)
    corners = np.array([-u - w, u - w, u + w, -u + w]) * 3.0
    cells = np.array([[0, 1, 2], [0, 2, 3]])
    R, t = look_at(np.array([0.0, 0.0, 2.0]), np.zeros(3), up=np.array([0.0, 1.0, 0.0]))
    K = np.array([[60.0, 0, 32], [0, 60.0, 32], [0, 0, 1]])
    cam = Camera(K, R, t, 64, 64)
    depth = render_depth(corners, cells, cam)[None]
    assert np.isfinite(depth).all()
    vol = fuse_depth_maps(depth, [cam], (np.full(3, -0.3), np.full(3, 0.3)), VOXEL)
    verts, _ = extract_surface(vol)
    assert len(verts) > 100
    centred = verts - verts.mean(axis=0)
    fit_normal = np.linalg.svd(centred)[2][-1]
    assert abs(fit_normal @ normal) > 0.999
    assert np.abs(verts @ normal).max() < 0.25 * VOXEL  # on the plane through the origin


def test_fusion_weights_mask_views_out() -> None:
    sphere = trimesh.creation.icosphere(3, radius=0.5)
    cams = camera_rig(4, np.zeros(3), 3.0, 32, 32, fov_deg=30.0)
    depths = depth_maps(sphere.vertices, sphere.faces, cams)
    wrong = depths.copy()
    wrong[0] = np.where(np.isfinite(wrong[0]), wrong[0] - 0.3, np.inf)  # one view's depths are off by 30 cm
    weights = np.ones_like(depths)
    weights[0] = 0.0
    bounds = (np.full(3, -0.7), np.full(3, 0.7))
    masked = fuse_depth_maps(wrong, cams, bounds, 0.04, weights=weights)
    clean = fuse_depth_maps(depths[1:], cams[1:], bounds, 0.04)
    np.testing.assert_allclose(masked.tsdf, clean.tsdf, atol=1e-6)
    np.testing.assert_allclose(masked.weight, clean.weight)


def test_bad_depth_input_is_a_clods_error_naming_the_argument() -> None:
    cams = camera_rig(2, np.zeros(3), 3.0, 16, 12)
    good = np.full((2, 12, 16), 3.0)
    cases = [
        (dict(depths=good[:1]), "cameras"),  # one map, two cameras
        (dict(depths=np.full((2, 16, 12), 3.0)), "depths"),  # transposed: not the cameras' size
        (dict(depths=np.where(np.arange(16) == 3, np.nan, good)), "depths"),
        (dict(depths=-good), "depths"),
        (dict(depths=good[0]), "depths"),
        (dict(depths=np.full_like(good, np.inf)), "depths"),  # no depth anywhere
        (dict(depths=good, weights=np.ones((2, 3, 3))), "weights"),
        (dict(depths=good, voxel_size=0.0), "voxel_size"),
        (dict(depths=good, trunc=-1.0), "trunc"),
        (dict(depths=good, bounds=(np.ones(3), np.zeros(3))), "bounds"),
        (dict(depths=good, orient=np.zeros(3)), "orient"),
        (dict(depths=good, voxel_size=1e-4), "voxel_size"),  # too many voxels
    ]
    for kwargs, where in cases:
        args = {"depths": good, "cameras": cams, "bounds": None, "voxel_size": 0.05} | kwargs
        with pytest.raises(ClodsError) as exc:
            fuse_depth_maps(**args)
        assert exc.value.where == where, (kwargs, exc.value)
    with pytest.raises(ClodsError) as exc:
        backproject(np.full((2, 12, 16), np.nan), cams)
    assert exc.value.where == "depths"


def test_a_volume_without_a_zero_crossing_has_no_surface() -> None:
    cams = camera_rig(2, np.zeros(3), 3.0, 16, 16)
    vol = fuse_depth_maps(np.full((2, 16, 16), 10.0), cams, (np.full(3, -0.2), np.full(3, 0.2)), 0.05)
    with pytest.raises(ClodsError, match="no zero crossing"):
        extract_surface(vol)


# ---------------------------------------------------------------- sheet


def cylinder_sheet(radius: float = 1.0, nx: int = 41, ny: int = 21) -> tuple[np.ndarray, np.ndarray]:
    """A 2 x 1 m flag rolled into a cylinder section (arc 2 rad): verts, cells. Developable: mesh_pos is exact."""
    m = make_flag_mesh(nx, ny, 2.0, 1.0)
    s, z = m.mesh_pos[:, 0].astype(np.float64) - 1.0, m.mesh_pos[:, 1].astype(np.float64)
    verts = np.stack([radius * np.sin(s / radius), radius * (1.0 - np.cos(s / radius)), z], axis=1)
    return verts, np.asarray(m.cells, np.int64)


def check_sheet(mesh: ClothMesh, verts: np.ndarray, cells: np.ndarray, num_nodes: int, size: float) -> dict[str, float]:
    validate_cloth_mesh(mesh, "test", has_handles=False)
    assert abs(mesh.num_nodes - num_nodes) <= 0.15 * num_nodes
    assert (mesh.node_type == NORMAL).all()
    on_truth = attach(mesh.rest_pos, verts, cells).distance  # the sheet's nodes lie on the true cloth
    cover = attach(verts, mesh.rest_pos, mesh.cells)  # and the sheet covers every true node
    rmse = float(attached_rmse(mesh.rest_pos[None], mesh.cells, cover, verts[None])[0])
    edge = mesh_pos_error(mesh)
    assert rmse < 0.02 * size, rmse
    assert edge < 0.02, edge
    return {"node_max": float(on_truth.max()), "node_mean": float(on_truth.mean()), "rmse": rmse, "edge": edge}


def test_sheet_from_points_on_a_cylinder_section() -> None:
    verts, cells = cylinder_sheet()
    pts = sample_surface(verts, cells, 30000)
    mesh = sheet_from_points(pts, 200)
    stats = check_sheet(mesh, verts, cells, 200, 2.0)
    assert stats["node_max"] < 0.01 and stats["rmse"] < 0.01
    # geodesic flattening: the 2 x 1 m rectangle comes back flat at its true size (a plane projection would give
    # a chord of 2 sin(1) = 1.68 m)
    span = mesh.mesh_pos.max(axis=0) - mesh.mesh_pos.min(axis=0)
    assert sorted(span) == pytest.approx([1.0, 2.0], abs=0.05)


@pytest.mark.parametrize("parameterization", ["isomap", "plane"])
def test_sheet_from_points_on_the_simulated_flag(flag_run: dict, parameterization: str) -> None:
    x0, cells = flag_run["frames"][0], flag_run["mesh"].cells
    pts = sample_surface(x0, cells, 30000)
    for num in (64, 128, 500):
        mesh = sheet_from_points(pts, num, parameterization=parameterization)
        stats = check_sheet(mesh, x0, cells, num, 2.0)
        assert stats["node_max"] < 0.04 and stats["node_mean"] < 0.01, (num, stats)


@pytest.mark.parametrize("parameterization", ["isomap", "plane"])
def test_sheet_from_noisy_points_stays_on_the_cloth(flag_run: dict, parameterization: str) -> None:
    x0, cells = flag_run["frames"][0], flag_run["mesh"].cells
    pts = sample_surface(x0, cells, 30000) + np.random.default_rng(1).normal(scale=0.005, size=(30000, 3))
    for num in (128, 1579):
        stats = check_sheet(sheet_from_points(pts, num, parameterization=parameterization), x0, cells, num, 2.0)
        assert stats["node_mean"] < 0.005 and stats["node_max"] < 0.05 and stats["rmse"] < 0.01, (num, stats)


def rigid_residual(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance between `a` and `b` (N,2) once `a` is moved onto `b` by the best rotation / reflection."""
    ac, bc = a - a.mean(axis=0), b - b.mean(axis=0)
    U, _, Vt = np.linalg.svd(ac.T @ bc)
    return float(np.sqrt(np.mean(np.sum((ac @ (U @ Vt) - bc) ** 2, axis=1))))


def test_landmark_mds_is_exact_for_euclidean_distances() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.0, 1.0, (300, 2)) * [2.0, 0.5]
    lm = rng.choice(300, 20, replace=False)
    sq = np.sum((pts[lm][:, None] - pts[None]) ** 2, axis=2)
    assert rigid_residual(landmark_mds(sq, lm), pts) < 1e-9
    with pytest.raises(ClodsError, match="dimension"):  # points on a line do not make a 2D layout
        line = np.outer(np.linspace(0.0, 1.0, 50), [1.0, 0.0])
        landmark_mds(np.sum((line[:10, None] - line[None]) ** 2, axis=2), np.arange(10))


def test_geodesic_uv_unrolls_a_cylinder_to_arc_length() -> None:
    verts, cells = cylinder_sheet()
    pts = sample_surface(verts, cells, 4000)
    kept, uv = geodesic_uv(pts)
    assert kept.size == pts.shape[0]
    # the true (arc length, height) of each sample: invert the roll
    truth = np.stack([np.arcsin(np.clip(pts[:, 0], -1, 1)), pts[:, 2]], axis=1)
    assert np.std(uv - uv.mean(0)) / np.std(truth - truth.mean(0)) == pytest.approx(1.0, abs=0.05)  # to scale
    iso = rigid_residual(uv, truth)
    assert iso < 0.04  # metres, on a 2 x 1 m sheet rolled on a 1 m radius (graph paths zigzag)
    # the plane projection shortens the 2 m arc to a 1.68 m chord
    centred = pts - pts.mean(axis=0)
    plane = centred @ np.linalg.eigh(centred.T @ centred)[1][:, 1:]
    assert rigid_residual(plane, truth) > 2.0 * iso


def test_voxel_thin_keeps_the_cloud_and_evens_it() -> None:
    pts = np.random.default_rng(2).uniform(0.0, 1.0, (20000, 3)) * [2.0, 1.0, 0.01]
    out = voxel_thin(pts, 2000)
    assert abs(out.shape[0] - 2000) <= 200
    assert (out.min(axis=0) >= pts.min(axis=0)).all() and (out.max(axis=0) <= pts.max(axis=0)).all()
    assert voxel_thin(pts[:100], 2000).shape == (100, 3)


def test_flatten_problem_jacobian_matches_finite_differences() -> None:
    flag = make_flag_mesh(5, 4, 1.0, 0.6)
    rest = np.column_stack([np.asarray(flag.mesh_pos, np.float64), np.random.default_rng(3).normal(scale=0.05, size=20)])
    cells = np.asarray(flag.cells, np.int64)
    residual, jac = flatten_problem(rest, cells)
    x = np.asarray(flag.mesh_pos, np.float64).ravel().copy()
    x[2 * 5 : 2 * 5 + 2] += [0.3, 0.25]  # node 5 dragged across its neighbours: some triangles fold, the hinge is on
    assert (residual(x)[-cells.shape[0] :] < 0).any()
    eps = 1e-7
    fd = np.stack([(residual(x + eps * e) - residual(x - eps * e)) / (2 * eps) for e in np.eye(x.size)], axis=1)
    np.testing.assert_allclose(jac(x).toarray(), fd, atol=1e-5)


def test_flatten_geodesic_unfolds_a_dragged_layout() -> None:
    flag = make_flag_mesh(6, 4, 1.0, 0.6)
    rest = np.column_stack([np.asarray(flag.mesh_pos, np.float64), np.zeros(24)])
    cells = np.asarray(flag.cells, np.int64)
    init = np.asarray(flag.mesh_pos, np.float64).copy()
    out = flatten_geodesic(rest, cells, init)
    a, b, c = out[cells[:, 0]], out[cells[:, 1]], out[cells[:, 2]]
    area = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    assert (area > FOLD_MIN * 0.5 * (0.2 * 0.2)).all()  # the flat grid is its own flattening: nothing folds
    np.testing.assert_allclose(out, init, atol=1e-6)


def test_a_node_beside_a_thin_strip_of_points_stays_among_them() -> None:
    """A node whose only neighbours form a strip 1 mm wide in (u, v) (a sliver at the rim of noisy fused points):
    an affine fit across the strip is all noise, and extrapolated 15 cm off it would put the node metres away (seen
    at ci: 183 m). It must stay within the fit radius of its neighbours."""
    from clods_bench.benchmark.clods.sheet_mesh import _positions

    rng = np.random.default_rng(4)
    uv = np.column_stack([rng.uniform(0.0, 0.001, 60), rng.uniform(-0.1, 0.1, 60)])
    xyz = np.column_stack([uv, np.zeros(60)]) + rng.normal(scale=0.01, size=(60, 3))
    node = np.array([[0.15, 0.0]])
    out = _positions(uv, xyz, node, 0.23)
    assert np.linalg.norm(xyz - out[0], axis=1).min() < 0.23


def test_isomap_and_plane_sheets_agree_on_a_flat_sheet(flag_run: dict) -> None:
    """On a flag that does not turn over, the geodesic layout is turned onto the best-fit plane: the two sheets face
    the same way (the cells' winding gives the same normals) and lie along the same axes in mesh space."""
    x0, cells = flag_run["frames"][0], flag_run["mesh"].cells
    pts = sample_surface(x0, cells, 20000)
    iso, plane = (sheet_from_points(pts, 128, parameterization=p) for p in ("isomap", "plane"))

    def mean_normal(m: ClothMesh) -> np.ndarray:
        t = m.rest_pos[m.cells]
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]).sum(axis=0)
        return n / np.linalg.norm(n)

    assert float(mean_normal(iso) @ mean_normal(plane)) > 0.95
    span_iso, span_plane = np.ptp(iso.mesh_pos, axis=0), np.ptp(plane.mesh_pos, axis=0)
    np.testing.assert_allclose(span_iso, span_plane, rtol=0.1)  # u along the flag's length in both


def curled_flag(curl_radius: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """A 2 x 1 m flag: flat for its first metre, then rolled on a circle of `curl_radius` for the second (arc 1 m,
    286 degrees at 0.2 m): its free end turns back over itself, so it is no height field over any plane."""
    m = make_flag_mesh(81, 41, 2.0, 1.0)
    s, z = m.mesh_pos[:, 0].astype(np.float64), m.mesh_pos[:, 1].astype(np.float64)
    a = np.clip(s - 1.0, 0.0, None) / curl_radius
    x = np.where(s <= 1.0, s, 1.0 + curl_radius * np.sin(a))
    y = np.where(s <= 1.0, 0.0, curl_radius * (1.0 - np.cos(a)))
    return np.stack([x, y, z], axis=1), np.asarray(m.cells, np.int64)


def test_isomap_sheet_unrolls_a_flag_curled_over_itself() -> None:
    verts, cells = curled_flag()
    pts = sample_surface(verts, cells, 30000)
    iso = sheet_from_points(pts, 200)
    stats = check_sheet(iso, verts, cells, 200, 2.0)
    assert stats["rmse"] < 0.01 and stats["node_max"] < 0.02, stats
    span = iso.mesh_pos.max(axis=0) - iso.mesh_pos.min(axis=0)
    assert sorted(span) == pytest.approx([1.0, 2.0], abs=0.06)  # the rolled-up half unrolls to its true length
    # a height field over the best-fit plane averages the curl's layers: several times the error
    plane = sheet_from_points(pts, 200, parameterization="plane")
    cover = attach(verts, plane.rest_pos, plane.cells)
    plane_rmse = float(attached_rmse(plane.rest_pos[None], plane.cells, cover, verts[None])[0])
    assert plane_rmse > 4.0 * stats["rmse"], (plane_rmse, stats)


def test_sheet_from_a_two_sided_shell_finds_the_mid_surface() -> None:
    verts, cells = cylinder_sheet()
    pts = sample_surface(verts, cells, 30000)
    normals = trimesh.Trimesh(verts, cells, process=False).vertex_normals
    nrm = attach(pts, verts, cells)
    n = np.einsum("nkx,nk->nx", normals[cells[nrm.face]], nrm.bary)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    side = np.where(np.arange(len(pts)) % 2 == 0, 1.0, -1.0)
    shell = pts + 0.03 * side[:, None] * n  # both faces of a 6 cm thick shell, like a plain TSDF of a thin cloth
    mesh = sheet_from_points(shell, 150)
    stats = check_sheet(mesh, verts, cells, 150, 2.0)
    # inside, on the mid-surface; the boundary nodes follow the shell's edge, which sticks out past the cloth's
    # by up to 3 cm x sin(slope)
    dist = attach(mesh.rest_pos, verts, cells).distance
    e = np.sort(np.concatenate([mesh.cells[:, [0, 1]], mesh.cells[:, [1, 2]], mesh.cells[:, [2, 0]]]), axis=1)
    edges, counts = np.unique(e, axis=0, return_counts=True)
    boundary = np.isin(np.arange(mesh.num_nodes), edges[counts == 1])
    assert dist[~boundary].mean() < 0.003 and dist[~boundary].max() < 0.01
    assert stats["node_max"] < 0.05


def test_bad_sheet_input_is_a_clods_error() -> None:
    pts = np.random.default_rng(0).uniform(size=(100, 3))
    for kwargs, where in [
        (dict(points=pts[:, :2]), "points"),
        (dict(points=np.where(np.arange(3) == 1, np.nan, pts)), "points"),
        (dict(points=pts[:5]), "points"),
        (dict(points=np.outer(np.arange(20.0), [1.0, 2.0, 3.0])), "points"),  # a line
        (dict(num_nodes=2), "num_nodes"),
        (dict(num_nodes=50.5), "num_nodes"),
        (dict(radius=-1.0), "radius"),
        (dict(parameterization="conformal"), "parameterization"),
    ]:
        args = {"points": pts, "num_nodes": 50} | kwargs
        with pytest.raises(ClodsError) as exc:
            sheet_from_points(**args)
        assert exc.value.where == where


def test_handles_from_tracks_and_with_handles_on_synthetic_tracks() -> None:
    rng = np.random.default_rng(0)
    tracks = np.repeat(rng.normal(size=(1, 10, 3)), 5, axis=0)
    tracks[1:, 3:] += rng.normal(scale=0.1, size=(4, 7, 3))
    tracks[:, 2, 0] += 0.0005 * np.arange(5)  # drifts 2 mm: within 3 mm
    np.testing.assert_array_equal(handles_from_tracks(tracks, 0.003), [0, 1, 2])
    np.testing.assert_array_equal(handles_from_tracks(tracks, 0.001), [0, 1])
    for bad, where in [((tracks[:1], 0.1), "tracks"), ((tracks[..., :2], 0.1), "tracks"), ((tracks, -1.0), "tol")]:
        with pytest.raises(ClodsError) as exc:
            handles_from_tracks(*bad)
        assert exc.value.where == where
    flag = make_flag_mesh(4, 3)
    free = ClothMesh(flag.cells, flag.mesh_pos, np.zeros(12, np.int32), flag.rest_pos)
    pinned = with_handles(free, np.array([0, 4]))
    assert np.flatnonzero(pinned.node_type == HANDLE).tolist() == [0, 4]
    assert (free.node_type == NORMAL).all()  # a copy
    with pytest.raises(ClodsError) as exc:
        with_handles(free, [12])
    assert exc.value.where == "indices"


def test_handles_from_tracks_finds_the_pole_of_a_simulated_flag(flag_run: dict) -> None:
    mesh, frames = flag_run["mesh"], flag_run["frames"]
    x0 = frames[0]
    sheet = sheet_from_points(sample_surface(x0, mesh.cells, 30000), 128)
    # track the reconstructed nodes over the simulated frames: bind them to the true cloth at frame 0, follow it
    att = attach(sheet.rest_pos, x0, mesh.cells)
    tracks = follow(frames, mesh.cells, att)
    handles = handles_from_tracks(tracks, 0.002)
    pinned = with_handles(sheet, handles)
    validate_cloth_mesh(pinned, "test", has_handles=True)
    # every handle found lies on the pole (mesh x = 0), and the pole is covered by them from end to end
    flag_mp = np.asarray(mesh.mesh_pos, np.float64)
    foot = np.einsum("nkx,nk->nx", flag_mp[mesh.cells[att.face]], att.bary)
    spacing = np.sqrt(2.0 / sheet.num_nodes)
    assert len(handles) >= 5
    assert foot[handles, 0].max() < 0.1 * spacing
    pole = x0[mesh.node_type == HANDLE]
    gap = np.linalg.norm(pole[:, None] - sheet.rest_pos[handles][None], axis=2).min(axis=1)
    assert gap.max() < spacing
    # and every reconstructed boundary node on the pole is a handle
    on_pole = np.flatnonzero(foot[:, 0] < 0.01)
    assert set(on_pole.tolist()) <= set(handles.tolist())


# ---------------------------------------------------------------- end to end


def test_end_to_end_flag_depth_maps_to_a_simulable_sheet(flag_run: dict) -> None:
    """Simulated flag frame 0 -> 6 depth maps at 64 px -> TSDF (2 cm) -> points -> 128-node sheet -> attached RMSE."""
    mesh, x0 = flag_run["mesh"], flag_run["frames"][0]
    start = time.perf_counter()
    cams = rig(0.5 * (x0.min(0) + x0.max(0)), 6)
    depths = depth_maps(x0, mesh.cells, cams)
    vol = fuse_depth_maps(depths, cams, None, VOXEL, orient=True)
    verts, faces = trim_to_support(*extract_surface(vol), backproject(depths, cams), 1.5 * VOXEL)
    sheet = sheet_from_points(verts, 128)
    seconds = time.perf_counter() - start
    att = attach(x0, sheet.rest_pos, sheet.cells)
    rmse = float(attached_rmse(sheet.rest_pos[None], sheet.cells, att, x0[None])[0])
    print(f"\nend-to-end: {sheet.num_nodes} nodes, attached RMSE {rmse * 1000:.1f} mm "
          f"({100 * rmse / 2.0:.2f} % of 2 m), max {att.distance.max() * 1000:.1f} mm, {seconds:.2f} s")  # fmt: skip
    validate_cloth_mesh(sheet, "end-to-end", has_handles=False)
    assert abs(sheet.num_nodes - 128) <= 0.15 * 128
    assert rmse < 0.02 * 2.0
    assert seconds < 60.0
    assert mesh_pos_error(sheet) < 0.02
