"""Options of the CloDS pipeline (`task_config.clods.*`), loaded into one typed dataclass."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal

from clods_bench.benchmark.core.config import RunConfig
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

Variant = Literal["scratch", "finetune"]
InitNoise = Literal["none", "gaussian", "translation", "scaling"]
StartGuess = Literal["previous", "velocity", "simulator"]
InitialMesh = Literal["truth", "reconstructed"]
WHERE = "task_config.clods"


DEFAULT_SIM_OVERRIDES: dict[str, Any] = {"loss": "rollout", "rollout_length": 8}
"""Stage 3's default options for learned simulators: the paper's 8-step rollout loss (eq. 8)."""


@dataclass(frozen=True)
class ClodsConfig:
    """Stage 2 (mesh extraction) settings, stage 3 overrides and the CDG row variant."""

    variant: Variant = "scratch"
    """'scratch': the simulator learns from the extracted meshes alone (CloDS*, CloDS**); 'finetune': it is
    first trained on the meshes of the first half (MGN*) and then fine-tuned on the videos of the second half (CloDS)."""
    init_noise: InitNoise = "none"
    """Initial mesh given to stages 1-2: the ground truth ('none', as in the paper's experiments) or it with one of
    the paper's robustness noises (appendix table 'CDR under different noise conditions')."""
    initial_mesh: InitialMesh = "truth"
    """'truth': stages 1-2 start from the true frame-0 mesh (with `init_noise`); 'reconstructed': from the mesh stage 0
    rebuilds from frame 0's images alone (`clods.stage0`: its own topology per video, the pinned edge found from the
    extracted motion, `clods.reconstructed`)."""
    stage0: dict[str, Any] = field(default_factory=dict)
    """initial_mesh=reconstructed: options of stage 0 (`Stage0Config` fields, as `task_config.initial_mesh`)."""
    gaussian_variance: float = 0.001
    """'gaussian': variance (m^2) of the zero-mean noise added to every node (paper: 0.001)."""
    translation_variance: float = 0.001
    """'translation': variance (m^2) of the one Gaussian offset moving the whole mesh."""
    translation_axes: str = "xyz"
    """'translation': the axes the offset acts along (paper: X, Y and Z separately, errors averaged)."""
    scale_range: tuple[float, float] = (0.95, 1.05)
    """'scaling': the mesh is scaled about its centroid by a factor drawn uniformly from this range."""
    gamma: float = 0.001
    """Weight of the edge-length loss L_edge (eq. 6); 0 switches it off (ablation 'w/o L_edge')."""
    iterations: int = 40
    """Iteration cap of the per-frame offset optimisation."""
    min_iterations: int = 10
    """Iterations always run before the convergence test."""
    rel_tolerance: float = 1e-3
    """Converged when the loss has not dropped below (1 - rel_tolerance) times its best for `patience` iterations."""
    patience: int = 6
    """See `rel_tolerance`."""
    stop_requires_progress: bool = False
    """If true, the convergence test cannot end a frame before an iteration has beaten the start guess's loss: when
    Adam's first steps (about `learning_rate` on every coordinate) overshoot, the default test stops at
    `min_iterations` and keeps the unfitted start guess, and on fast motion the next frame's velocity start then
    compounds the miss (README "The CloDS pipeline", the paragraph on fast motion). False keeps the rule the committed
    tables were made with."""
    learning_rate: float = 0.003
    """Adam step size (m) of the vertex offsets; it decays exponentially to `lr_final_factor` of itself over the cap."""
    lr_final_factor: float = 0.2
    """See `learning_rate`."""
    start: StartGuess = "velocity"
    """Start of frame t+1's optimisation: the previous mesh ('previous', Algorithm S1), extrapolated by its velocity, or
    ('simulator', the Cloth-Splatting filter's predict step) the pretrained simulator's step from the two previous meshes
    (needs variant=finetune, whose first-half mesh pretraining gives that simulator)."""
    num_cameras: int | None = None
    """Training cameras used by stages 1-2 (the first ones of the training rig); None: all (ablation 'number of cameras')."""
    extraction_seed: int | None = None
    """Seed of stages 1-2 (renderer fit, initial-mesh noise); None: the run's seed. A fixed value lets every seed
    of a run reuse one cached extraction, so the seeds then repeat stage 3 only."""
    cache_dir: str | None = None
    """Where stage 1-2 results are cached; None: `<runs_dir>/clods_cache`."""
    num_threads: int | None = None
    """torch CPU threads in stages 1-2; None leaves torch's setting."""
    read_ahead: bool = True
    """Stage 2 reads frame t+1 in a background thread while it fits frame t (`clods.prefetch`): hides most of the
    CPU rasterizer's reads when frames are rendered on demand and the fit runs on a GPU. Same meshes either way."""
    smooth_window: int = 0
    """Stage 3 learns from the extracted meshes filtered in time by a Savitzky-Golay filter over this many frames (odd,
    >= 3; `clods.smooth`): stage 2's frame-to-frame noise, which the accelerations stage 3 learns amplify, is cut. 0
    (the default, and the paper) hands stage 3 the meshes as extracted. Not part of the extraction's cache key."""
    smooth_order: int = 2
    """Degree of the smoothing polynomial (1 <= smooth_order < smooth_window)."""
    sim_overrides: dict[str, Any] = field(default_factory=lambda: dict(DEFAULT_SIM_OVERRIDES))
    """Stage 3: options laid over `sim_config.<sim>` for learned simulators. The keys given are laid over the default
    (paper eq. 8: the 8-step rollout loss), so setting one key (e.g. `train_steps`) keeps that loss; `loss: one_step`
    switches it off."""

    def validate(self) -> None:
        """Raise ClodsError naming the first field out of range."""
        for name in ("iterations", "patience"):
            if getattr(self, name) < 1:
                raise ClodsError(f"must be >= 1, got {getattr(self, name)}", where=f"{WHERE}.{name}")
        if not 0 <= self.min_iterations <= self.iterations:
            raise ClodsError(f"must be in [0, iterations={self.iterations}], got {self.min_iterations}", where=f"{WHERE}.min_iterations")
        for name in ("gamma", "rel_tolerance", "gaussian_variance", "translation_variance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ClodsError(f"must be a finite number >= 0, got {value}", where=f"{WHERE}.{name}")
        for name in ("learning_rate", "lr_final_factor"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ClodsError(f"must be > 0, got {value}", where=f"{WHERE}.{name}")
        lo, hi = self.scale_range if len(self.scale_range) == 2 else (0.0, -1.0)
        if not 0 < lo <= hi:
            raise ClodsError(f"must be [low, high] with 0 < low <= high, got {list(self.scale_range)}", where=f"{WHERE}.scale_range")
        if not self.translation_axes or set(self.translation_axes) - set("xyz"):
            raise ClodsError(f"must be a non-empty combination of x, y, z, got '{self.translation_axes}'", where=f"{WHERE}.translation_axes")
        if self.num_cameras is not None and self.num_cameras < 1:
            raise ClodsError(f"must be >= 1 or null, got {self.num_cameras}", where=f"{WHERE}.num_cameras")
        if self.start == "simulator" and self.variant != "finetune":
            raise ClodsError(
                f"start=simulator predicts each frame with the pretrained simulator, which only variant=finetune trains (variant is '{self.variant}')",
                where=f"{WHERE}.start", hint="add task_config.clods.variant=finetune, or use start=velocity",
            )  # fmt: skip
        if self.initial_mesh == "reconstructed":
            if self.init_noise != "none":
                raise ClodsError("the reconstructed initial mesh takes no ground-truth noise", where=f"{WHERE}.init_noise", hint="leave it at 'none'")
            if self.start == "simulator":
                raise ClodsError("start=simulator predicts on the true mesh's topology, not the reconstructed one's", where=f"{WHERE}.start")
        if self.smooth_window != 0 and (self.smooth_window < 3 or self.smooth_window % 2 == 0):
            raise ClodsError(f"must be 0 (off) or an odd number of frames >= 3, got {self.smooth_window}", where=f"{WHERE}.smooth_window")
        if self.smooth_window and not 1 <= self.smooth_order < self.smooth_window:
            raise ClodsError(f"must be in [1, smooth_window={self.smooth_window}), got {self.smooth_order}", where=f"{WHERE}.smooth_order")
        if self.num_threads is not None and self.num_threads < 1:
            raise ClodsError(f"must be >= 1 or null, got {self.num_threads}", where=f"{WHERE}.num_threads")

    def extraction_identity(self) -> dict[str, Any]:
        """The fields that change the extracted meshes (part of the cache key); stage-3 and bookkeeping fields are left out."""
        d = dataclasses.asdict(self)
        for key in ("variant", "cache_dir", "num_threads", "read_ahead", "sim_overrides", "extraction_seed", "smooth_window", "smooth_order"):
            d.pop(key)
        d["scale_range"] = list(d["scale_range"])
        if not self.stop_requires_progress:  # keys of extractions made before the option existed stay what they were
            d.pop("stop_requires_progress")
        if self.initial_mesh == "truth":  # keys of extractions from the true mesh stay what they were
            for key in ("initial_mesh", "stage0"):
                d.pop(key)
        return d


def clods_device_options(cfg: RunConfig) -> dict[str, type]:
    """The CloDS rows' `TaskSpec.device_options`: stage 0's options (`task_config.clods.stage0`, its surfel backend)
    when the run fits a renderer from the reconstructed initial mesh; stages 1-2 follow the renderer, 3 the simulator."""
    from clods_bench.benchmark.clods.stage0 import Stage0Config

    clods = cfg.task_config.get("clods")
    reconstructed = isinstance(clods, dict) and clods.get("initial_mesh") == "reconstructed"
    return {"clods.stage0": Stage0Config} if cfg.renderer and reconstructed else {}


def clods_config(cfg: RunConfig) -> ClodsConfig:
    """The run's `task_config.clods` as a checked ClodsConfig."""
    raw = dict(cfg.task_config.get("clods", {}))
    if isinstance(raw.get("sim_overrides"), dict):  # keys given are laid over the default, not instead of it
        raw["sim_overrides"] = {**DEFAULT_SIM_OVERRIDES, **raw["sim_overrides"]}
    opts: ClodsConfig = dataclass_from_dict(ClodsConfig, raw, where=WHERE, prefix="clods.")
    opts.validate()
    return opts
