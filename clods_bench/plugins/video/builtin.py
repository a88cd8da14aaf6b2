"""Registers the built-in video predictors through the `clods_bench` entry-point group."""

from __future__ import annotations

from typing import Any

from clods_bench.benchmark.core.descriptors import BuildContext, PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.plugins.video.mau import MauConfig
from clods_bench.plugins.video.mmvp import MmvpConfig
from clods_bench.plugins.video.simvp import SimvpConfig
from clods_bench.plugins.video.tau import TauConfig


def _build_copylast(cfg: Any, ctx: BuildContext) -> Any:
    from clods_bench.plugins.video.copylast import CopyLastPredictor

    return CopyLastPredictor()


def _build_simvp(cfg: SimvpConfig, ctx: BuildContext) -> Any:
    from clods_bench.plugins.video.simvp import SimvpPredictor

    return SimvpPredictor(cfg, seed=ctx.seed, progress=ctx.progress)


def _build_tau(cfg: TauConfig, ctx: BuildContext) -> Any:
    from clods_bench.plugins.video.tau import TauPredictor

    return TauPredictor(cfg, seed=ctx.seed, progress=ctx.progress)


def _build_mau(cfg: MauConfig, ctx: BuildContext) -> Any:
    from clods_bench.plugins.video.mau import MauPredictor

    return MauPredictor(cfg, seed=ctx.seed, progress=ctx.progress)


def _build_mmvp(cfg: MmvpConfig, ctx: BuildContext) -> Any:
    from clods_bench.plugins.video.mmvp import MmvpPredictor

    return MmvpPredictor(cfg, seed=ctx.seed, progress=ctx.progress)


@hookimpl
def clods_bench_video_predictors() -> list[PluginSpec]:
    return [
        PluginSpec(
            name="copylast",
            label="Copy last",
            description="Copy the last observed frame into every future frame (the floor for video prediction).",
            build=_build_copylast,
        ),
        PluginSpec(
            name="simvp",
            label="SimVP",
            description="SimVP (v1) (Gao et al. CVPR 2022, the authors' code): CNN encoder, Inception U-Net translator over stacked time, CNN decoder; MSE, Adam one-cycle at 0.01.",
            build=_build_simvp,
            config_cls=SimvpConfig,
            learned=True,
        ),
        PluginSpec(
            name="tau",
            label="TAU",
            description="TAU (Tan et al. CVPR 2023, the authors' OpenSTL code): SimVP v2 encoder/decoder around temporal attention units; MSE + 0.1 x differential divergence.",
            build=_build_tau,
            config_cls=TauConfig,
            learned=True,
        ),
        PluginSpec(
            name="mau",
            label="MAU",
            description="MAU (Chang et al. NeurIPS 2021, the authors' code): recurrent motion-aware units attending over past states; MSE with scheduled sampling.",
            build=_build_mau,
            config_cls=MauConfig,
            learned=True,
        ),
        PluginSpec(
            name="mmvp",
            label="MMVP",
            description="MMVP (Zhong et al. 2023): motion matrices of feature maps, predicted and composed with the last frame's features.",
            build=_build_mmvp,
            config_cls=MmvpConfig,
            learned=True,
        ),
    ]
