"""Registers the built-in simulators through the `clods_bench` entry-point group."""

from __future__ import annotations

from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.plugins.simulators.baselines import ConstantVelocity, Frozen
from clods_bench.plugins.simulators.learned.config import MgnConfig
from clods_bench.plugins.simulators.learned.lip_config import LipConfig
from clods_bench.plugins.simulators.learned.unet_configs import BsmsConfig, DhmpConfig, HcmtConfig
from clods_bench.plugins.simulators.physics import PhysicsConfig, PhysicsSimulator


def _build_mgn(cfg: MgnConfig, ctx: object) -> object:
    from clods_bench.plugins.simulators.learned.mgn import build_mgn  # torch is imported only when a model is built

    return build_mgn(cfg, ctx)


def _build_bsms(cfg: BsmsConfig, ctx: object) -> object:
    from clods_bench.plugins.simulators.learned.bsms import build_bsms  # torch is imported only when a model is built

    return build_bsms(cfg, ctx)


def _build_hcmt(cfg: HcmtConfig, ctx: object) -> object:
    from clods_bench.plugins.simulators.learned.hcmt import build_hcmt  # torch is imported only when a model is built

    return build_hcmt(cfg, ctx)


def _build_dhmp(cfg: DhmpConfig, ctx: object) -> object:
    from clods_bench.plugins.simulators.learned.dhmp import build_dhmp  # torch is imported only when a model is built

    return build_dhmp(cfg, ctx)


def _build_lip(cfg: LipConfig, ctx: object) -> object:
    from clods_bench.plugins.simulators.learned.lip import build_lip  # torch is imported only when a model is built

    return build_lip(cfg, ctx)


@hookimpl
def clods_bench_simulators() -> list[PluginSpec]:
    return [
        PluginSpec(
            name="constvel",
            label="Const. velocity",
            description="Constant-velocity baseline: x[t+1] = 2 x[t] - x[t-1], handles kinematic.",
            build=lambda cfg, ctx: ConstantVelocity(),
        ),
        PluginSpec(
            name="frozen",
            label="Frozen",
            description="Frozen-cloth baseline: every free node stays where it is at frame 1.",
            build=lambda cfg, ctx: Frozen(),
        ),
        PluginSpec(
            name="physics",
            label="Physics",
            description="Traditional pipeline: the implicit cloth solver with the scene's known physics and expected wind.",
            build=lambda cfg, ctx: PhysicsSimulator(ctx.scene, cfg),
            config_cls=PhysicsConfig,
        ),
        PluginSpec(
            name="mgn",
            label="MGN",
            description="MeshGraphNets cloth model (encode-process-decode, 15 residual message-passing steps), mesh-supervised.",
            build=_build_mgn,
            config_cls=MgnConfig,
            learned=True,
        ),
        PluginSpec(
            name="bsms",
            label="BSMS",
            variant="MGN cloth frame",
            description="BSMS-GNN variant: the authors' bi-stride message-passing U-Net (same-weights match to their code) in MGN's cloth frame (features, normalisers, noise, acceleration loss and training), its fibres normalised per level; mesh-supervised.",
            build=_build_bsms,
            config_cls=BsmsConfig,
            learned=True,
        ),
        PluginSpec(
            name="hcmt",
            label="HCMT",
            variant="MGN cloth frame",
            description="HCMT variant: the authors' processor (contact and hierarchical mesh transformers over bi-stride levels, same-weights match) in MGN's cloth frame (features, noise, acceleration output without the stress head, training); mesh-supervised.",
            build=_build_hcmt,
            config_cls=HcmtConfig,
            learned=True,
        ),
        PluginSpec(
            name="dhmp",
            label="DHMP",
            variant="MGN cloth frame",
            description="DHMP variant: the authors' anisotropic U-Net over levels selected per input (EvoMesh code, same-weights match) in MGN's cloth frame (features, normalisers, noise, loss and training), its fibres normalised per level, the most probable levels in evaluation; mesh-supervised.",
            build=_build_dhmp,
            config_cls=DhmpConfig,
            learned=True,
        ),
        PluginSpec(
            name="lip",
            label="LIP-style",
            description="LIP-style particle model: GNS encode-process-decode over a radius graph rebuilt every step, no mesh edges.",
            build=_build_lip,
            config_cls=LipConfig,
            learned=True,
        ),
    ]
