"""Cross-topology scoring: closest points on a triangle mesh against an independent numpy reference, barycentric
following through frames, attached-point RMSE, and the Chamfer distance against brute force."""

from __future__ import annotations

import numpy as np
import pytest

from clods_bench.benchmark.scoring.cross_topology import attach, attached_rmse, chamfer, chamfer_per_frame, follow
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.errors import ClodsError


def wavy_flag(nx: int = 9, ny: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A flag mesh bent out of its plane: verts (V,3), faces (F,3)."""
    m = make_flag_mesh(nx, ny, 2.0, 1.0)
    v = np.asarray(m.rest_pos, np.float64).copy()
    v[:, 1] = 0.2 * np.sin(2.0 * v[:, 0]) + 0.05 * v[:, 2] ** 2
    return v, np.asarray(m.cells, np.int64)


def points_on(verts: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n random points on the mesh: positions, their faces and barycentric coordinates."""
    f = rng.integers(0, faces.shape[0], n)
    b = rng.dirichlet(np.ones(3), n)
    return np.einsum("nkx,nk->nx", verts[faces[f]], b), f, b


def _seg_closest(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(np.einsum("nx,nx->n", p - a, ab) / np.maximum(np.einsum("nx,nx->n", ab, ab), 1e-300), 0.0, 1.0)
    return a + t[:, None] * ab


def reference_closest(points: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Distance from each point to the mesh, brute force: the plane projection when it falls inside the triangle
    (sign test of the three sub-triangles), else the nearest of the three edges' closest points."""
    out = np.full(points.shape[0], np.inf)
    for f in faces:
        a, b, c = (np.broadcast_to(verts[i], points.shape) for i in f)
        n = np.cross(b - a, c - a)
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        proj = points - np.einsum("nx,nx->n", points - a, n)[:, None] * n
        inside = np.ones(points.shape[0], bool)
        for s, e in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("nx,nx->n", np.cross(e - s, proj - s), n) >= 0
        cands = [_seg_closest(points, a, b), _seg_closest(points, b, c), _seg_closest(points, c, a)]
        d = np.min([np.linalg.norm(points - q, axis=1) for q in cands], axis=0)
        d = np.where(inside, np.linalg.norm(points - proj, axis=1), d)
        out = np.minimum(out, d)
    return out


def test_points_on_the_mesh_attach_at_distance_zero_and_are_reproduced() -> None:
    rng = np.random.default_rng(0)
    v, f = wavy_flag()
    p, face, bary = points_on(v, f, 300, rng)
    att = attach(p, v, f)
    assert att.distance.max() < 1e-9
    np.testing.assert_allclose(follow(v[None], f, att)[0], p, atol=1e-9)
    # in a triangle's interior the face and coordinates are the ones the point was made from
    interior = bary.min(axis=1) > 1e-3
    assert np.mean(att.face[interior] == face[interior]) > 0.99
    np.testing.assert_allclose(att.bary[interior][att.face[interior] == face[interior]],
                               bary[interior][att.face[interior] == face[interior]], atol=1e-9)  # fmt: skip


def test_barycentric_coordinates_are_a_convex_combination() -> None:
    rng = np.random.default_rng(1)
    v, f = wavy_flag()
    p = rng.uniform(v.min(0) - 0.5, v.max(0) + 0.5, (500, 3))
    att = attach(p, v, f)
    assert att.bary.shape == (500, 3) and att.face.shape == (500,) and att.distance.shape == (500,)
    assert (att.bary >= 0).all()
    np.testing.assert_allclose(att.bary.sum(axis=1), 1.0, atol=1e-12)
    # the distance is the one to the point the coordinates describe
    foot = follow(v[None], f, att)[0]
    np.testing.assert_allclose(np.linalg.norm(p - foot, axis=1), att.distance, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_closest_point_matches_a_brute_force_reference_on_a_random_mesh(seed: int) -> None:
    rng = np.random.default_rng(seed)
    verts = rng.normal(size=(40, 3))
    faces = np.array([rng.choice(40, 3, replace=False) for _ in range(60)])
    points = rng.normal(scale=1.5, size=(400, 3))
    att = attach(points, verts, faces)
    np.testing.assert_allclose(att.distance, reference_closest(points, verts, faces), atol=1e-9)


def test_following_the_same_topology_is_exact() -> None:
    rng = np.random.default_rng(2)
    v, f = wavy_flag()
    frames = v[None] + np.cumsum(rng.normal(scale=0.02, size=(6, *v.shape)), axis=0)
    frames[0] = v
    att = attach(v, v, f)  # the ground-truth nodes bound to their own mesh
    np.testing.assert_allclose(follow(frames, f, att), frames, atol=1e-9)
    np.testing.assert_allclose(attached_rmse(frames, f, att, frames), 0.0, atol=1e-9)
    # and points inside triangles: followed positions = barycentric combination in every frame
    p, face, bary = points_on(v, f, 50, rng)
    gt = np.einsum("tnkx,nk->tnx", frames[:, f[face]], bary)
    np.testing.assert_allclose(attached_rmse(frames, f, attach(p, v, f), gt), 0.0, atol=1e-9)


def test_attached_rmse_measures_a_shift() -> None:
    v, f = wavy_flag()
    att = attach(v, v, f)
    shifted = v[None] + np.array([0.0, 0.03, 0.04])
    np.testing.assert_allclose(attached_rmse(shifted, f, att, v[None]), [0.05], atol=1e-12)


def test_chamfer_matches_brute_force_is_symmetric_and_zero_on_identical_sets() -> None:
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(120, 3)), rng.normal(loc=0.3, size=(80, 3))
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    ref = 0.5 * (d.min(axis=1).mean() + d.min(axis=0).mean())
    assert chamfer(a, b) == pytest.approx(ref, rel=1e-12)
    assert chamfer(b, a) == pytest.approx(chamfer(a, b), rel=1e-12)
    assert chamfer(a, a) == 0.0
    assert chamfer(a, a[::-1]) == 0.0
    per = chamfer_per_frame(np.stack([a, a + 1.0]), np.stack([b, b + 1.0]))
    np.testing.assert_allclose(per, [ref, ref], rtol=1e-9)
    # distances, not squared: a set moved by 0.1 is 0.1 away
    assert chamfer(np.zeros((1, 3)), np.array([[0.1, 0.0, 0.0]])) == pytest.approx(0.1)


def test_bad_input_is_a_clods_error_naming_the_argument() -> None:
    v, f = wavy_flag()
    with pytest.raises(ClodsError) as exc:
        attach(np.zeros((3, 2)), v, f)
    assert exc.value.where == "points"
    with pytest.raises(ClodsError) as exc:
        attach(np.full((2, 3), np.nan), v, f)
    assert exc.value.where == "points"
    with pytest.raises(ClodsError) as exc:
        attach(np.zeros((2, 3)), v, f + v.shape[0])
    assert exc.value.where == "faces"
    att = attach(v, v, f)
    with pytest.raises(ClodsError) as exc:
        attached_rmse(v[None], f, att, v[None, :5])
    assert exc.value.where == "gt_frames"
    with pytest.raises(ClodsError) as exc:
        follow(v[None], f[:3], att)
    assert exc.value.where == "att.face"
    with pytest.raises(ClodsError) as exc:
        chamfer(np.zeros((0, 3)), v)
    assert exc.value.where == "a"
    with pytest.raises(ClodsError) as exc:
        chamfer_per_frame(v[None], np.stack([v, v]))
    assert exc.value.where == "b_frames"
