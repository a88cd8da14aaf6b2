"""GaMeS (Waczynska et al. 2024): Gaussians anchored on mesh faces, driven by the mesh, fixed opacities.

Fitted parameters: per Gaussian an in-plane scale factor (log), an opacity (logit) and a colour (RGB,
or SH coefficients of `sh_degree` >= 1). Barycentric weights are fixed (the paper's "the same beta"
as the mesh deforms); geometry comes from the vertices (`mesh_gaussians`). `render(verts, cameras)`
is differentiable w.r.t. `verts` (CloDS stage 2 recovers meshes through it). SMGS (`smgs.py`)
subclasses this and replaces the opacity.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch
from torch import Tensor

from clods_bench.datasets.cameras import Camera
from clods_bench.errors import ClodsError
from clods_bench.plugins.renderers.checks import FitInputs, check_fit_inputs, check_render_cameras, check_render_verts
from clods_bench.plugins.renderers.device import check_device_config, fit_device, leaf_to, tensors_to
from clods_bench.plugins.renderers.fitting import ParamGroup, check_positive, fit_adam
from clods_bench.plugins.renderers.losses import render_loss
from clods_bench.plugins.renderers.mesh_gaussians import anchor_gaussians, barycentric_layout
from clods_bench.splatting import render_gaussians
from clods_bench.splatting.sh import num_sh_bases
from clods_bench.typed_config import check_count

Backend = Literal["cpu", "reference", "gsplat"]


@dataclass(frozen=True)
class GamesConfig:
    """Options of the GaMeS renderer (`renderer_config.games.*`); defaults fit the ci preset in seconds."""

    gaussians_per_face: int = 5
    """Gaussians anchored on each face at fixed barycentric weights (paper: 5, 10 or 20)."""
    iterations: int = 300
    """Adam steps of the fit (each renders every training camera of one frame)."""
    sh_degree: int = 0
    """Colour model: 0 = one learnable RGB per Gaussian (SH degree 0), 1-3 = view-dependent SH."""
    normal_scale: float = 1e-6
    """Standard deviation (m) across the face: GaMeS Gaussians are flat (its eps)."""
    init_opacity: float = 0.1
    """Initial opacity (GaMeS: 0.1)."""
    init_scale_factor: float = 1.0
    """Initial in-plane scale multiplier (GaMeS: 1, i.e. half the centroid-to-vertex distance)."""
    lr_color: float = 0.05
    """Adam learning rate of the colours (RGB units; SH degree >= 1 terms use 1/20 of it, as 3DGS)."""
    lr_opacity: float = 0.1
    """Adam learning rate of the opacity logits."""
    lr_scale: float = 0.02
    """Adam learning rate of the log scale factors."""
    lr_final_factor: float = 0.1
    """Every learning rate decays exponentially to this fraction of itself over the fit."""
    lambda_dssim: float = 0.2
    """Weight of D-SSIM = 1 - SSIM in the loss (paper eq. 5: 0.2)."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Colour behind the Gaussians (the ground-truth renderer's is white)."""
    backend: Backend = "cpu"
    """Splatting backend: 'cpu' (numba), 'reference' (plain torch, slow) or 'gsplat' (CUDA)."""
    device: str = "cpu"
    """Where parameters, targets and loss live during fit: 'cpu', or 'cuda[:N]' with backend gsplat."""

    def validate(self, where: str) -> None:
        """Raise ClodsError naming the first field that is out of range."""
        if self.gaussians_per_face < 1:
            raise ClodsError(f"must be >= 1, got {self.gaussians_per_face}", where=f"{where}.gaussians_per_face")
        check_count(self.iterations, f"{where}.iterations", minimum=0)
        if not 0 <= self.sh_degree <= 3:
            raise ClodsError(f"must be in 0..3, got {self.sh_degree}", where=f"{where}.sh_degree")
        if not 0.0 < self.init_opacity < 1.0:
            raise ClodsError(f"must be in (0, 1), got {self.init_opacity}", where=f"{where}.init_opacity")
        if not 0.0 <= self.lambda_dssim <= 1.0:
            raise ClodsError(f"must be in [0, 1], got {self.lambda_dssim}", where=f"{where}.lambda_dssim")
        for name in ("normal_scale", "init_scale_factor", "lr_final_factor"):
            check_positive(getattr(self, name), f"{where}.{name}")
        for name in ("lr_color", "lr_opacity", "lr_scale"):
            check_positive(getattr(self, name), f"{where}.{name}", allow_zero=True)
        if len(self.background) != 3 or not all(math.isfinite(b) for b in self.background):
            raise ClodsError(f"must be 3 finite numbers, got {self.background!r}", where=f"{where}.background")
        if self.backend not in ("cpu", "reference", "gsplat"):
            raise ClodsError(f"unknown backend '{self.backend}'; known: cpu, reference, gsplat", where=f"{where}.backend")
        check_device_config(self.device, self.backend, where)


