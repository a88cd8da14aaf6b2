"""SMGS (paper section 3.2, eq. 4): GaMeS with dual-position opacity modulation.

Opacity of Gaussian i at time t is alpha_i,t = sigmoid(MLP(PE(mu_W), PE(mu_M))): mu_W is the world
position of its centre (moves with the mesh: relative), mu_M its mesh-space position, the same
barycentric weights applied to `mesh_pos` (fixed: absolute). Both are normalised to [-1,1] by the
bounding boxes seen in `fit`, then NeRF positional encoding [x, sin(2^k pi x), cos(2^k pi x)]_{k<L}; the
mesh position is also encoded by a learned dense feature grid over mesh space, sampled bilinearly
(`mesh_grid`), so that the opacity can vary from Gaussian to Gaussian as GaMeS's does (the paper:
without mu_W the modulation "reduces to standard GaMeS").
Ablation switch `inputs`: 'both' (SMGS), 'world', 'mesh' (a per-Gaussian constant, i.e.
GaMeS-like), 'none' (one shared learned opacity). Everything else is GaMeS (`games.py`).

Defaults were chosen on the training trajectories of the ci data (held-out cameras, README "SMGS
defaults"): a world encoding with frequencies (world_freqs >= 1) fitted on one frame memorises the
frame's opacity pattern in world space and scrambles it as the cloth moves (-0.3 to -1.3 dB by frame
15), so the world position enters linearly (world_freqs 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.checks import FitInputs
from clods_bench.plugins.renderers.fitting import ParamGroup, check_positive
from clods_bench.plugins.renderers.games import GamesConfig, GamesRenderer, logit
from clods_bench.plugins.renderers.mesh_gaussians import mesh_space_means

Inputs = Literal["both", "world", "mesh", "none"]


@dataclass(frozen=True)
class SmgsConfig(GamesConfig):
    """Options of SMGS (`renderer_config.smgs.*`): GaMeS's plus the opacity MLP's."""

    inputs: Inputs = "both"
    """Opacity MLP inputs: 'both' (paper eq. 4), 'world' (mu_W only), 'mesh' (mu_M only), 'none' (constant)."""
    world_freqs: int = 0
    """Positional-encoding frequencies L of the world position (0: the normalised position itself)."""
    mesh_freqs: int = 6
    """Positional-encoding frequencies L of the mesh-space position."""
    mesh_grid: int = 48
    """Cells per side of the learned mesh-space feature grid (0: positional encoding only)."""
    grid_features: int = 4
    """Feature channels of that grid."""
    lr_grid: float = 0.02
    """Adam learning rate of the grid features."""
    hidden: int = 64
    """Width of the MLP's hidden layers."""
    layers: int = 2
    """Hidden layers of the MLP (ReLU)."""
    lr_mlp: float = 0.02
    """Adam learning rate of the MLP weights."""

    def validate(self, where: str) -> None:
        """GaMeS's checks plus the MLP's."""
        super().validate(where)
        if self.inputs not in ("both", "world", "mesh", "none"):
            raise ClodsError(f"unknown inputs '{self.inputs}'; known: both, world, mesh, none", where=f"{where}.inputs")
        for name in ("world_freqs", "mesh_freqs", "layers", "mesh_grid"):
            if getattr(self, name) < 0:
                raise ClodsError(f"must be >= 0, got {getattr(self, name)}", where=f"{where}.{name}")
        if self.mesh_grid == 1:
            raise ClodsError("must be 0 (off) or >= 2", where=f"{where}.mesh_grid")
        for name in ("hidden", "grid_features"):
            if getattr(self, name) < 1:
                raise ClodsError(f"must be >= 1, got {getattr(self, name)}", where=f"{where}.{name}")
        check_positive(self.lr_mlp, f"{where}.lr_mlp", allow_zero=True)
        check_positive(self.lr_grid, f"{where}.lr_grid", allow_zero=True)

    @property
    def uses_grid(self) -> bool:
        """Whether the mesh position is also encoded by the feature grid."""
        return self.inputs in ("both", "mesh") and self.mesh_grid > 0


def positional_encoding(x: Tensor, freqs: int) -> Tensor:
    """(G, D (1 + 2L)) NeRF encoding of (G,D) coordinates: x, sin(2^k pi x), cos(2^k pi x) for k < L."""
    if freqs == 0:
        return x
    scaled = x[:, None, :] * (math.pi * 2.0 ** torch.arange(freqs, dtype=x.dtype, device=x.device))[None, :, None]  # (G,L,D)
    return torch.cat([x, torch.sin(scaled).flatten(1), torch.cos(scaled).flatten(1)], dim=1)


