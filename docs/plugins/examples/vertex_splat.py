"""A renderer plugin in one module: one isotropic Gaussian on every mesh vertex, its colour fitted to the images.

Mesh-driven, so it is differentiable with respect to the vertices and can serve CloDS's mesh extraction as well as
the NVS task. Register it with one line in your package's pyproject.toml:

    [project.entry-points.clods_bench]
    vertex_splat = "my_package.vertex_splat"
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import torch

from clods_bench.api import ClodsError, PluginSpec, hookimpl
from clods_bench.splatting import render_gaussians  # the benchmark's splatting (internal: not in clods_bench.api)

CLODS_BENCH_API = "1.1"  # the plugin API this module is written for


@dataclass(frozen=True)
class VertexSplatConfig:
    """Options of `vertex-splat` (`renderer_config.vertex-splat.*`, or `--set`)."""

    size: float = 0.5
    """Standard deviation of each vertex's isotropic Gaussian, as a fraction of the mesh's mean edge length."""
    opacity: float = 0.95
    """Opacity of every Gaussian, in (0, 1)."""
    iterations: int = 60
    """Adam steps fitting the vertex colours."""
    learning_rate: float = 0.1
    """Adam's step on the colour logits."""


class VertexSplat:
    """Gaussians at the vertices; `fit` learns a colour per vertex, `render` splats them for any vertex positions."""

    per_frame = False  # one representation for the whole trajectory: the NVS task fits it on frame 0 only

    def __init__(self, cfg: VertexSplatConfig, seed: int) -> None:
        if cfg.size <= 0 or not 0.0 < cfg.opacity < 1.0 or cfg.iterations < 1:
            raise ClodsError(f"needs size > 0, 0 < opacity < 1, iterations >= 1; got {cfg}", where="renderer_config.vertex-splat")
        self.cfg = cfg
        self.generator = torch.Generator().manual_seed(seed)
        self.logits: torch.Tensor | None = None
        self.sigma = 0.0

    def fit(self, verts: Any, cells: Any, mesh_pos: Any, images: Any, cameras: Sequence[Any]) -> dict[str, float]:
        """Fit the colours to B frames: verts (B,V,3) world positions, images (B,N,H,W,3) in [0,1] seen by `cameras`."""
        frames = torch.as_tensor(verts, dtype=torch.float32)
        targets = torch.as_tensor(images, dtype=torch.float32)
        tri = torch.as_tensor(cells, dtype=torch.long)
        edges = frames[0][tri] - frames[0][tri.roll(1, dims=1)]  # (F,3,3): each triangle's three edges
        self.sigma = self.cfg.size * float(edges.norm(dim=-1).mean())
        self.logits = (0.1 * torch.randn(frames.shape[1], 3, generator=self.generator)).requires_grad_()
        opt = torch.optim.Adam([self.logits], lr=self.cfg.learning_rate)
        for it in range(self.cfg.iterations):
            b = it % frames.shape[0]
            loss = (self.render(frames[b], cameras) - targets[b]).abs().mean()  # L1, as the built-in renderers
            opt.zero_grad()
            loss.backward()
            opt.step()
        self.logits.requires_grad_(False)
        return {"final_loss": float(loss.detach()), "num_gaussians": float(frames.shape[1])}

    def render(self, verts: Any, cameras: Sequence[Any]) -> torch.Tensor:
        """(N,H,W,3) images in [0,1] of the mesh at `verts` (V,3); differentiable with respect to `verts`."""
        if self.logits is None:
            raise ClodsError("render called before fit", where="renderer 'vertex-splat'")
        means = torch.as_tensor(verts, dtype=torch.float32)
        covars = (self.sigma**2) * torch.eye(3).expand(means.shape[0], 3, 3)
        opacities = torch.full((means.shape[0],), self.cfg.opacity)
        out = render_gaussians(means, covars, opacities, torch.sigmoid(self.logits), list(cameras))  # white background
        return out.rgb


@hookimpl
def clods_bench_renderers() -> list[PluginSpec]:
    """The one hook: the plugin's name, description, factory and config class."""
    return [
        PluginSpec(
            name="vertex-splat",
            description="Example plugin: one isotropic Gaussian per mesh vertex with a fitted colour.",
            build=lambda cfg, ctx: VertexSplat(cfg, seed=ctx.seed),
            config_cls=VertexSplatConfig,
        )
    ]
