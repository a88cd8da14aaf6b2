"""Cloth-obstacle contact of the cloth solver against analytic equilibria, Coulomb's law and the contact-free solver."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from clods_bench.datasets.cloth_solver import ClothSolver, SolverParams
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.obstacles import Box, ObstaclePath, Sphere, TriangleMeshObstacle
from clods_bench.datasets.types import ClothMesh
from clods_bench.errors import ClodsError

STILL = SolverParams(air_density=0.0, air_drag=0.0)
G = 9.81
T = STILL.contact_thickness
K = STILL.contact_stiffness
DT = 0.02
TABLE = Box((0.0, 0.0, -0.5), (2.0, 2.0, 0.5))  # top face at z = 0
REST_Z = T - G / K  # penalty equilibrium on the table: k m (T - d) = m g


def sheet(nx: int, ny: int, lx: float, ly: float, z: float) -> ClothMesh:
    """A free horizontal lx x ly sheet of nx x ny nodes centred over the origin at height z."""
    m = make_flag_mesh(nx, ny, lx, ly)
    r = m.rest_pos
    rest = np.stack([r[:, 0] - lx / 2, r[:, 2] - ly / 2, np.full(r.shape[0], z)], axis=1)
    return dataclasses.replace(m, rest_pos=rest, node_type=np.zeros_like(m.node_type))


def run(solver: ClothSolver, x: np.ndarray, v: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions of every step (steps+1, V, 3) and the final state."""
    xs = [x]
    for i in range(steps):
        x, v = solver.step(x, v, i * solver.dt)
        xs.append(x)
    return np.array(xs), x, v


@pytest.mark.parametrize("newton", [1, 3])
@pytest.mark.parametrize("kind", ["sphere", "mesh"])
def test_sheet_dropped_on_sphere_drapes_without_penetration(kind, newton):
    """A 1.2 x 0.6 m sheet falls from z 0.45 onto a 0.25 m ball: it drapes (its ends hang below the equator) and no
    node ends inside the ball by more than half the thickness; without the ball it falls through."""
    m = sheet(13, 7, 1.2, 0.6, 0.45)
    ball = Sphere((0.0, 0.0, 0.0), 0.25) if kind == "sphere" else TriangleMeshObstacle(*Sphere((0.0, 0.0, 0.0), 0.25, subdivisions=3).surface(0.0))
    params = dataclasses.replace(STILL, newton_iterations=newton)
    solver = ClothSolver(m, params, DT, obstacles=[ball])
    zero = np.zeros_like(m.rest_pos)
    xs, x, v = run(solver, m.rest_pos, zero, 120)
    d = np.array([ball.query(f, 0.0)[0] for f in xs])
    assert np.isfinite(xs).all()
    assert d[-1].min() > -0.5 * T
    assert d.min() > -T - 1e-12  # the safety projection holds every step
    assert solver.stats["contacts"] > 100 and solver.stats["contact_projections"] <= 5
    assert x[:, 2].min() < -0.1 and x[:, 2].max() > 0.2  # draped over the top
    through, _, _ = run(ClothSolver(m, params, DT), m.rest_pos, zero, 20)
    assert min(ball.query(f, 0.0)[0].min() for f in through) < -0.2  # the same fall without contact goes through the ball


def test_sheet_at_rest_on_table_stays_at_rest():
    """At the penalty equilibrium (depth g/k below the thickness) the sheet stays exactly there; started at the
    layer's edge it sinks to that equilibrium."""
    m = sheet(8, 8, 0.4, 0.4, REST_Z)
    solver = ClothSolver(m, STILL, DT, obstacles=[TABLE])
    zero = np.zeros_like(m.rest_pos)
    xs, x, v = run(solver, m.rest_pos, zero, 200)
    assert np.abs(xs - m.rest_pos).max() < 1e-9 and np.abs(v).max() < 1e-9
    assert solver.stats["contacts"] == 200 * m.num_nodes
    m2 = sheet(8, 8, 0.4, 0.4, T)
    _, x, v = run(ClothSolver(m2, STILL, DT, obstacles=[TABLE]), m2.rest_pos, zero, 50)
    np.testing.assert_allclose(x[:, 2], REST_Z, atol=1e-8)
    assert np.abs(v).max() < 1e-6


def test_falling_sheet_lands_at_analytic_depth_without_bounce():
    """A small flat sheet (every node alike: a falling point mass) follows backward Euler's free fall until it reaches
    the layer, never rises above the layer after landing, and rests at depth T - g/k."""
    z0 = 0.3
    m = sheet(3, 3, 0.1, 0.1, z0)
    solver = ClothSolver(m, dataclasses.replace(STILL, cg_tol=1e-12), DT, obstacles=[TABLE])
    x, v, zs, vz = m.rest_pos, np.zeros_like(m.rest_pos), [z0], []
    for i in range(60):
        x, v = solver.step(x, v, i * DT)
        zs.append(x[0, 2])
        vz.append(v[:, 2].min())
    z, vz = np.array(zs), np.array(vz)
    assert np.ptp(x[:, 2]) < 1e-9  # the sheet stays flat: a point mass
    t = DT * np.arange(8)
    np.testing.assert_allclose(z[:8], z0 - 0.5 * G * t**2 - 0.5 * G * t * DT, atol=1e-9)  # untouched before landing
    landed = int(np.argmax(z < T))
    assert 5 < landed < 20 and vz[landed - 2] < -1.0  # it arrives fast
    assert vz[landed - 1 :].min() >= 0.0  # inelastic: in the layer no node moves towards the table
    assert z[landed:].max() <= T  # no bounce out of the layer
    assert z.min() > -0.5 * T
    np.testing.assert_allclose(x[:, 2], REST_Z, atol=1e-9)
    assert np.abs(v).max() < 1e-9


