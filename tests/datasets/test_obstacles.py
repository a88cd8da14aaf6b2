"""Obstacles: signed distances and normals against closed forms and brute-force references, paths, surfaces, validation."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from clods_bench.datasets.obstacle_meshes import icosphere
from clods_bench.datasets.obstacles import (
    Box,
    Capsule,
    FrameMeshObstacle,
    ObstaclePath,
    Sphere,
    TriangleMeshObstacle,
    overlap,
)
from clods_bench.errors import ClodsError


def random_points(n: int = 600, scale: float = 1.2, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-scale, scale, (n, 3))


def test_sphere_distance_and_normal_closed_form():
    c, r = np.array([0.1, -0.2, 0.05]), 0.6
    x = random_points()
    d, n, vel = Sphere(tuple(c), r).query(x, 0.3)
    rel = x - c
    dist = np.sqrt(np.sum(rel**2, axis=1))
    assert (d < 0).sum() > 20 and (d > 0).sum() > 20  # inside and outside points
    np.testing.assert_allclose(d, dist - r, atol=1e-12)
    np.testing.assert_allclose(n, rel / dist[:, None], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(x - d[:, None] * n - c, axis=1), r, atol=1e-12)  # x - d n on the sphere
    assert not vel.any()  # static


def test_box_distance_and_normal_closed_form():
    """Outside: distance to the clamped point; inside: minus the distance to the nearest face plane."""
    c, h = np.array([0.2, 0.0, -0.1]), np.array([0.5, 0.3, 0.7])
    x = random_points(2000)
    d, n, _ = Box(tuple(c), tuple(h)).query(x, 0.0)
    lo, hi = c - h, c + h
    clamped = np.clip(x, lo, hi)
    inside = (x > lo).all(axis=1) & (x < hi).all(axis=1)
    gaps = np.concatenate([x - lo, hi - x], axis=1)  # distances to the 6 face planes, inside
    ref = np.where(inside, -gaps.min(axis=1), np.linalg.norm(x - clamped, axis=1))
    assert inside.sum() > 50 and (~inside).sum() > 50
    np.testing.assert_allclose(d, ref, atol=1e-12)
    face_normals = np.concatenate([-np.eye(3), np.eye(3)])
    ref_n = np.where(inside[:, None], face_normals[gaps.argmin(axis=1)], (x - clamped) / np.maximum(ref, 1e-300)[:, None])
    np.testing.assert_allclose(n, ref_n, atol=1e-12)
    surf = x - d[:, None] * n  # the closest surface point lies on the box surface
    np.testing.assert_allclose(np.max(np.abs(surf - c) / h, axis=1), 1.0, atol=1e-12)


def test_capsule_distance_against_sampled_segment():
    a, b, r = np.array([-0.3, 0.1, 0.0]), np.array([0.4, -0.2, 0.3]), 0.25
    x = random_points(500, 0.7)
    d, n, _ = Capsule(tuple(a), tuple(b), r).query(x, 0.0)
    s = np.linspace(0.0, 1.0, 20001)
    seg = a[None] + s[:, None] * (b - a)[None]
    ref = np.sqrt(((x[:, None, :] - seg[None, :, :]) ** 2).sum(-1)).min(axis=1) - r
    assert (ref < 0).sum() > 20 and (ref > 0).sum() > 20
    np.testing.assert_allclose(d, ref, atol=1e-8)  # sampling error (spacing 4e-5 m)^2 / 2r
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    # moving from x by -d along n lands on the surface: distance r from the segment
    surf = x - d[:, None] * n
    dist_surf = np.sqrt(((surf[:, None, :] - seg[None, :, :]) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_allclose(dist_surf, r, atol=1e-8)


def _closest_reference(x: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unsigned distance of points to a triangle soup, brute force in numpy: the projection onto each triangle's
    plane when it falls inside the triangle, otherwise the nearest of its three edges (a different algorithm
    from the kernel's Voronoi regions)."""
    tri = verts[faces]  # (F,3,3)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    nrm = np.cross(b - a, c - a)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    rel = x[:, None, :] - a[None]  # (N,F,3)
    h = np.einsum("nfi,fi->nf", rel, nrm)
    proj = x[:, None, :] - h[..., None] * nrm[None]
    inside = np.ones(h.shape, bool)
    for p, q in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("nfi,fi->nf", np.cross(q - p, proj - p[None]), nrm) >= 0
    best = np.where(inside, np.abs(h), np.inf)
    for p, q in ((a, b), (b, c), (c, a)):
        e = q - p
        s = np.clip(np.einsum("nfi,fi->nf", x[:, None, :] - p[None], e) / np.einsum("fi,fi->f", e, e), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(x[:, None, :] - (p[None] + s[..., None] * e[None]), axis=2))
    return best.min(axis=1)


