"""Registers the built-in renderers through the `clods_bench` entry-point group."""

from __future__ import annotations

from typing import Any

from clods_bench.benchmark.core.descriptors import BuildContext, PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.plugins.renderers.games import GamesConfig
from clods_bench.plugins.renderers.gs3d import Gs3dConfig
from clods_bench.plugins.renderers.smgs import SmgsConfig


def _build_games(cfg: GamesConfig, ctx: BuildContext) -> Any:
    from clods_bench.plugins.renderers.games import GamesRenderer

    return GamesRenderer(cfg, seed=ctx.seed, progress=ctx.progress)


def _build_smgs(cfg: SmgsConfig, ctx: BuildContext) -> Any:
    from clods_bench.plugins.renderers.smgs import SmgsRenderer

    return SmgsRenderer(cfg, seed=ctx.seed, progress=ctx.progress)


def _build_gs3d(cfg: Gs3dConfig, ctx: BuildContext) -> Any:
    from clods_bench.plugins.renderers.gs3d import Gs3dRenderer

    return Gs3dRenderer(cfg, seed=ctx.seed, progress=ctx.progress)


@hookimpl
def clods_bench_renderers() -> list[PluginSpec]:
    return [
        PluginSpec(
            name="games",
            label="GaMeS",
            description="GaMeS: Gaussians on mesh faces (fixed barycentric weights, Gram-Schmidt frames), constant opacity.",
            build=_build_games,
            config_cls=GamesConfig,
        ),
        PluginSpec(
            name="smgs",
            label="SMGS",
            description="SMGS (CloDS eq. 4): GaMeS with opacity = MLP(world, mesh-space position of each Gaussian).",
            build=_build_smgs,
            config_cls=SmgsConfig,
        ),
        PluginSpec(
            name="gs3d",
            label="3DGS (per frame)",
            description="Per-frame 3D Gaussian splatting fitted on every frame independently (free geometry; no temporal or mesh prior).",
            build=_build_gs3d,
            config_cls=Gs3dConfig,
        ),
    ]
