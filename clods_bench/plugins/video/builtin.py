"""Registers the built-in video predictors through the `clods_bench` entry-point group."""

from __future__ import annotations

from typing import Any

from clods_bench.benchmark.descriptors import BuildContext, PluginSpec
from clods_bench.benchmark.hookspecs import hookimpl
from clods_bench.plugins.video.simvp import SimvpConfig


def _build_copylast(cfg: Any, ctx: BuildContext) -> Any:
    from clods_bench.plugins.video.copylast import CopyLastPredictor

    return CopyLastPredictor()


def _build_simvp(cfg: SimvpConfig, ctx: BuildContext) -> Any:
    from clods_bench.plugins.video.simvp import SimvpPredictor

    return SimvpPredictor(cfg, seed=ctx.seed, progress=ctx.progress)


@hookimpl
def clods_bench_video_predictors() -> list[PluginSpec]:
    return [
        PluginSpec(
            name="copylast",
            description="Copy the last observed frame into every future frame (the floor for video prediction).",
            build=_build_copylast,
        ),
        PluginSpec(
            name="simvp",
            description="SimVP (Gao et al. 2022): CNN encoder, Inception translator over stacked time, CNN decoder; MSE on single-view videos.",
            build=_build_simvp,
            config_cls=SimvpConfig,
            learned=True,
        ),
    ]
