"""The public plugin API of clods-bench, in one place, with its version.

A plugin package imports what it needs from here (`from clods_bench.api import PluginSpec, hookimpl`) and may
declare the API version it was written for in its entry-point module: `CLODS_BENCH_API = "1.2"`. Everything in
`__all__` follows the API's semantic versioning (`clods_bench.api_version`): a minor version only adds; a change or
a removal is a major version, announced a minor release ahead with a `PluginAPIDeprecationWarning` that says what to
write instead. The changelog names every change. Whatever is not listed here is internal and may change in any
release, even where a plugin can reach it.

The hooks a plugin implements (one list of descriptors each, all implementations concatenated):
`clods_bench_simulators`, `clods_bench_renderers`, `clods_bench_video_predictors` (`PluginSpec`),
`clods_bench_scenes` (`SceneSpec`) and `clods_bench_tasks` (`TaskSpec`, with the `TableLayout` of its table);
their contracts are the docstrings of `clods_bench.benchmark.core.hookspecs`.
"""

from __future__ import annotations

from clods_bench.api_version import API_VERSION, DECLARATION, PluginAPIDeprecationWarning
from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.descriptors import BuildContext, EmptyConfig, PluginSpec, TableLayout, TaskContext, TaskResult, TaskSpec
from clods_bench.benchmark.core.hookspecs import ENTRY_POINT_GROUP, hookimpl
from clods_bench.benchmark.core.interfaces import (
    FitContext,
    Renderer,
    RolloutInput,
    Simulator,
    VideoPredictor,
    check_prediction,
    check_rollout,
    check_video,
)
from clods_bench.benchmark.outputs.tables import metric_frame
from clods_bench.datasets.cameras import Camera
from clods_bench.datasets.cloth_solver import SolverParams
from clods_bench.datasets.cloths import Cloth, CylinderCloth, FlagCloth, MeshCloth, Resolution, SheetCloth, mesh_cloth_from_file
from clods_bench.datasets.data_config import DataConfig
from clods_bench.datasets.lighting import DirectionalLight
from clods_bench.datasets.obstacles import Obstacle, ObstaclePath, Sphere
from clods_bench.datasets.scenes import SceneSpec
from clods_bench.datasets.types import HANDLE, NORMAL, OBSTACLE, ClothMesh, Trajectory
from clods_bench.errors import ClodsError

HOOKS = ("clods_bench_simulators", "clods_bench_renderers", "clods_bench_video_predictors", "clods_bench_scenes", "clods_bench_tasks")
"""The hook names a plugin may implement (with `@hookimpl`)."""

__all__ = [
    # version and registration
    "API_VERSION",
    "DECLARATION",
    "ENTRY_POINT_GROUP",
    "HOOKS",
    "PluginAPIDeprecationWarning",
    "hookimpl",
    # descriptors the hooks return, and what their factories and runs receive
    "PluginSpec",
    "TaskSpec",
    "BuildContext",
    "TaskContext",
    "TaskResult",
    "EmptyConfig",
    # a task's table (API 1.2)
    "TableLayout",
    "metric_frame",
    "RunConfig",
    "DataConfig",
    # the plugin interfaces and their checks
    "Simulator",
    "Renderer",
    "VideoPredictor",
    "RolloutInput",
    "FitContext",
    "check_rollout",
    "check_video",
    "check_prediction",
    # scenes and their cloths
    "SceneSpec",
    "Cloth",
    "FlagCloth",
    "CylinderCloth",
    "SheetCloth",
    "MeshCloth",
    "mesh_cloth_from_file",
    "Resolution",
    "SolverParams",
    "DirectionalLight",
    "Obstacle",
    "ObstaclePath",
    "Sphere",
    # data
    "ClothMesh",
    "Trajectory",
    "Camera",
    "NORMAL",
    "OBSTACLE",
    "HANDLE",
    # errors
    "ClodsError",
]
