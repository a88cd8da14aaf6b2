"""Hook specification: scene plugins (cloth set-ups the data generator can simulate)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

from clods_bench.benchmark.core.hookspecs import hookspec

if TYPE_CHECKING:
    from clods_bench.datasets.scenes import SceneSpec


@hookspec
def clods_bench_scenes() -> Sequence["SceneSpec"]:
    """Return the scenes this plugin provides (`clods_bench.datasets.scenes.SceneSpec`).

    A scene brings its own cloth (`clods_bench.datasets.cloths.Cloth`: the triangle mesh, its 2D
    material coordinates `mesh_pos`, the handle nodes and their prescribed motion), the solver
    parameters and wind, and the ranges each trajectory's initial state is drawn from; its mesh is
    validated when built. It declares what it has (obstacles, wind, lighting, handles) so that
    simulators, renderers and tasks leave out what it does not need.
    """
