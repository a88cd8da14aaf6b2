"""Data generation gives the same bits whichever BLAS kernel the CPU gets (fixed_order, block_cg.inverse3)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from clods_bench.datasets.block_cg import inverse3
from clods_bench.datasets.fixed_order import apply3, dot3


def test_dot3_and_apply3_equal_numpy_products():
    rng = np.random.default_rng(0)
    a, v, m = rng.standard_normal((50, 3)), rng.standard_normal(3), rng.standard_normal((3, 3))
    np.testing.assert_allclose(dot3(a, v), a @ v, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(apply3(m, a), a @ m.T, rtol=1e-14, atol=1e-15)
    b = rng.standard_normal((50, 3))
    np.testing.assert_allclose(dot3(a, b), np.einsum("ni,ni->n", a, b), rtol=1e-14, atol=1e-15)
    # small integers: every product and sum is exact, so the fixed order must give numpy's value exactly
    ai, mi = rng.integers(-9, 9, (20, 3)).astype(float), rng.integers(-9, 9, (3, 3)).astype(float)
    np.testing.assert_array_equal(apply3(mi, ai), ai @ mi.T)


def test_inverse3_inverts_and_refuses_a_singular_block():
    rng = np.random.default_rng(1)
    out = np.empty((3, 3))
    for _ in range(20):
        q = rng.standard_normal((3, 3))
        a = q @ q.T + 0.1 * np.eye(3)  # SPD, like a preconditioner block
        inverse3(a, out)
        np.testing.assert_allclose(out, np.linalg.inv(a), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(a @ out, np.eye(3), atol=1e-10)
    inverse3(np.diag([2.0, 4.0, 8.0]), out)
    np.testing.assert_array_equal(out, np.diag([0.5, 0.25, 0.125]))
    with pytest.raises(ValueError, match="singular"):
        inverse3(np.ones((3, 3)), out)


_PROBE = """
import hashlib, numpy as np
from clods_bench.datasets.cameras import Camera, look_at, intrinsics_from_fov
from clods_bench.datasets.cloth_solver import ClothSolver
from clods_bench.datasets.scenes import draw_wind, get_scene, initial_state
h = hashlib.sha256()
for name in ("flag", "sphere-drop", "flag-ball"):
    scene = get_scene(name)
    mesh = scene.build_mesh((9, 5) if name != "sphere-drop" else (8, 8))
    rng = np.random.default_rng(3)
    x, v, _ = initial_state(scene, mesh, rng)
    params, _ = draw_wind(scene, rng)
    solver = ClothSolver(mesh, params, scene.dt, seed=7, obstacles=scene.obstacles)
    for k in range(12):
        x, v = solver.step(x, v, k * scene.dt)
    h.update(x.tobytes()); h.update(v.tobytes())
R, t = look_at(np.array([2.0, -3.0, 1.0]), np.zeros(3))
h.update(Camera(intrinsics_from_fov(50.0, 64, 48), R, t, 64, 48).world_to_camera(x).tobytes())
print(h.hexdigest())
"""


def _cpu_flags() -> set[str]:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def _kernels() -> list[str]:
    """OpenBLAS kernels this CPU can run: Prescott and Nehalem need SSE only, Sandybridge AVX, Haswell AVX2."""
    flags = _cpu_flags()
    return ["Prescott", "Nehalem"] + (["Sandybridge"] if "avx" in flags else []) + (["Haswell"] if "avx2" in flags else [])


@pytest.mark.skipif(platform.machine() != "x86_64", reason="forces OpenBLAS's x86 kernels by name (OPENBLAS_CORETYPE)")
def test_generation_does_not_depend_on_the_blas_kernel():
    """The float64 cloth state after 12 solver steps of three scenes (wind, contact with a resting and a moving
    obstacle) and a camera projection, under OpenBLAS's automatic kernel and every forced one this CPU runs. Before
    the fix the automatic kernel of an AVX-512 host and Sandybridge's gave other bits than Haswell's (the
    preconditioner's 3x3 inverses went through LAPACK, the initial rotation through dgemm)."""
    digests = {}
    for core in [None, *_kernels()]:
        # host mode: deterministic mode would set OpenBLAS's kernel to Haswell's whatever is asked here
        env = {k: val for k, val in os.environ.items() if k != "OPENBLAS_CORETYPE"} | {"CLODS_BENCH_DETERMINISTIC": "0"}
        if core:
            env["OPENBLAS_CORETYPE"] = core
        run = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr[-2000:]
        digests[core or "automatic"] = run.stdout.strip()
    assert len(set(digests.values())) == 1, digests