def logit(p: float) -> float:
    """Inverse of the sigmoid."""
    return math.log(p / (1.0 - p))


class GamesRenderer:
    """A mesh-driven Gaussian renderer: fit on frames with known meshes, then render any deformation of the mesh."""

    name = "games"
    per_frame = False  # one representation for the whole trajectory (the NVS task fits it once, on frame 0)

    def __init__(self, config: GamesConfig | None = None, seed: int = 0, progress: bool = False) -> None:
        """Check the config; parameters are created by `fit` (they depend on the mesh)."""
        self.config = config or GamesConfig()
        self.config.validate(f"renderer_config.{self.name}")
        self.seed = seed
        self.progress = progress
        self.cells: Tensor | None = None
        self.bary = torch.tensor(barycentric_layout(self.config.gaussians_per_face), dtype=torch.float64)
        self.params: dict[str, Tensor] = {}
        self.device = torch.device("cpu")  # where the fitted tensors live (config.device once fit)

    # ------------------------------------------------------------------ parameters

    @property
    def num_gaussians(self) -> int:
        """Gaussians in the fitted representation (0 before fit)."""
        return 0 if self.cells is None else int(self.cells.shape[0]) * self.config.gaussians_per_face

    def _init_params(self, data: FitInputs, gen: torch.Generator) -> None:
        """Create the learnable tensors for G = F * K Gaussians (subclasses add theirs)."""
        cfg, G = self.config, self.num_gaussians
        self.params = {
            "log_scale": torch.full((G,), math.log(cfg.init_scale_factor)).requires_grad_(),
            "opacity_logit": torch.full((G,), logit(cfg.init_opacity)).requires_grad_(),
            **init_colors(G, cfg.sh_degree),
        }

    def _param_groups(self) -> list[ParamGroup]:
        """Adam groups with their learning rates (SH rest at 1/20 of the colour rate, as 3DGS)."""
        cfg, p = self.config, self.params
        groups = [ParamGroup("log_scale", [p["log_scale"]], cfg.lr_scale)]
        if "opacity_logit" in p:  # SMGS replaces it by an MLP
            groups.append(ParamGroup("opacity", [p["opacity_logit"]], cfg.lr_opacity))
        groups.append(ParamGroup("color", [p["color"]], cfg.lr_color))
        if "sh_rest" in p:
            groups.append(ParamGroup("sh_rest", [p["sh_rest"]], cfg.lr_color / 20.0))
        return groups

    def opacities(self, means: Tensor, verts: Tensor) -> Tensor:
        """(G,) opacities in (0,1); GaMeS: one learnable constant per Gaussian (SMGS overrides)."""
        return torch.sigmoid(self.params["opacity_logit"]).to(means.dtype)

    def gaussians(self, verts: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Means (G,3), covariances (G,3,3), opacities (G,) and colours of the Gaussians on the mesh `verts`."""
        if self.cells is None:
            raise ClodsError("render called before fit", where=f"renderer '{self.name}'", hint="call fit on the first frame first")
        factor = torch.exp(self.params["log_scale"]).to(verts.dtype)
        means, covars, _ = anchor_gaussians(verts, self.cells, self.bary, factor, self.config.normal_scale)
        return means, covars, self.opacities(means, verts), colors_of(self.params, verts.dtype)

    # ------------------------------------------------------------------ interface

    def fit(self, verts: Any, cells: Any, mesh_pos: Any, images: Any, cameras: Sequence[Camera]) -> dict[str, float]:
        """Fit colours, scales and opacities to B frames (B,N,H,W,3) with known meshes (B,V,3); returns statistics."""
        where = f"renderer '{self.name}'.fit"
        data = check_fit_inputs(verts, cells, mesh_pos, images, cameras, where)
        device = fit_device(self.config.device, f"renderer_config.{self.name}")
        self.num_verts = data.verts.shape[1]
        self.cells = torch.from_numpy(data.cells)
        self.mesh_pos = torch.from_numpy(data.mesh_pos)
        gen = torch.Generator().manual_seed(self.seed)
        self._setup(data, gen)
        self._init_params(data, gen)  # on the CPU: the same initial values on every device
        self._move_to(device)
        frames = torch.from_numpy(data.verts).to(device, torch.float32)
        targets = torch.from_numpy(data.images).to(device)
        cams = list(data.cameras)

        def loss_at(it: int) -> Tensor:
            b = it % frames.shape[0]
            pred = self.render(frames[b], cams)
            return render_loss(pred, targets[b], self.config.lambda_dssim)

        stats = fit_adam(self._param_groups(), loss_at, self.config.iterations, self.config.lr_final_factor, self.progress, f"fit {self.name}")
        for p in self.params.values():
            p.requires_grad_(False)
        stats["num_gaussians"] = float(self.num_gaussians)
        return stats

    def relocate(self) -> None:
        """Put the fitted tensors back on `self.device` after a pickled fit was loaded with map_location='cpu' (the
        stage-1 cache): the device attribute survives pickling, the tensors land on the CPU."""
        if self.device.type == "cuda":
            fit_device(str(self.device), f"renderer_config.{self.name}")  # a clear error when that GPU is absent
        self._move_to(self.device)

    def _move_to(self, device: torch.device) -> None:
        """Move the parameters (as new leaves) and every other tensor attribute to `device`."""
        self.params = {k: leaf_to(p, device) for k, p in self.params.items()}
        for name, value in list(vars(self).items()):
            if name != "params":
                setattr(self, name, tensors_to(value, device))
        self.device = device

    def _setup(self, data: FitInputs, gen: torch.Generator) -> None:
        """Hook for subclasses that need the fit data before parameters are created (SMGS: normalisation)."""

    def render(self, verts: Any, cameras: Sequence[Camera]) -> Tensor:
        """(N,H,W,3) images of the mesh at `verts` (V,3) seen by `cameras`; differentiable w.r.t. verts."""
        where = f"renderer '{self.name}'.render"
        if self.cells is None:
            raise ClodsError("render called before fit", where=where, hint="call fit on the first frame first")
        v = check_render_verts(verts, self.num_verts, where)
        cams = check_render_cameras(cameras, where)
        means, covars, opac, colors = self.gaussians(v.to(self.device))  # differentiable across devices
        out = render_gaussians(
            means, covars, opac, colors, cams,
            sh_degree=self.config.sh_degree if self.config.sh_degree > 0 else None,
            background=self.config.background, backend=self.config.backend,
        )  # fmt: skip
        return out.rgb.to(v.device)


def init_colors(num: int, sh_degree: int) -> dict[str, Tensor]:
    """Grey learnable colours: {'color': (G,3) RGB} for degree 0, plus {'sh_rest': (G,B-1,3)} zeros for SH."""
    if sh_degree == 0:
        return {"color": torch.full((num, 3), 0.5).requires_grad_()}
    return {  # DC coefficient c0 renders as SH_C0 * c0 + 0.5: zero is grey
        "color": torch.zeros(num, 3).requires_grad_(),
        "sh_rest": torch.zeros(num, num_sh_bases(sh_degree) - 1, 3).requires_grad_(),
    }


def colors_of(params: dict[str, Tensor], dtype: torch.dtype) -> Tensor:
    """(G,3) RGB or (G,B,3) SH coefficients from the 'color' (and 'sh_rest') parameters."""
    if "sh_rest" not in params:
        return params["color"].to(dtype)
    return torch.cat([params["color"][:, None], params["sh_rest"]], dim=1).to(dtype)