def bumpy_sheet(n: int = 6, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """An open, non-convex height-field mesh (normals up)."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.linspace(-0.5, 0.5, n), np.linspace(-0.5, 0.5, n), indexing="xy")
    verts = np.stack([xs.ravel(), ys.ravel(), 0.15 * rng.standard_normal(n * n)], axis=1)
    faces = []
    for j in range(n - 1):
        for i in range(n - 1):
            v = i + n * j
            faces += [(v, v + 1, v + n + 1), (v, v + n + 1, v + n)]
    return verts, np.array(faces, np.int32)


def test_mesh_distance_matches_brute_force_reference():
    verts, faces = bumpy_sheet()
    x = random_points(400, 0.8, seed=2)
    d, n, _ = TriangleMeshObstacle(verts, faces).query(x, 0.0)
    np.testing.assert_allclose(np.abs(d), _closest_reference(x, verts, faces), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    # the mesh is closed here (a box), so the kernel's distance is also checked with a sign
    bv, bf = Box((0.1, 0.0, 0.0), (0.3, 0.4, 0.2)).surface(0.0)
    d, _, _ = TriangleMeshObstacle(bv, bf).query(x, 0.0)
    np.testing.assert_allclose(np.abs(d), _closest_reference(x, bv, bf), atol=1e-12)


def winding_number(x: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Generalised winding number of a closed mesh at points x (1 inside, 0 outside): the triangles' solid angles
    (Van Oosterom & Strackee 1983) summed over 4 pi."""
    r = verts[faces][None] - x[:, None, None, :]  # (N,F,3,3)
    a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
    la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
    num = np.einsum("nfi,nfi->nf", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("nfi,nfi->nf", a, b) * lc + np.einsum("nfi,nfi->nf", b, c) * la + np.einsum("nfi,nfi->nf", c, a) * lb
    return (2.0 * np.arctan2(num, den)).sum(axis=1) / (4.0 * np.pi)


def test_nonconvex_closed_mesh_signs_match_winding_number():
    """A bumpy (star-shaped, non-convex) icosphere: near its vertices, edges and faces, the sign of the distance says
    inside exactly where the winding number does (a face-normal-only sign fails at concave edges and corners)."""
    rng = np.random.default_rng(9)
    unit, faces = icosphere(2)
    verts = unit * rng.uniform(0.65, 1.35, (unit.shape[0], 1))
    x = np.concatenate([verts + rng.normal(0.0, 0.05, verts.shape), rng.uniform(-1.4, 1.4, (300, 3))])
    d, n, _ = TriangleMeshObstacle(verts, faces).query(x, 0.0)
    inside = winding_number(x, verts, faces) > 0.5
    assert inside.sum() > 100 and (~inside).sum() > 100
    np.testing.assert_array_equal(d < 0, inside)
    np.testing.assert_allclose(np.abs(d), _closest_reference(x, verts, faces), atol=1e-12)
    np.testing.assert_allclose(np.abs(TriangleMeshObstacle(verts, faces).query(x - d[:, None] * n, 0.0)[0]), 0.0, atol=1e-12)


def test_box_mesh_equals_analytic_box_with_signs_and_normals():
    """The 12-triangle box mesh is the box exactly: distance, sign (inside/outside near faces, edges, corners) and normal."""
    box = Box((0.1, -0.2, 0.3), (0.4, 0.25, 0.6))
    mesh = TriangleMeshObstacle(*box.surface(0.0))
    x = random_points(3000, 1.0, seed=4)
    d_ref, n_ref, _ = box.query(x, 0.0)
    d, n, _ = mesh.query(x, 0.0)
    assert (d_ref < 0).sum() > 100
    np.testing.assert_allclose(d, d_ref, atol=1e-12)
    np.testing.assert_allclose(n, n_ref, atol=1e-9)


def test_icosphere_mesh_matches_sphere_within_tessellation_error():
    r = 0.7
    verts, faces = Sphere((0.0, 0.0, 0.0), r, subdivisions=3).surface(0.0)
    tri = verts[faces]
    sag = r - np.abs(_closest_reference(np.zeros((1, 3)), verts, faces))[0]  # deepest gap between mesh and sphere
    assert 0 < sag < 0.01 * r
    x = random_points(800, 1.4, seed=5)
    d_mesh, n_mesh, _ = TriangleMeshObstacle(verts, faces).query(x, 0.0)
    d_ref, n_ref, _ = Sphere((0.0, 0.0, 0.0), r).query(x, 0.0)
    assert (d_ref < -sag).sum() > 50
    assert np.all(d_mesh >= d_ref - 1e-12) and np.all(d_mesh <= d_ref + sag + 1e-12)  # inscribed polyhedron
    far = np.abs(d_ref) > 0.1
    cos = np.einsum("ni,ni->n", n_mesh[far], n_ref[far])
    assert cos.min() > np.cos(np.radians(10.0))
    assert np.isclose(np.linalg.norm(tri, axis=2), r).all()


def test_open_mesh_sign_follows_face_normal():
    verts = np.array([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])  # normal +z
    rng = np.random.default_rng(6)
    x = np.column_stack([rng.uniform(-0.9, 0.9, (200, 2)), rng.uniform(-0.5, 0.5, 200)])
    d, n, _ = TriangleMeshObstacle(verts, faces).query(x, 0.0)
    np.testing.assert_allclose(d, x[:, 2], atol=1e-12)
    np.testing.assert_allclose(n, np.tile([0.0, 0.0, 1.0], (200, 1)), atol=1e-12)


def closed_and_outward(verts: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume of a mesh, after checking each directed edge appears once and its reverse once (closed, consistent)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    directed = {tuple(p) for p in e.tolist()}
    assert len(directed) == e.shape[0]
    assert all((b, a) in directed for a, b in directed)
    tri = verts[faces]
    return float(np.einsum("fi,fi->f", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def test_surfaces_are_closed_outward_and_on_the_shape():
    sphere = Sphere((0.0, 0.1, 0.2), 0.5, subdivisions=2)
    capsule = Capsule((0.0, 0.0, 0.0), (0.3, 0.4, 0.0), 0.2)
    box = Box((1.0, 0.0, 0.0), (0.1, 0.2, 0.3))
    for shape, volume, tol in (
        (sphere, 4 / 3 * np.pi * 0.5**3, 0.06),
        (capsule, np.pi * 0.2**2 * 0.5 + 4 / 3 * np.pi * 0.2**3, 0.06),
        (box, 0.2 * 0.4 * 0.6, 1e-12),
    ):
        verts, faces = shape.surface(0.0)
        assert verts.dtype == np.float64 and faces.dtype == np.int32
        assert closed_and_outward(verts, faces) == pytest.approx(volume, rel=tol)
        d, _, _ = shape.query(verts, 0.0)
        np.testing.assert_allclose(d, 0.0, atol=1e-12)  # vertices lie on the exact surface
    assert icosphere(2)[1].shape == (320, 3) and icosphere(0)[0].shape == (12, 3)


def test_path_offset_velocity_and_holding():
    path = ObstaclePath(times=(0.5, 1.0, 2.5), offsets=((0.0, 0.0, 0.0), (0.3, -0.2, 0.1), (0.3, 0.4, -0.5)))
    for t, off in ((0.5, 0), (1.0, 1), (2.5, 2)):
        np.testing.assert_allclose(path.offset(t), path.offsets[off], atol=1e-15)
    for t in (-3.0, 0.0, 0.49):
        np.testing.assert_array_equal(path.offset(t), path.offsets[0])
        np.testing.assert_array_equal(path.velocity(t), 0.0)
    for t in (2.51, 10.0):
        np.testing.assert_array_equal(path.offset(t), path.offsets[-1])
        np.testing.assert_array_equal(path.velocity(t), 0.0)
    h = 1e-6
    for t in np.random.default_rng(7).uniform(0.3, 2.7, 40):
        fd = (path.offset(t + h) - path.offset(t - h)) / (2 * h)
        np.testing.assert_allclose(path.velocity(t), fd, atol=1e-7)
    for knot in path.times:  # C1: no velocity jump at the knots
        assert np.abs(path.velocity(knot - 1e-9)).max() < 1e-6 and np.abs(path.velocity(knot + 1e-9)).max() < 1e-6
    mid = 0.5 * (1.0 + 2.5)  # smoothstep: mid-segment speed is 1.5 x the mean speed
    np.testing.assert_allclose(path.velocity(mid), 1.5 * (np.array(path.offsets[2]) - path.offsets[1]) / 1.5, atol=1e-12)


def test_moving_obstacle_translates_query_and_surface():
    path = ObstaclePath(times=(0.0, 1.0), offsets=((0.0, 0.0, 0.0), (0.5, 0.0, -0.2)))
    moving = Sphere((0.0, 0.0, 0.0), 0.3, path=path)
    still = Sphere((0.0, 0.0, 0.0), 0.3)
    x = random_points(50)
    v0, f0 = moving.surface(0.0)
    for t in (0.25, 0.6, 3.0):
        v, f = moving.surface(t)
        np.testing.assert_array_equal(f, f0)  # same topology at every t
        np.testing.assert_allclose(v - v0, np.broadcast_to(path.offset(t), v.shape), atol=1e-15)
        d, n, vel = moving.query(x, t)
        d_ref, n_ref, _ = still.query(x - path.offset(t), 0.0)
        np.testing.assert_allclose(d, d_ref, atol=1e-12)
        np.testing.assert_allclose(n, n_ref, atol=1e-12)
        np.testing.assert_allclose(vel, np.broadcast_to(path.velocity(t), vel.shape))
    assert np.abs(moving.query(x, 0.5)[2]).max() > 0.5  # the obstacle really moves at t = 0.5


def test_from_frames_interpolates_positions_and_velocities():
    verts, faces = Box((0.0, 0.0, 0.0), (0.2, 0.2, 0.2)).surface(0.0)
    rng = np.random.default_rng(8)
    dt, steps = 0.1, np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.3, 0.0], [0.1, 0.3, -0.2]])
    frames = verts[None] + np.cumsum(steps, axis=0)[:, None, :]  # rigid moves, each frame to the next
    obstacle = TriangleMeshObstacle.from_frames(frames, faces, dt)
    assert isinstance(obstacle, FrameMeshObstacle)
    obstacle.validate("recorded")
    x = rng.uniform(-0.6, 0.6, (100, 3))
    for t, k, s in ((0.13, 1, 0.3), (0.25, 2, 0.5), (0.0, 0, 0.0)):
        pos, f = obstacle.surface(t)
        np.testing.assert_array_equal(f, faces)
        np.testing.assert_allclose(pos, (1 - s) * frames[k] + s * frames[k + 1], atol=1e-12)
        d, n, vel = obstacle.query(x, t)
        d_ref, n_ref, _ = TriangleMeshObstacle(pos, faces).query(x, 0.0)
        np.testing.assert_allclose(d, d_ref, atol=1e-12)
        np.testing.assert_allclose(vel, np.broadcast_to((frames[k + 1, 0] - frames[k, 0]) / dt, vel.shape), atol=1e-9)
    for t, k in ((-1.0, 0), (0.31, 3), (5.0, 3)):  # held before the first and after the last frame
        np.testing.assert_allclose(obstacle.surface(t)[0], frames[k], atol=1e-12)
        assert not obstacle.query(x, t)[2].any()
    # a deforming mesh: the surface velocity at a vertex is that vertex's finite difference
    grow = np.stack([verts, 1.5 * verts])
    d, _, vel = TriangleMeshObstacle.from_frames(grow, faces, 1.0).query(1.2 * verts + 1e-3 * np.sign(verts), 0.4)
    np.testing.assert_allclose(vel, 0.5 * verts, atol=1e-9)


def test_overlap_flags_points_inside_or_within_margin():
    obstacles = [Sphere((0.0, 0.0, 0.0), 0.5), Box((2.0, 0.0, 0.0), (0.2, 0.2, 0.2))]
    x = np.array([[0.0, 0.0, 0.4], [0.0, 0.0, 0.55], [0.0, 0.0, 0.7], [2.0, 0.0, 0.1], [2.0, 0.0, 0.25], [1.0, 0.0, 0.0]])
    np.testing.assert_array_equal(overlap(obstacles, x, 0.0), [True, False, False, True, False, False])
    np.testing.assert_array_equal(overlap(obstacles, x, 0.0, margin=0.1), [True, True, False, True, True, False])
    assert overlap([], x, 0.0).shape == (6,) and not overlap([], x, 0.0).any()


def test_obstacles_pickle_and_stay_frozen():
    verts, faces = icosphere(1)
    for obstacle in (Sphere((0.0, 0.0, 0.0), 1.0), TriangleMeshObstacle(verts, faces)):
        copy = pickle.loads(pickle.dumps(obstacle))
        x = random_points(20)
        np.testing.assert_array_equal(copy.query(x, 0.0)[0], obstacle.query(x, 0.0)[0])
        with pytest.raises(dataclasses.FrozenInstanceError):
            obstacle.path = None  # type: ignore[misc]


@pytest.mark.parametrize(
    "obstacle, field",
    [
        (Sphere((0.0, 0.0, 0.0), -1.0), "ob.radius"),
        (Sphere((0.0, float("nan"), 0.0), 1.0), "ob.center"),
        (Sphere((0.0, 0.0, 0.0), 1.0, subdivisions=9), "ob.subdivisions"),
        (Capsule((0.0, 0.0, 0.0), (1.0, 0.0), 0.1), "ob.b"),  # type: ignore[arg-type]
        (Capsule((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0.0), "ob.radius"),
        (Box((0.0, 0.0, 0.0), (1.0, 0.0, 1.0)), "ob.half_extents"),
        (Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), path=ObstaclePath((0.0, 0.0), ((0, 0, 0), (1, 0, 0)))), "ob.path.times"),
        (Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), path=ObstaclePath((0.0, 1.0), ((0, 0, 0),))), "ob.path.times"),
        (Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), path=ObstaclePath((0.0, 1.0), ((0, 0, 0), (1, 0, float("inf"))))), "ob.path.offsets[1]"),
        (TriangleMeshObstacle(np.zeros((3, 2)), np.array([[0, 1, 2]])), "ob.vertices"),
        (TriangleMeshObstacle(np.eye(3), np.array([[0, 1, 3]])), "ob.faces"),
        (TriangleMeshObstacle(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), np.array([[0, 1, 2]])), "ob.faces"),  # zero area
        (FrameMeshObstacle(np.eye(3)[None], np.array([[0, 1, 2]]), 0.0), "ob.dt"),
        (FrameMeshObstacle(np.eye(3), np.array([[0, 1, 2]]), 0.1), "ob.frames"),
    ],
)
def test_validation_names_the_field(obstacle, field):
    with pytest.raises(ClodsError) as err:
        obstacle.validate("ob")
    assert err.value.where == field
