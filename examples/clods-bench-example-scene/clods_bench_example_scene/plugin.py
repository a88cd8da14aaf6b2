"""The entry-point module: one hook returning the scene (its cloth, physics and random ranges)."""

from __future__ import annotations

from clods_bench.api import SceneSpec, SolverParams, hookimpl

from clods_bench_example_scene.banner import load_banner

CLODS_BENCH_API = "1.1"  # the plugin API this package is written for (clods_bench.api)

CANVAS = SolverParams(density=0.3, youngs_modulus=8000.0, bending_stiffness=1e-3, turbulence_amplitude=0.3, air_drag=0.02,
                      damping_stiffness=1e-3)  # fmt: skip


@hookimpl
def clods_bench_scenes() -> list[SceneSpec]:
    return [
        SceneSpec(
            name="banner",
            description="Example plugin: a swallowtail banner (OBJ) pinned to a swaying bar, in a light breeze (clods-bench-example-scene).",
            cloth=load_banner(),
            params=CANVAS,
            rotation_range=(-0.3, 0.3),
            init_speed_range=(0.0, 0.3),
            perturb_amplitude=0.02,
            wind_speed_range=(1.0, 2.0),
            wind_direction_spread=0.5,
        )
    ]