@pytest.mark.parametrize("mu", [0.3, 0.6])
def test_friction_stops_a_sliding_sheet_as_coulomb_says(mu):
    """Sliding at v0 on the table, friction decelerates by mu g: the speed drops by mu g dt per step and the sheet
    stops after v0 / (mu g) s, having slid about v0^2 / (2 mu g); without friction it keeps v0."""
    v0 = 1.0
    m = sheet(6, 6, 0.3, 0.3, REST_Z)
    vel = np.tile([v0, 0.0, 0.0], (m.num_nodes, 1))
    solver = ClothSolver(m, dataclasses.replace(STILL, friction=mu), DT, obstacles=[TABLE])
    speeds, x, v = [v0], m.rest_pos, vel
    for i in range(40):
        x, v = solver.step(x, v, i * DT)
        speeds.append(float(np.linalg.norm(v, axis=1).max()))
    speeds = np.array(speeds)
    stop = v0 / (mu * G)
    sliding = np.arange(41) * DT < stop - DT
    np.testing.assert_allclose(speeds[sliding], v0 - mu * G * DT * np.arange(41)[sliding], atol=1e-6)
    assert speeds[int(np.ceil(stop / DT)) + 1 :].max() < 1e-3
    slid = x[:, 0].mean() - m.rest_pos[:, 0].mean()
    assert slid == pytest.approx(v0**2 / (2 * mu * G), abs=v0 * DT)  # backward Euler: within a step's travel
    np.testing.assert_allclose(x[:, 2], REST_Z, atol=1e-9)
    free = ClothSolver(m, dataclasses.replace(STILL, friction=0.0), DT, obstacles=[TABLE])
    _, x, v = run(free, m.rest_pos, vel, 40)
    np.testing.assert_allclose(v, vel, atol=1e-12)
    np.testing.assert_allclose(x[:, 0] - m.rest_pos[:, 0], v0 * 40 * DT, atol=1e-9)


def test_moving_table_lifts_and_carries_the_sheet():
    """A table rising 0.2 m lifts the sheet with it (same equilibrium depth); one sliding 0.1 m sideways carries it
    along by friction (its peak acceleration 0.6 m/s^2 is below mu g) and slides under it without friction."""
    m = sheet(6, 6, 0.3, 0.3, REST_Z)
    zero = np.zeros_like(m.rest_pos)
    up = dataclasses.replace(TABLE, path=ObstaclePath((0.0, 1.0), ((0.0, 0.0, 0.0), (0.0, 0.0, 0.2))))
    xs, x, _ = run(ClothSolver(m, STILL, DT, obstacles=[up]), m.rest_pos, zero, 75)
    np.testing.assert_allclose(x[:, 2], 0.2 + REST_Z, atol=1e-6)
    heights = np.array([up.query(f, i * DT)[0] for i, f in enumerate(xs)])
    assert heights.min() > 0.5 * T  # pushed up, never through
    side = dataclasses.replace(TABLE, path=ObstaclePath((0.0, 1.0), ((0.0, 0.0, 0.0), (0.1, 0.0, 0.0))))
    _, x, v = run(ClothSolver(m, dataclasses.replace(STILL, friction=0.5), DT, obstacles=[side]), m.rest_pos, zero, 75)
    np.testing.assert_allclose(x[:, 0] - m.rest_pos[:, 0], 0.1, atol=1e-3)
    assert np.abs(v).max() < 1e-3
    _, x, _ = run(ClothSolver(m, dataclasses.replace(STILL, friction=0.0), DT, obstacles=[side]), m.rest_pos, zero, 75)
    np.testing.assert_allclose(x[:, 0], m.rest_pos[:, 0], atol=1e-9)


