"""Mesh builders and mesh file I/O: counts, handles, orientation, OBJ/PLY round trips."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from clods_bench.datasets.meshes import (
    export_sequence,
    make_cylinder_mesh,
    make_flag_mesh,
    make_flagsimple_mesh,
    mesh_from_file,
)
from clods_bench.datasets.types import HANDLE, NORMAL, Trajectory, edges_from_cells
from clods_bench.errors import ClodsError


def signed_areas(mesh_pos: np.ndarray, cells: np.ndarray) -> np.ndarray:
    a = mesh_pos[cells[:, 1]] - mesh_pos[cells[:, 0]]
    b = mesh_pos[cells[:, 2]] - mesh_pos[cells[:, 0]]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def boundary_nodes(cells: np.ndarray) -> np.ndarray:
    e = np.sort(np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    assert count.max() <= 2, "non-manifold edge"
    return np.unique(uniq[count == 1])


def test_flagsimple_counts_and_topology():
    m = make_flagsimple_mesh()
    assert (m.num_nodes, m.num_faces) == (1579, 3028)
    assert m.cells.dtype == np.int32 and m.mesh_pos.dtype == np.float32 and m.node_type.dtype == np.int32
    assert boundary_nodes(m.cells).size == 128  # F = 2V - B - 2 for a disc
    areas = signed_areas(m.mesh_pos.astype(np.float64), m.cells)
    assert areas.min() > 0  # counter-clockwise in mesh space
    assert areas.sum() == pytest.approx(2.0 * 1.0)
    handles = np.flatnonzero(m.node_type == HANDLE)
    assert handles.size == 22
    np.testing.assert_array_equal(np.flatnonzero(m.mesh_pos[:, 0] == 0), handles)
    assert set(np.unique(m.node_type)) == {NORMAL, HANDLE}


def test_flag_mesh_layout():
    m = make_flag_mesh(7, 4, length=3.0, height=1.5)
    assert (m.num_nodes, m.num_faces) == (28, 2 * 6 * 3)
    assert signed_areas(m.mesh_pos.astype(np.float64), m.cells).min() > 0
    np.testing.assert_allclose(m.rest_pos[:, 1], 0.0)  # hangs in the x-z plane
    np.testing.assert_allclose(m.rest_pos[:, [0, 2]], m.mesh_pos, atol=1e-6)
    assert m.mesh_pos[:, 0].max() == pytest.approx(3.0) and m.mesh_pos[:, 1].max() == pytest.approx(1.5)
    assert np.all((m.node_type == HANDLE) == np.isclose(m.rest_pos[:, 0], 0.0))
    assert m.uv is None
    # alternating diagonals: both diagonal directions occur
    edges = edges_from_cells(m.cells)
    d = m.mesh_pos[edges[:, 1]] - m.mesh_pos[edges[:, 0]]
    diag = (np.abs(d[:, 0]) > 1e-6) & (np.abs(d[:, 1]) > 1e-6)
    assert len(np.unique(np.sign(d[diag, 0] * d[diag, 1]))) == 2


def test_cylinder_mesh():
    n_around, n_along, r, h = 12, 5, 0.3, 1.2
    m = make_cylinder_mesh(n_around, n_along, r, h)
    assert (m.num_nodes, m.num_faces) == (60, 2 * 12 * 4)
    np.testing.assert_allclose(np.linalg.norm(m.rest_pos[:, :2], axis=1), r)
    assert len(np.unique(np.round(m.rest_pos, 9), axis=0)) == m.num_nodes  # no duplicated seam nodes
    top = np.isclose(m.rest_pos[:, 2], h)
    np.testing.assert_array_equal(m.node_type == HANDLE, top)
    assert m.uv is not None and m.uv.min() >= 0 and m.uv[:, 0].max() < 1 and m.uv[:, 1].max() == pytest.approx(1)
    assert m.mesh_pos[:, 0].max() == pytest.approx(2 * np.pi * r * (n_around - 1) / n_around, rel=1e-6)
    # a closed tube: the only boundary is the top and bottom rings
    assert boundary_nodes(m.cells).size == 2 * n_around
    # outward normals
    x = m.rest_pos
    n = np.cross(x[m.cells[:, 1]] - x[m.cells[:, 0]], x[m.cells[:, 2]] - x[m.cells[:, 0]])
    c = x[m.cells].mean(axis=1)
    assert np.all(np.einsum("fi,fi->f", n[:, :2], c[:, :2]) > 0)


@pytest.mark.parametrize("bad", [(1, 3), (3, 0)])
def test_builders_reject_bad_sizes(bad):
    with pytest.raises(ClodsError, match="make_flag_mesh"):
        make_flag_mesh(*bad)
    with pytest.raises(ClodsError, match="make_cylinder_mesh"):
        make_cylinder_mesh(bad[0], bad[1], 0.3, 1.0)


def _trajectory(mesh, frames=3):
    rng = np.random.default_rng(0)
    wp = mesh.rest_pos[None] + 0.01 * rng.standard_normal((frames, mesh.num_nodes, 3))
    return Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, wp.astype(np.float32), 0.02)


@pytest.mark.parametrize("fmt", ["obj", "ply"])
def test_export_and_read_back_flag(tmp_path, fmt):
    mesh = make_flag_mesh(9, 5)
    traj = _trajectory(mesh)
    paths = export_sequence(traj, tmp_path, fmt)
    assert [p.name for p in paths] == [f"frame_{i:04d}.{fmt}" for i in range(3)]
    assert not list(tmp_path.glob("*.tmp*"))  # atomic writes leave no temporaries
    pole = lambda rest, mesh_pos: mesh_pos[:, 0] <= mesh_pos[:, 0].min() + 1e-6  # noqa: E731
    back = mesh_from_file(paths[2], handle_fn=pole)
    np.testing.assert_array_equal(back.cells, mesh.cells)
    np.testing.assert_allclose(back.rest_pos, traj.world_pos[2], atol=1e-6)
    # mesh space comes from the UVs (bbox-normalised on export) scaled back to metres
    np.testing.assert_allclose(back.mesh_pos - back.mesh_pos.min(axis=0), mesh.mesh_pos, atol=0.02)
    np.testing.assert_array_equal(back.node_type, mesh.node_type)
    np.testing.assert_allclose(back.uv, mesh.texture_uv(), atol=1e-6)


def test_cylinder_round_trip_keeps_uv_and_top_handles(tmp_path):
    mesh = make_cylinder_mesh(16, 6, 0.3, 1.0)
    traj = Trajectory(mesh.cells, mesh.mesh_pos, mesh.node_type, np.stack([mesh.rest_pos] * 2).astype(np.float32), 0.02)
    path = export_sequence(traj, tmp_path, "obj", uv=mesh.uv)[0]
    back = mesh_from_file(path, top_tol=1e-4)
    np.testing.assert_allclose(back.uv, mesh.uv, atol=1e-6)
    np.testing.assert_array_equal(back.node_type, mesh.node_type)
    # seam edges are left out of the uv scale fit: unrolled arc vs chord differ by < 1%
    np.testing.assert_allclose(back.mesh_pos, mesh.mesh_pos, atol=0.02)


def test_mesh_without_uv_is_projected_onto_its_plane(tmp_path):
    mesh = make_flag_mesh(6, 4)
    path = tmp_path / "plain.obj"
    trimesh.Trimesh(mesh.rest_pos, mesh.cells, process=False).export(path)
    back = mesh_from_file(path)
    assert back.uv is None and np.all(back.node_type == NORMAL)
    e = edges_from_cells(mesh.cells)
    l2 = np.linalg.norm(back.mesh_pos[e[:, 0]] - back.mesh_pos[e[:, 1]], axis=1)
    l3 = np.linalg.norm(mesh.rest_pos[e[:, 0]] - mesh.rest_pos[e[:, 1]], axis=1)
    np.testing.assert_allclose(l2, l3, rtol=1e-5)


def test_bad_files_name_the_path(tmp_path):
    with pytest.raises(ClodsError, match="missing.obj"):
        mesh_from_file(tmp_path / "missing.obj")
    bad = tmp_path / "bad.ply"
    bad.write_text("this is not a mesh\n")
    with pytest.raises(ClodsError, match="bad.ply"):
        mesh_from_file(bad)
    with pytest.raises(ClodsError, match="unknown mesh format"):
        export_sequence(_trajectory(make_flag_mesh(3, 3)), tmp_path, "stl")  # type: ignore[arg-type]


def test_edge_use_counts_and_rim_of_a_grid_against_a_count_by_hand() -> None:
    from clods_bench.datasets.types import boundary_nodes, edge_use_counts, edges_from_cells

    mesh = make_flag_mesh(4, 3)  # 4 x 3 nodes: 12, of which only the 2 middle ones are off the rim
    edges, counts = edge_use_counts(mesh.cells)
    np.testing.assert_array_equal(edges, edges_from_cells(mesh.cells))
    by_hand = {}
    for tri in mesh.cells:
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            key = (min(a, b), max(a, b))
            by_hand[key] = by_hand.get(key, 0) + 1
    assert {tuple(e): int(c) for e, c in zip(edges.tolist(), counts)} == by_hand
    assert set(boundary_nodes(mesh.cells).tolist()) == set(range(12)) - {5, 6}