def sample_grid(grid: Tensor, coords: Tensor) -> Tensor:
    """(G,C) features of a (C,R,R) or (C,R,R,R) grid spanning [-1,1]^D, bilinearly sampled at (G,D) coords.

    Grid axis order is (..., axis 1, axis 0): coordinate 0 runs along the last grid axis (torch grid_sample's x).
    Coordinates outside [-1,1] take the border value.
    """
    pts = coords.reshape((1, -1) + (1,) * (coords.shape[1] - 1) + (coords.shape[1],))
    out = torch.nn.functional.grid_sample(grid[None], pts.to(grid.dtype), mode="bilinear", padding_mode="border", align_corners=True)
    return out.reshape(grid.shape[0], -1).T


def box_normaliser(points: Tensor) -> tuple[Tensor, Tensor]:
    """Centre (D,) and half extent (scalar, > 0) mapping the points' bounding box into [-1,1]^D."""
    lo, hi = points.min(0).values, points.max(0).values
    half = ((hi - lo).max() / 2.0).clamp(min=1e-6)
    return (lo + hi) / 2.0, half


class SmgsRenderer(GamesRenderer):
    """GaMeS whose opacities come from an MLP of world- and mesh-space Gaussian positions."""

    name = "smgs"
    config: SmgsConfig

    def __init__(self, config: SmgsConfig | None = None, seed: int = 0, progress: bool = False) -> None:
        """Check the config; the MLP is created by `fit`."""
        super().__init__(config or SmgsConfig(), seed, progress)

    def _setup(self, data: FitInputs, gen: torch.Generator) -> None:
        """Normalisation boxes of world (all fitted frames) and mesh coordinates, and the fixed mesh-space means."""
        self.world_box = box_normaliser(torch.from_numpy(data.verts.reshape(-1, 3)))
        mesh_box = box_normaliser(self.mesh_pos)
        self.mesh_means = (mesh_space_means(self.mesh_pos, self.cells, self.bary) - mesh_box[0]) / mesh_box[1]

    def _init_params(self, data: FitInputs, gen: torch.Generator) -> None:
        """GaMeS's parameters without the per-Gaussian opacity, plus the MLP (last layer starts at init_opacity)."""
        super()._init_params(data, gen)
        del self.params["opacity_logit"]
        cfg = self.config
        use_w, use_m = cfg.inputs in ("both", "world"), cfg.inputs in ("both", "mesh")
        dim = self.mesh_means.shape[1]
        width_in = (3 * (1 + 2 * cfg.world_freqs) if use_w else 0) + (dim * (1 + 2 * cfg.mesh_freqs) if use_m else 0)
        if cfg.uses_grid:
            if dim not in (2, 3):
                raise ClodsError(f"the mesh-space grid needs 2- or 3-D mesh_pos, got {dim}-D", where=f"renderer_config.{self.name}.mesh_grid", hint="set mesh_grid=0")
            width_in += cfg.grid_features
            shape = (cfg.grid_features,) + (cfg.mesh_grid,) * dim
            self.params["mesh_grid"] = ((torch.rand(shape, generator=gen) * 2 - 1) * 0.01).requires_grad_()
        sizes = [max(width_in, 1)] + [cfg.hidden] * cfg.layers + [1]
        for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
            bound = 1.0 / math.sqrt(n_in)  # torch.nn.Linear's default init
            w = (torch.rand(n_out, n_in, generator=gen) * 2 - 1) * bound
            b = (torch.rand(n_out, generator=gen) * 2 - 1) * bound
            if i == len(sizes) - 2:  # last layer: near-constant initial opacity
                w, b = w * 0.01, torch.full((n_out,), logit(cfg.init_opacity))
            self.params[f"mlp_w{i}"], self.params[f"mlp_b{i}"] = w.requires_grad_(), b.requires_grad_()
        self.num_layers = len(sizes) - 1

    def _param_groups(self) -> list[ParamGroup]:
        """Scale and colour groups of GaMeS plus one group for the MLP."""
        groups = super()._param_groups()
        mlp = [p for k, p in self.params.items() if k.startswith("mlp_")]
        groups.append(ParamGroup("mlp", mlp, self.config.lr_mlp))
        if "mesh_grid" in self.params:
            groups.append(ParamGroup("mesh_grid", [self.params["mesh_grid"]], self.config.lr_grid))
        return groups

    def features(self, means: Tensor) -> Tensor:
        """(G,E) MLP input: encoded normalised world and/or mesh positions per `inputs` (zeros (G,1) for 'none')."""
        cfg, parts = self.config, []
        if cfg.inputs in ("both", "world"):
            centre, half = self.world_box
            parts.append(positional_encoding((means - centre.to(means.dtype)) / half.to(means.dtype), cfg.world_freqs))
        if cfg.inputs in ("both", "mesh"):
            parts.append(positional_encoding(self.mesh_means.to(means.dtype), cfg.mesh_freqs))
        if cfg.uses_grid:
            parts.append(sample_grid(self.params["mesh_grid"].to(means.dtype), self.mesh_means.to(means.dtype)))
        return torch.cat(parts, dim=1) if parts else torch.zeros(means.shape[0], 1, dtype=means.dtype, device=means.device)

    def _move_to(self, device: torch.device) -> None:
        """GaMeS's move, dropping the frozen-MLP cache (rebuilt on the new device on first use)."""
        vars(self).pop("_frozen", None)
        super()._move_to(device)

    def __getstate__(self) -> dict:
        """Pickle (the stage-1 cache) without the frozen-MLP cache: it is rebuilt on first use."""
        state = dict(vars(self))
        state.pop("_frozen", None)
        return state

    def _frozen_first_layer(self, dtype: torch.dtype, device: torch.device) -> Tensor | None:
        """Layer 0's pre-activation from the fixed inputs alone (mesh encoding, grid features, bias) as (G, hidden), once
        the fit has frozen the MLP (stage 2, predictions, evaluation); None while it trains or with no mesh inputs.

        The mesh-space position of a Gaussian never moves, so with frozen weights this part of layer 0 is the same in
        every render: computing it once leaves only the world position's columns (3 at world_freqs 0) per render, and
        skips the encoding, the grid sampling and their backward. Cached by the identity and version of the weights.
        """
        cfg = self.config
        if cfg.inputs not in ("both", "mesh"):
            return None
        fixed = [self.params[k] for k in ("mlp_w0", "mlp_b0", "mesh_grid") if k in self.params]
        if any(p.requires_grad for p in fixed):
            return None
        key = (dtype, device, tuple((id(p), p._version) for p in fixed))
        cache = getattr(self, "_frozen", None)
        if cache is None or cache[0] != key:
            parts = [positional_encoding(self.mesh_means.to(device, dtype), cfg.mesh_freqs)]
            if cfg.uses_grid:
                parts.append(sample_grid(self.params["mesh_grid"].to(device, dtype), self.mesh_means.to(device, dtype)))
            w0 = self.params["mlp_w0"].to(dtype)
            mesh_cols = w0[:, w0.shape[1] - sum(x.shape[1] for x in parts):]
            cache = (key, torch.nn.functional.linear(torch.cat(parts, dim=1), mesh_cols, self.params["mlp_b0"].to(dtype)))
            self._frozen = cache
        return cache[1]

    def opacities(self, means: Tensor, verts: Tensor) -> Tensor:
        """(G,) opacities sigmoid(MLP(features)); they change with the world positions unless inputs is 'mesh'/'none'."""
        fixed = self._frozen_first_layer(means.dtype, means.device)
        if fixed is not None:  # frozen: layer 0 = world columns x world encoding + the cached fixed part
            cfg = self.config
            if cfg.inputs == "both":
                centre, half = self.world_box
                world = positional_encoding((means - centre.to(means.dtype)) / half.to(means.dtype), cfg.world_freqs)
                h = torch.nn.functional.linear(world, self.params["mlp_w0"][:, : world.shape[1]].to(means.dtype)) + fixed
            else:
                h = fixed
            for i in range(1, self.num_layers):
                h = torch.nn.functional.linear(torch.relu(h), self.params[f"mlp_w{i}"].to(h.dtype), self.params[f"mlp_b{i}"].to(h.dtype))
            return torch.sigmoid(h[:, 0])
        h = self.features(means)
        for i in range(self.num_layers):
            h = torch.nn.functional.linear(h, self.params[f"mlp_w{i}"].to(h.dtype), self.params[f"mlp_b{i}"].to(h.dtype))
            if i < self.num_layers - 1:
                h = torch.relu(h)
        return torch.sigmoid(h[:, 0])