def test_wind_pressed_curtain_stays_in_front_of_a_thin_wall():
    """8 m/s wind on the light curtain (about 65 g) slams it into a 10 cm wall 3 cm behind it: the first step alone
    carries it past the wall's middle, where the closest face is the back one. It must end up resting on the front
    face (pressed into the layer by the wind, w / k = 6.4 mm), never behind the middle."""
    m = make_flag_mesh(8, 8, 1.0, 1.0)
    r = m.rest_pos
    m = dataclasses.replace(m, rest_pos=np.stack([r[:, 2], 0.0 * r[:, 0], -r[:, 0]], axis=1))  # pinned along its top
    wall = Box((0.5, 0.08, -0.5), (1.0, 0.05, 1.0))  # faces at y = 0.03 and 0.13
    solver = ClothSolver(m, SolverParams(wind_velocity=(0.0, 8.0, 0.0)), DT, obstacles=[wall])
    xs, x, v = run(solver, m.rest_pos, np.zeros_like(m.rest_pos), 60)
    assert xs[:, :, 1].max() < 0.03 + 1e-9  # in front of the wall's front face, every step
    assert solver.stats["contact_projections"] > 0  # the safety net was needed
    assert np.abs(v).max() < 1e-2
    free = m.node_type == 0
    assert np.all(x[free, 1] > 0.03 - 0.02)  # resting on the wall, not hanging short of it


def test_without_obstacles_the_solver_is_unchanged():
    """Bit-identical flags: no obstacles, obstacles=() and a ball far away (never touched); a ball in the way
    changes the motion, and assigning it to `solver.obstacles` later gives the same as passing it at the start."""
    m = make_flag_mesh(9, 5)
    params = SolverParams(wind_velocity=(6.0, 1.0, 0.0), turbulence_amplitude=1.0)
    x0, v0 = m.rest_pos, np.zeros_like(m.rest_pos)
    base = ClothSolver(m, params, DT, seed=2).simulate(x0, v0, 60)
    empty = ClothSolver(m, params, DT, seed=2, obstacles=())
    np.testing.assert_array_equal(empty.simulate(x0, v0, 60), base)
    far = ClothSolver(m, params, DT, seed=2, obstacles=[Sphere((0.0, 50.0, 0.0), 1.0)])
    np.testing.assert_array_equal(far.simulate(x0, v0, 60), base)
    assert far.stats["contacts"] == 0 and empty.stats["contacts"] == 0
    ball = Sphere((1.5, 0.3, 0.5), 0.25)
    hit = ClothSolver(m, params, DT, seed=2, obstacles=[ball]).simulate(x0, v0, 60)
    assert np.abs(hit - base).max() > 0.05
    empty.obstacles = [ball]
    np.testing.assert_array_equal(empty.simulate(x0, v0, 60), hit)


def test_contact_params_leave_the_identity_at_their_defaults():
    before_contact = {
        "density", "youngs_modulus", "poisson_ratio", "bending_stiffness", "damping_mass", "damping_stiffness", "gravity",
        "wind_velocity", "turbulence_amplitude", "turbulence_time_scale", "wind_ramp_time", "air_density", "air_drag",
        "newton_iterations", "cg_tol", "cg_max_iter",
    }  # fmt: skip
    params = SolverParams(wind_velocity=(3.0, 0.0, 0.0))
    assert set(params.identity()) == before_contact
    assert params.identity() == {k: v for k, v in dataclasses.asdict(params).items() if k in before_contact}
    changed = dataclasses.replace(params, friction=0.5, contact_thickness=0.02).identity()
    assert changed["friction"] == 0.5 and changed["contact_thickness"] == 0.02
    assert set(changed) == before_contact | {"friction", "contact_thickness"}


@pytest.mark.parametrize(
    "field, value",
    [("contact_thickness", 0.0), ("contact_stiffness", -1.0), ("friction", -0.1), ("friction_stick_speed", 0.0), ("friction", float("inf"))],
)
def test_bad_contact_params_are_named(field, value):
    with pytest.raises(ClodsError, match=field):
        dataclasses.replace(STILL, **{field: value}).validate()


def test_bad_obstacles_are_named():
    m = sheet(3, 3, 0.1, 0.1, 0.0)
    with pytest.raises(ClodsError) as err:
        ClothSolver(m, STILL, DT, obstacles=[TABLE, Sphere((0.0, 0.0, 0.0), -1.0)])
    assert err.value.where == "ClothSolver.obstacles[1].radius"
    with pytest.raises(ClodsError, match="expected an Obstacle"):
        ClothSolver(m, STILL, DT, obstacles=["ball"])  # type: ignore[list-item]


def test_stiff_contact_stays_stable():
    """Penalty 100x stiffer (1e7 / s^2, k dt^2 = 4000): the drop stays finite and out of the ball; on the table the
    sheet rests at the 100x smaller depth g/k."""
    stiff = dataclasses.replace(STILL, contact_stiffness=1e7)
    m = sheet(9, 5, 1.0, 0.5, 0.4)
    ball = Sphere((0.0, 0.0, 0.0), 0.25)
    xs, x, v = run(ClothSolver(m, stiff, DT, obstacles=[ball]), m.rest_pos, np.zeros_like(m.rest_pos), 100)
    assert np.isfinite(xs).all() and np.abs(v).max() < 20.0
    assert min(ball.query(f, 0.0)[0].min() for f in xs) > -0.5 * T
    flat = sheet(5, 5, 0.2, 0.2, T)
    _, x, _ = run(ClothSolver(flat, stiff, DT, obstacles=[TABLE]), flat.rest_pos, np.zeros_like(flat.rest_pos), 30)
    np.testing.assert_allclose(x[:, 2], T - G / 1e7, atol=1e-9)
