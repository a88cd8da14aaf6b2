"""The cloth solver against closed forms, finite differences and physical invariants."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from clods_bench.datasets import cloth_energy, wind
from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.types import NORMAL, ClothMesh, edges_from_cells
from clods_bench.errors import ClodsError

STILL = SolverParams(air_density=0.0, air_drag=0.0)  # no aerodynamics, no damping


def curtain(nx: int = 7, ny: int = 5) -> ClothMesh:
    """A 1 m x 1 m flag turned so the pinned edge is horizontal on top: it hangs under tension."""
    m = make_flag_mesh(nx, ny, 1.0, 1.0)
    r = m.rest_pos
    return dataclasses.replace(m, rest_pos=np.stack([r[:, 2], 0.0 * r[:, 0], -r[:, 0]], axis=1))


def swing_velocity(mesh: ClothMesh, speed: float) -> np.ndarray:
    """Out-of-plane velocity growing linearly with depth below the pinned edge (a pendulum push)."""
    v = np.zeros_like(mesh.rest_pos)
    v[:, 1] = -speed * mesh.rest_pos[:, 2]
    v[mesh.node_type != NORMAL] = 0.0
    return v


def max_strain(mesh: ClothMesh, x: np.ndarray) -> float:
    e = edges_from_cells(mesh.cells)
    rest = np.linalg.norm(mesh.rest_pos[e[:, 0]] - mesh.rest_pos[e[:, 1]], axis=1)
    return float(np.max(np.abs(np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) / rest - 1.0)))


def test_free_fall_matches_backward_euler_closed_form():
    """Unpinned cloth, uniform v0: elastic forces vanish (rigid translation), so backward Euler gives
    x_n = x0 + v0 t + g t^2/2 + g t dt/2 exactly: the O(dt) error against the exact parabola is
    |g| t dt / 2 (0.098 m at t = 1 s, dt = 0.02). Tolerance 1e-5 m covers float32 output rounding."""
    m = make_flag_mesh(6, 4)
    m = dataclasses.replace(m, node_type=np.zeros_like(m.node_type))
    dt, n = 0.02, 51
    solver = ClothSolver(m, dataclasses.replace(STILL, cg_tol=1e-12), dt)
    v0 = np.tile([0.3, -0.2, 1.0], (m.num_nodes, 1))
    out = solver.simulate(m.rest_pos, v0, n).astype(np.float64)
    t = dt * np.arange(n)[:, None, None]
    g = np.array(STILL.gravity)
    exact = m.rest_pos[None] + v0[None] * t + 0.5 * g * t**2
    np.testing.assert_allclose(out, exact + 0.5 * g * t * dt, atol=1e-5)
    err = np.abs(out - exact)[..., 2].max()
    assert err == pytest.approx(0.5 * 9.81 * 1.0 * dt, rel=1e-3)


def test_damped_pinned_cloth_comes_to_rest():
    """Mass damping a = 2/s: pendulum energy decays like exp(-a t); after 8 s, KE < 1e-6 of its start."""
    m = curtain(9, 6)
    solver = ClothSolver(m, dataclasses.replace(STILL, damping_mass=2.0), 0.02)
    x, v = m.rest_pos.copy(), swing_velocity(m, 2.0)
    ke0 = solver.energy(x, v)["kinetic"]
    for i in range(400):
        x, v = solver.step(x, v, i * 0.02)
    assert solver.energy(x, v)["kinetic"] < 1e-6 * ke0
    assert max_strain(m, x) < 0.05
    handles = m.node_type != NORMAL
    np.testing.assert_array_equal(x[handles], m.rest_pos[handles])  # pinned nodes never move


def door_velocity(mesh: ClothMesh, speed: float) -> np.ndarray:
    """Out-of-plane velocity of the upright flag growing with distance from its pole (a door push)."""
    v = np.zeros_like(mesh.rest_pos)
    v[:, 1] = speed * mesh.rest_pos[:, 0]
    return v


@pytest.mark.parametrize(
    "mesh, v0",
    [(curtain(), swing_velocity(curtain(), 1.5)), (make_flag_mesh(9, 5), door_velocity(make_flag_mesh(9, 5), 0.75))],
    ids=["hanging", "upright"],
)
def test_energy_does_not_grow_without_damping_or_wind(mesh, v0):
    """Backward Euler dissipates: total energy never exceeds its initial value (1e-9 J slack)."""
    solver = ClothSolver(mesh, dataclasses.replace(STILL, cg_tol=1e-10), 0.02)
    x, v = mesh.rest_pos.copy(), v0
    e0 = solver.energy(x, v)["total"]
    totals = []
    for i in range(150):
        x, v = solver.step(x, v, i * 0.02)
        totals.append(solver.energy(x, v)["total"])
    assert max(totals) <= e0 + 1e-9
    assert totals[-1] < e0


def _geometry(seed: int = 0):
    m = make_flag_mesh(5, 4)
    rng = np.random.default_rng(seed)
    x = m.rest_pos + 0.05 * rng.standard_normal(m.rest_pos.shape)
    return m, cloth_energy.rest_geometry(m), x, rng


def test_membrane_forces_and_hessian_match_finite_differences():
    m, geo, x, rng = _geometry()
    mu, lam = cloth_energy.lame_from_young(1000.0, 0.3)
    _, f = cloth_energy.membrane_energy_forces(x, geo, mu, lam)
    d, h = rng.standard_normal(x.shape), 1e-6
    ep, fp = cloth_energy.membrane_energy_forces(x + h * d, geo, mu, lam)
    em, fm = cloth_energy.membrane_energy_forces(x - h * d, geo, mu, lam)
    assert -np.sum(f * d) == pytest.approx((ep - em) / (2 * h), rel=1e-6)
    hess = cloth_energy.membrane_hessian_dense(x, geo, mu, lam, project=False)
    fd = -(fp - fm).ravel() / (2 * h)
    np.testing.assert_allclose(hess @ d.ravel(), fd, atol=1e-6 * np.abs(fd).max())
    np.testing.assert_allclose(hess, hess.T, atol=1e-9 * np.abs(hess).max())
    # the projected Hessian used by the integrator is PSD even in compression (the exact one is not)
    assert np.linalg.eigvalsh(hess).min() < 0
    proj = cloth_energy.membrane_hessian_dense(x, geo, mu, lam, project=True)
    assert np.linalg.eigvalsh(proj).min() > -1e-9 * np.abs(proj).max()


def test_bending_is_zero_when_flat_and_matches_finite_differences():
    m, geo, x, rng = _geometry(1)
    q = cloth_energy.bending_matrix(geo, m.num_nodes)
    affine = m.rest_pos @ rng.standard_normal((3, 3)) + rng.standard_normal(3)
    assert np.abs(q @ affine).max() < 1e-10  # any affine image of the flat sheet is unbent
    d, h = rng.standard_normal(x.shape), 1e-6
    fd = (cloth_energy.bending_energy(x + h * d, q) - cloth_energy.bending_energy(x - h * d, q)) / (2 * h)
    assert np.sum((q @ x) * d) == pytest.approx(fd, rel=1e-6)
    assert np.linalg.eigvalsh(q.toarray()).min() > -1e-9  # constant PSD Hessian


def test_solver_forces_are_minus_energy_gradient():
    """Membrane + bending + gravity forces of the solver against its own energy() by central differences."""
    m, _, x, rng = _geometry(2)
    solver = ClothSolver(m, SolverParams(bending_stiffness=0.05), 0.02)
    f_el, _ = solver._forces(x)
    f = f_el + solver.mass[:, None] * np.asarray(solver.params.gravity)[None]
    d, h, zero = rng.standard_normal(x.shape), 1e-6, np.zeros_like(x)
    ep = solver.energy(x + h * d, zero)["total"]
    em = solver.energy(x - h * d, zero)["total"]
    assert -np.sum(f * d) == pytest.approx((ep - em) / (2 * h), rel=1e-6)


def test_wind_force_closed_form_and_velocity_jacobian():
    cells = np.array([[0, 1, 2]], dtype=np.int64)
    x = np.array([[0.0, 0, 0], [2, 0, 0], [0, 1, 0]])  # area 1, normal +z
    rho, drag, w = 1.2, 0.3, np.array([3.0, 0.0, -5.0])
    empty = np.zeros((0, 3))
    tri_map = np.arange(9, dtype=np.int64).reshape(1, 3, 3)

    def force(v):
        out, blocks = np.zeros((3, 3)), np.zeros((9, 3, 3))
        wind.wind_kernel(x, v, cells, 0.0, w, empty, np.zeros(0), empty, np.zeros(0), rho, drag, out, blocks, tri_map, 1.0)
        return out, blocks

    f, blocks = force(np.zeros((3, 3)))
    expected = (rho * 1.0 * 5.0 * np.array([0, 0, -5.0]) + drag * 1.0 * np.array([3.0, 0, 0])) / 3
    np.testing.assert_allclose(f, np.tile(expected, (3, 1)))
    rng = np.random.default_rng(3)
    v, d, h = rng.standard_normal((3, 3)), rng.standard_normal((3, 3)), 1e-6
    _, blocks = force(v)
    jd = np.einsum("abij,bj->ai", blocks.reshape(3, 3, 3, 3), d)
    fd = (force(v + h * d)[0] - force(v - h * d)[0]) / (2 * h)
    np.testing.assert_allclose(-jd, fd, rtol=1e-6, atol=1e-9)


def test_halving_dt_converges():
    """Same physical time (0.2 s), dt = 0.02 / 2^k via substeps: successive differences halve
    (first order), with 1 Newton iteration and with 3 (fully converged implicit Euler)."""
    m = curtain()
    v0 = swing_velocity(m, 1.0)
    for newton in (1, 3):
        solver = ClothSolver(m, dataclasses.replace(STILL, cg_tol=1e-12, newton_iterations=newton), 0.02)
        ends = [solver.simulate(m.rest_pos, v0, 11, substeps=k)[-1].astype(np.float64) for k in (1, 2, 4, 8)]
        diffs = [np.sqrt(np.mean((a - b) ** 2)) for a, b in zip(ends[:-1], ends[1:])]
        ratios = np.array(diffs[1:]) / np.array(diffs[:-1])
        assert np.all((ratios > 0.4) & (ratios < 0.65)), (newton, diffs)


def test_stiff_cloth_and_large_steps_stay_bounded():
    """Membrane and bending 50x stiffer at dt = 0.02, and the default cloth at dt = 0.05, in gusty wind."""
    m = make_flag_mesh(9, 5)
    gusty = SolverParams(wind_velocity=(8.0, 2.0, 0.0), turbulence_amplitude=2.0, wind_ramp_time=0.5)
    for params, dt, bound in ((gusty.scaled(50.0, 50.0), 0.02, 0.01), (gusty, 0.05, 0.25)):
        out = ClothSolver(m, params, dt, seed=1).simulate(m.rest_pos, np.zeros_like(m.rest_pos), 401)
        assert np.isfinite(out).all()
        assert max(max_strain(m, frame.astype(np.float64)) for frame in out[::10]) < bound


def test_moving_handles_follow_their_path():
    m = curtain(5, 4)
    handles = np.flatnonzero(m.node_type != NORMAL)
    path = lambda t: m.rest_pos[handles] + np.array([0.3 * np.sin(2.0 * t), 0.0, 0.0])  # noqa: E731
    solver = ClothSolver(m, STILL, 0.02, handle_fn=path)
    out = solver.simulate(m.rest_pos, np.zeros_like(m.rest_pos), 21)
    np.testing.assert_allclose(out[20][handles], path(0.4), atol=1e-6)
    assert np.isfinite(out).all()


def test_bad_parameters_are_named():
    with pytest.raises(ClodsError, match="density"):
        SolverParams(density=-1.0).validate()
    with pytest.raises(ClodsError, match="wind_velocity"):
        SolverParams(wind_velocity=(1.0, 2.0)).validate()  # type: ignore[arg-type]
    with pytest.raises(ClodsError, match="dt"):
        ClothSolver(make_flag_mesh(3, 3), SolverParams(), 0.0)


def spherical_cap() -> ClothMesh:
    """An irregular, curved cloth: the part of a 0.5 m icosphere above z = -0.15 (no grid, curved rest shape)."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    faces = sphere.faces[(sphere.vertices[sphere.faces][:, :, 2] > -0.15).all(axis=1)]
    used, cells = np.unique(faces, return_inverse=True)
    rest = sphere.vertices[used] + [0.0, 0.0, 2.0]
    node_type = np.full(used.size, NORMAL, np.int32)
    mesh_pos = rest[:, :2].astype(np.float32)  # the solver takes its rest metric from rest_pos
    return ClothMesh(cells.reshape(-1, 3).astype(np.int32), mesh_pos, node_type, rest)


