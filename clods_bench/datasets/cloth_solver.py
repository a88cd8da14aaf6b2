"""The ground-truth cloth solver: implicit (backward) Euler on membrane, bending, gravity and wind.

Each step solves implicit Euler, M (v+ - v) = h f(x + h v+, v+), for the new velocity v+ of
the free nodes by Newton iterations v_k -> v_k + dv (Baraff & Witkin 1998 linear systems):
    [(1 + h a) M + (h b + h^2) K + h B] dv = -r,
    r = M (v_k - v) - h [f(x + h v_k) + f_w - B (v_k - v) - a M v_k - b K v_k],
with K the PSD-projected elastic Hessian at x + h v_k, B the PSD wind velocity Jacobian
(wind linearised once per step at v), a and b the Rayleigh damping coefficients, solved by
block-Jacobi PCG. Newton starts at the inertial prediction v_0 = v rather than at x (v_0 = 0,
Baraff-Witkin): same cost per iteration and exact for linear forces, but a rotating cloth
gains no spurious stretch from the linearisation (with 1 iteration, max strain of a 50x stiff
flag in gusty wind 0.6% instead of 3.6%). Kinematic (non-NORMAL) nodes are filtered out.

Contact with rigid obstacles (`clods_bench.datasets.obstacles`) is implicit penalty contact. Each Newton
iteration queries the free nodes at their predicted positions at t + h: x + h v_k, and in the first
iteration (v_0 = v) also pushed on by the external forces, + h^2 f_ext / m shortened to at most T, so that a
cloth resting in the contact layer is seen in contact rather than leaving the layer for a free-fall step
(shortened: wind on light cloth reaches 100 g, and a query far from the node finds the wrong side). A node closer than
the cloth's half-thickness T to an obstacle (signed distance d < T, normal n, surface velocity u) gets
the force k m (T - d) n, linearised about the query point (exact for a plane), and the stiffness
h^2 k m n n^T joins its diagonal block of the implicit matrix. Friction is a regularised Coulomb drag
-c (I - n n^T)(v+ - u) with c = mu N / max(s, eps), added to the residual and (times h) to the same block:
N is the normal force that stops the node's approach within the step against the other forces, and s
the slip speed Coulomb's law predicts at the step's end (slip pushed by the other tangential forces,
less mu N h / m), so a sliding node loses exactly mu N h / m of speed per step and one below eps sticks.

Why this method: the contact terms live on the 3x3 diagonal blocks only, so the system keeps its sparsity
and block-Jacobi preconditioner (what contact adds to the diagonal helps rather than hurts CG), and being implicit the step
stays stable for any stiffness (k h^2 = 40 at the default 1e5/s^2 and dt 0.02: the layer acts as a stiff,
overdamped spring; the equilibrium depth under gravity is g / k = 0.1 mm). Explicit penalties would need
dt < 2/sqrt(k); constraint projection or an LCP solve would need a different solver. Nodes do not bounce:
after the step, nodes in the layer lose the normal velocity with which they approach the obstacle (an
inelastic layer: it also holds at the next step's start), and any node still deeper than T inside an
obstacle is put back on its surface where its path in the step entered it, found by sphere tracing, so a
fast node past the middle of a thin obstacle does not leave by the far side (a safety net, counted in
`stats["contact_projections"]`; `stats["contacts"]` counts active node-steps). There is no continuous
collision detection: a node that crosses a whole obstacle within one step is not caught (use substeps),
and loads above k m (2 T) per node (k = 1e5: 2000 m/s^2) push the cloth through the layer into the safety
net. Without obstacles none of this runs: the step is bit-identical to the solver without contact.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from clods_bench.datasets import block_cg, cloth_energy, wind
from clods_bench.datasets.obstacles import Obstacle
from clods_bench.datasets.types import NORMAL, ClothMesh
from clods_bench.errors import ClodsError

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class SolverParams:
    """Physical and numerical parameters of the cloth solver (SI units)."""

    density: float = 0.1
    """Areal mass density (kg/m^2), lumped per node as a third of its triangles' rest areas."""
    youngs_modulus: float = 5000.0
    """2D membrane Young modulus (N/m): resistance to stretch; with poisson_ratio sets mu, lambda."""
    poisson_ratio: float = 0.3
    """Membrane Poisson ratio (plane stress), in [0, 0.5); shear modulus mu = Y / (2 (1 + nu))."""
    bending_stiffness: float = 2e-4
    """Bending stiffness k (N m) of the quadratic bending model (energy (k/2) x^T Q x)."""
    damping_mass: float = 0.0
    """Mass-proportional Rayleigh damping a (1/s): force -a M v. 0 means none."""
    damping_stiffness: float = 0.0
    """Stiffness-proportional Rayleigh damping b (s): force -b K v. 0 means none."""
    gravity: Vec3 = (0.0, 0.0, -9.81)
    """Gravitational acceleration (m/s^2)."""
    wind_velocity: Vec3 = (0.0, 0.0, 0.0)
    """Mean wind velocity (m/s)."""
    turbulence_amplitude: float = 0.0
    """RMS per component of the turbulent wind fluctuation (m/s); 0 for steady wind."""
    turbulence_time_scale: float = 1.0
    """Typical period of the turbulent fluctuation (s)."""
    wind_ramp_time: float = 0.0
    """Seconds over which wind (mean and turbulence) ramps up smoothly from 0; 0 for none."""
    air_density: float = 1.0
    """Coefficient of the normal (pressure) wind term, rho |v.n| v_n per area (kg/m^3)."""
    air_drag: float = 0.0
    """Coefficient of the tangential (skin drag) wind term, c v_t per area (kg/(m^2 s))."""
    newton_iterations: int = 1
    """Newton iterations per step; 1 is the linearly implicit Baraff-Witkin step."""
    cg_tol: float = 1e-6
    """Relative residual at which conjugate gradients stops."""
    cg_max_iter: int = 2000
    """Iteration cap of conjugate gradients per Newton iteration."""
    contact_thickness: float = 0.01
    """Collision half-thickness of the cloth (m): nodes closer than this to an obstacle are in contact."""
    contact_stiffness: float = 1e5
    """Penalty stiffness per unit node mass (1/s^2): contact force k m (thickness - distance) along the normal."""
    friction: float = 0.3
    """Coulomb friction coefficient between cloth and obstacles; 0 for frictionless contact."""
    friction_stick_speed: float = 1e-3
    """Regularisation of Coulomb friction (m/s): below this sliding speed friction is a viscous drag."""

    def validate(self, where: str = "solver params") -> None:
        """Raise ClodsError naming the field that is out of range."""
        checks = [
            ("density", self.density > 0),
            ("youngs_modulus", self.youngs_modulus >= 0),
            ("poisson_ratio", 0 <= self.poisson_ratio < 0.5),
            ("bending_stiffness", self.bending_stiffness >= 0),
            ("damping_mass", self.damping_mass >= 0),
            ("damping_stiffness", self.damping_stiffness >= 0),
            ("turbulence_amplitude", self.turbulence_amplitude >= 0),
            ("turbulence_time_scale", self.turbulence_time_scale > 0),
            ("wind_ramp_time", self.wind_ramp_time >= 0),
            ("air_density", self.air_density >= 0),
            ("air_drag", self.air_drag >= 0),
            ("newton_iterations", self.newton_iterations >= 1),
            ("cg_tol", 0 < self.cg_tol < 1),
            ("cg_max_iter", self.cg_max_iter >= 1),
            ("contact_thickness", self.contact_thickness > 0),
            ("contact_stiffness", self.contact_stiffness > 0),
            ("friction", self.friction >= 0),
            ("friction_stick_speed", self.friction_stick_speed > 0),
        ]
        for name, ok in checks:
            if not (ok and (name not in _CONTACT_FIELDS or np.isfinite(getattr(self, name)))):
                raise ClodsError(f"value {getattr(self, name)!r} is out of range", where=f"{where}.{name}")
        for name in ("gravity", "wind_velocity"):
            vec = np.asarray(getattr(self, name), dtype=np.float64)
            if vec.shape != (3,) or not np.isfinite(vec).all():
                raise ClodsError(f"must be 3 finite numbers, got {getattr(self, name)!r}", where=f"{where}.{name}")

    def identity(self) -> dict[str, Any]:
        """The fields that decide the data: `dataclasses.asdict`, less the contact fields left at their defaults.

        Contact parameters only matter with obstacles; leaving them out at their defaults keeps the fingerprints of
        datasets made before contact existed."""
        out = dataclasses.asdict(self)
        for name in _CONTACT_FIELDS:
            if out[name] == _CONTACT_DEFAULTS[name]:
                del out[name]
        return out

    def scaled(self, membrane: float = 1.0, bending: float = 1.0) -> "SolverParams":
        """A copy with membrane and bending stiffness multiplied (for stiff-cloth scenes)."""
        return dataclasses.replace(
            self, youngs_modulus=self.youngs_modulus * membrane, bending_stiffness=self.bending_stiffness * bending
        )


def _entry_points(obstacle: Obstacle, start: np.ndarray, end: np.ndarray, t: float, iterations: int = 32) -> np.ndarray:
    """Where the segments start -> end first reach the obstacle's surface, by sphere tracing: step along each segment
    by the signed distance, which never overshoots the surface (a distance bound); a start inside stays put."""
    delta = end - start
    inv_length = 1.0 / np.maximum(np.linalg.norm(delta, axis=1), 1e-300)
    s = np.zeros(start.shape[0])
    for _ in range(iterations):
        d, _, _ = obstacle.query(start + s[:, None] * delta, t)
        step = np.maximum(d, 0.0) * inv_length
        s = np.minimum(s + step, 1.0)
        if step.max() < 1e-9:
            break
    return start + s[:, None] * delta


_CONTACT_FIELDS = ("contact_thickness", "contact_stiffness", "friction", "friction_stick_speed")
_CONTACT_DEFAULTS = {f.name: f.default for f in dataclasses.fields(SolverParams) if f.name in _CONTACT_FIELDS}


class ClothSolver:
    """Implicit cloth solver on one mesh; kinematic nodes follow `handle_fn(t)` or stay put."""

    def __init__(
        self,
        mesh: ClothMesh,
        params: SolverParams,
        dt: float,
        seed: int = 0,
        handle_fn: Callable[[float], np.ndarray] | None = None,
        obstacles: Sequence[Obstacle] = (),
    ) -> None:
        mesh.validate("solver mesh")
        params.validate()
        if not (np.isfinite(dt) and dt > 0):
            raise ClodsError(f"dt must be a positive number, got {dt}", where="ClothSolver.dt")
        self.mesh, self.params, self.dt = mesh, params, float(dt)
        self.handle_fn = handle_fn
        for i, obstacle in enumerate(obstacles):
            if not isinstance(obstacle, Obstacle):
                raise ClodsError(f"is a {type(obstacle).__name__}, expected an Obstacle", where=f"ClothSolver.obstacles[{i}]")
            obstacle.validate(f"ClothSolver.obstacles[{i}]")
        self.obstacles: Sequence[Obstacle] = list(obstacles)
        """The obstacles of the next steps; a caller may reassign them (e.g. per rollout)."""
        self.geo = cloth_energy.rest_geometry(mesh)
        v = mesh.num_nodes
        self.mass = np.zeros(v)
        np.add.at(self.mass, self.geo.cells.ravel(), np.repeat(params.density * self.geo.area / 3.0, 3))
        self.free = np.asarray(mesh.node_type) == NORMAL
        self.handles = np.flatnonzero(~self.free)
        self.pattern = block_cg.build_pattern(v, self.geo.cells, self.geo.hinges)
        self.q = block_cg.hinge_scalars(self.pattern, self.geo.hinge_k, self.geo.hinge_w)
        self.mu, self.lam = cloth_energy.lame_from_young(params.youngs_modulus, params.poisson_ratio)
        self.gravity = np.asarray(params.gravity, dtype=np.float64)
        self.wind = wind.make_wind_field(
            params.wind_velocity, params.turbulence_amplitude, params.turbulence_time_scale, np.random.default_rng(seed)
        )
        # air acts on moving cloth even in still air, so aerodynamics is on whenever a coefficient is
        self.has_wind = bool(params.air_density > 0 or params.air_drag > 0)
        self.free_nodes = np.flatnonzero(self.free)
        self.stats: dict[str, float] = {"cg_iterations": 0, "cg_residual_max": 0.0, "steps": 0, "contacts": 0, "contact_projections": 0}

    def handle_positions(self, t: float, x: np.ndarray) -> np.ndarray:
        """Positions (H,3) of the kinematic nodes at time t (unchanged when no handle_fn)."""
        if self.handle_fn is None:
            return x[self.handles]
        pos = np.asarray(self.handle_fn(t), dtype=np.float64)
        if pos.shape != (self.handles.size, 3):
            raise ClodsError(f"handle_fn returned shape {pos.shape}, expected ({self.handles.size}, 3)", where="ClothSolver.handle_fn")
        return pos

    def _forces(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Elastic (membrane + bending) forces (V,3) and the PSD stiffness K = -df/dx as blocks."""
        forces = np.zeros_like(x)
        blocks = np.zeros((self.pattern.nnzb, 3, 3))
        cloth_energy.membrane_kernel(
            x, self.geo.cells, self.geo.dm_inv, self.geo.area, self.mu, self.lam, forces, blocks, self.pattern.tri_map, 1.0, True, True
        )
        kb = self.params.bending_stiffness
        if kb > 0:
            qx = np.empty_like(x)
            block_cg.scalar_matvec(self.pattern.indptr, self.pattern.indices, self.q, x, qx)
            forces -= kb * qx
            blocks += (kb * self.q)[:, None, None] * np.eye(3)[None]
        return forces, blocks

    def step(self, x: np.ndarray, v: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Advance positions and velocities (V,3) by one step of dt from time t."""
        return self._step(np.asarray(x, np.float64), np.asarray(v, np.float64), float(t), self.dt)

    def _step(self, x: np.ndarray, v: np.ndarray, t: float, h: float) -> tuple[np.ndarray, np.ndarray]:
        p, pat = self.params, self.pattern
        m3 = self.mass[:, None]
        vk = np.where(self.free[:, None], v, 0.0)  # Newton starts at the inertial prediction x + h v
        if self.handles.size:
            vk[self.handles] = (self.handle_positions(t + h, x) - x[self.handles]) / h
        f_ext = m3 * self.gravity[None, :]
        wind_blocks = np.zeros((pat.nnzb, 3, 3))
        if self.has_wind:
            w = self.wind
            ramp = wind.ramp_factor(t, p.wind_ramp_time)
            wind.wind_kernel(
                x, v, self.geo.cells, t, ramp * w.mean, ramp * w.amps, w.omegas, w.wavevecs, w.phases,
                p.air_density, p.air_drag, f_ext, wind_blocks, pat.tri_map, 1.0,
            )  # fmt: skip
        bv = np.empty_like(v)
        block_cg.block_matvec(pat.indptr, pat.indices, wind_blocks, v, bv)
        for it in range(p.newton_iterations):
            xk = x + h * vk
            f_el, kblocks = self._forces(xk)
            kv = np.empty_like(v)
            block_cg.block_matvec(pat.indptr, pat.indices, kblocks, vk, kv)
            bvk = np.empty_like(v)
            block_cg.block_matvec(pat.indptr, pat.indices, wind_blocks, vk, bvk)
            rhs = -m3 * (vk - v) + h * (f_el + f_ext - bvk + bv - p.damping_mass * m3 * vk - p.damping_stiffness * kv)
            a = (h * p.damping_stiffness + h * h) * kblocks + h * wind_blocks
            a[pat.diag] += ((1.0 + h * p.damping_mass) * self.mass)[:, None, None] * np.eye(3)[None]
            if self.obstacles:
                # first iteration: the inertial prediction pushed on by the external forces, so a cloth resting in the
                # contact layer stays in contact instead of leaving it for a free-fall step; then the iterate itself
                xq = xk + self._contact_push(f_ext, h) if it == 0 else xk
                self._add_contact(xq, xk, vk, f_el + f_ext, t + h, h, rhs, a, count=it == p.newton_iterations - 1)
            delta = np.zeros_like(v)
            iters, res = block_cg.block_pcg(pat.indptr, pat.indices, pat.diag, a, rhs, delta, self.free, p.cg_tol, p.cg_max_iter)
            vk = vk + delta
            self.stats["cg_iterations"] += iters
            self.stats["cg_residual_max"] = max(float(self.stats["cg_residual_max"]), float(res))
        self.stats["steps"] += 1
        if self.obstacles:
            return self._resolve_contact(x, x + h * vk, vk, t + h)
        return x + h * vk, vk

    def _contact_push(self, f_ext: np.ndarray, h: float) -> np.ndarray:
        """The external forces' displacement h^2 f_ext / m over a step, each node's shortened to at most the thickness
        (wind on light cloth can reach 100 g: the query point must stay near the node)."""
        push = (h * h / self.mass[:, None]) * f_ext
        length = np.linalg.norm(push, axis=1)
        return push * np.minimum(1.0, self.params.contact_thickness / np.maximum(length, 1e-300))[:, None]

    def _contacts(self, x: np.ndarray, t: float, within: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Per obstacle, the free nodes closer than `within` to it at time t: (nodes, distance, normal, surface velocity)."""
        out = []
        nodes = self.free_nodes
        pts = x[nodes]
        for obstacle in self.obstacles:
            d, n, u = obstacle.query(pts, t)
            hit = np.flatnonzero(d < within)
            if hit.size:
                out.append((nodes[hit], d[hit], n[hit], u[hit]))
        return out

    def _add_contact(
        self, xq: np.ndarray, xk: np.ndarray, vk: np.ndarray, force: np.ndarray, t: float, h: float, rhs: np.ndarray, a: np.ndarray, count: bool
    ) -> None:
        """Add penalty and friction forces (times h) at the iterate (xk, vk) to `rhs` and their implicit terms to the
        diagonal blocks of `a`; the contacts are found and linearised at the query positions xq, `force` is the
        other forces on the nodes (for friction's normal force)."""
        p = self.params
        for nodes, d, n, u in self._contacts(xq, t, p.contact_thickness):
            km = p.contact_stiffness * self.mass[nodes]
            # the penalty linearised at xq: k m (T - d(xq) - n.(x - xq)) n, exact for a plane
            depth = p.contact_thickness - d - np.einsum("ni,ni->n", xk[nodes] - xq[nodes], n)
            nn = n[:, :, None] * n[:, None, :]
            m = self.mass[nodes]
            rel = vk[nodes] - u
            vn = np.einsum("ni,ni->n", rel, n)
            slip = rel - vn[:, None] * n
            fn_other = np.einsum("ni,ni->n", force[nodes], n)
            # friction's normal force: what stops the node's approach within the step against the other forces
            normal_force = np.maximum(-m * vn / h - fn_other, 0.0)
            # slip speed at the step's end by Coulomb's law: the other forces' tangential push, less mu N h / m
            pushed = slip + (h / m)[:, None] * (force[nodes] - fn_other[:, None] * n)
            end_slip = np.linalg.norm(pushed, axis=1) - h * p.friction * normal_force / m
            c = p.friction * normal_force / np.maximum(end_slip, p.friction_stick_speed)
            np.add.at(rhs, nodes, h * ((km * depth)[:, None] * n - c[:, None] * slip))
            np.add.at(a, self.pattern.diag[nodes], (h * h) * km[:, None, None] * nn + h * c[:, None, None] * (np.eye(3)[None] - nn))
            if count:  # active node-steps: counted once per step
                self.stats["contacts"] += nodes.size

    def _resolve_contact(self, x0: np.ndarray, x: np.ndarray, v: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """After a step from x0 to x: nodes deeper than the thickness inside an obstacle go back to where their path
        from x0 entered it (x0 itself if it was inside by less than the thickness; along the normal to the surface if
        deeper); then nodes in the contact layer lose their approaching normal velocity."""
        p = self.params
        for obstacle in self.obstacles:
            nodes = self.free_nodes
            d, n, u = obstacle.query(x[nodes], t)
            hit = d < p.contact_thickness
            nodes, d, n, u = nodes[hit], d[hit], n[hit], u[hit]
            deep = np.flatnonzero(d < -p.contact_thickness)
            if deep.size:
                x[nodes[deep]] -= d[deep, None] * n[deep]
                start = x0[nodes[deep]]
                came_in = obstacle.query(start, t)[0] >= -p.contact_thickness
                if came_in.any():  # a fast node may have crossed the middle of a thin obstacle: back on its entry side
                    sel = deep[came_in]
                    x[nodes[sel]] = _entry_points(obstacle, start[came_in], x[nodes[sel]] + d[sel, None] * n[sel], t)
                    _, n[sel], u[sel] = obstacle.query(x[nodes[sel]], t)
                self.stats["contact_projections"] += int(deep.size)
            vn = np.einsum("ni,ni->n", v[nodes] - u, n)
            approach = vn < 0
            v[nodes[approach]] -= vn[approach, None] * n[approach]
        return x, v

    def energy(self, x: np.ndarray, v: np.ndarray) -> dict[str, float]:
        """Kinetic, membrane, bending and gravity potential energy (J) and their total."""
        x = np.asarray(x, np.float64)
        v = np.asarray(v, np.float64)
        membrane, _ = cloth_energy.membrane_energy_forces(x, self.geo, self.mu, self.lam)
        qx = np.empty_like(x)
        block_cg.scalar_matvec(self.pattern.indptr, self.pattern.indices, self.q, x, qx)
        out = {
            "kinetic": 0.5 * float(np.sum(self.mass[:, None] * v * v)),
            "membrane": float(membrane),
            "bending": 0.5 * self.params.bending_stiffness * float(np.sum(x * qx)),
            "gravity": -float(np.sum(self.mass[:, None] * x * self.gravity[None, :])),
        }
        out["total"] = sum(out.values())
        return out

    def simulate(
        self,
        x0: np.ndarray,
        v0: np.ndarray,
        num_steps: int,
        substeps: int = 1,
        t0: float = 0.0,
        progress: Callable[[int, int], None] | None = None,
    ) -> np.ndarray:
        """Frames (num_steps, V, 3) float32, frame 0 = x0, frames dt apart, each in `substeps` sub-steps.

        `progress(frame, num_steps)` is called after each frame when given.
        """
        if int(substeps) < 1 or int(num_steps) < 1:
            raise ClodsError(f"num_steps and substeps must be >= 1, got {num_steps}, {substeps}", where="ClothSolver.simulate")
        x = np.array(x0, dtype=np.float64)
        v = np.array(v0, dtype=np.float64)
        h = self.dt / substeps
        out = np.empty((num_steps, x.shape[0], 3), dtype=np.float32)
        out[0] = x
        for frame in range(1, num_steps):
            for s in range(substeps):
                x, v = self._step(x, v, t0 + (frame - 1) * self.dt + s * h, h)
            out[frame] = x
            if progress is not None:
                progress(frame, num_steps)
        return out