def test_arbitrary_mesh_with_every_node_pinned_stays_exactly_still():
    m = spherical_cap()
    m = dataclasses.replace(m, node_type=np.full(m.num_nodes, 3, np.int32))
    windy = SolverParams(wind_velocity=(6.0, 2.0, 0.0), turbulence_amplitude=2.0)
    out = ClothSolver(m, windy, 0.02, seed=3).simulate(m.rest_pos, np.zeros_like(m.rest_pos), 20)
    np.testing.assert_array_equal(out, np.broadcast_to(m.rest_pos.astype(np.float32), out.shape))


def test_free_arbitrary_mesh_falls_with_g():
    """No handles, no air: internal (membrane + bending) forces sum to zero, so the mass-weighted centre follows
    backward Euler's free fall exactly, z0 + v0 t - g t^2/2 - g t dt/2, while the shape changes (the flat-rest
    bending model flattens the cap), i.e. the forces are there but cancel."""
    m = spherical_cap()
    assert m.num_nodes > 100 and cloth_energy.find_hinges(m.cells).shape[0] > 200
    dt, n = 0.02, 26
    solver = ClothSolver(m, dataclasses.replace(STILL, cg_tol=1e-12, bending_stiffness=2e-2), dt)
    v0 = np.tile([0.1, 0.0, 0.5], (m.num_nodes, 1))
    out = solver.simulate(m.rest_pos, v0, n).astype(np.float64)
    w = solver.mass / solver.mass.sum()
    com = np.einsum("v,tvd->td", w, out)
    t = dt * np.arange(n)[:, None]
    g = np.array(STILL.gravity)
    expected = w @ m.rest_pos + v0[0] * t + 0.5 * g * t**2 + 0.5 * g * t * dt
    np.testing.assert_allclose(com, expected, atol=2e-6)
    shape_change = np.abs((out[-1] - com[-1]) - (m.rest_pos - com[0])).max()
    assert shape_change > 1e-3


def test_solver_does_not_depend_on_node_or_face_order():
    """The flag with its nodes and faces shuffled gives the same motion, node for node (up to CG tolerance)."""
    m = curtain(6, 5)
    rng = np.random.default_rng(0)
    perm = rng.permutation(m.num_nodes)  # new node i is old node perm[i]
    inv = np.argsort(perm)
    cells = inv[m.cells][rng.permutation(m.num_faces)]
    cells = np.roll(cells, 1, axis=1)  # rotate each triangle's corners (orientation kept)
    p = ClothMesh(cells.astype(np.int32), m.mesh_pos[perm], m.node_type[perm], m.rest_pos[perm])
    params = dataclasses.replace(STILL, air_density=1.0, air_drag=0.05, wind_velocity=(0.0, 4.0, 0.0), cg_tol=1e-11)
    a = ClothSolver(m, params, 0.02).simulate(m.rest_pos, swing_velocity(m, 1.0), 30)
    b = ClothSolver(p, params, 0.02).simulate(p.rest_pos, swing_velocity(m, 1.0)[perm], 30)
    assert np.abs(a[-1] - a[0]).max() > 0.1
    np.testing.assert_allclose(b, a[:, perm], atol=2e-6)
