"""A video-predictor plugin in one module: each pixel keeps moving as it did, with a momentum gain fitted to the videos.

The gain g is the least-squares fit of d[t+1] = g d[t] over the training videos, d[t] = x[t] - x[t-1] being a
frame's change; a prediction continues the last change: x[t+k] = x[t] + (g + g^2 + ... + g^k) d[t]. g = 0 is
copy-last. Register it with one line in your package's pyproject.toml:

    [project.entry-points.clods_bench]
    momentum = "my_package.momentum_predictor"
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from clods_bench.api import ClodsError, FitContext, PluginSpec, check_video, hookimpl

CLODS_BENCH_API = "1.1"  # the plugin API this module is written for


@dataclass(frozen=True)
class MomentumConfig:
    """Options of `momentum` (`video_config.momentum.*`, or `--set`)."""

    max_gain: float = 1.0
    """The fitted gain is clipped to [0, max_gain]: 0 is copy-last, 1 constant pixel velocity."""


class MomentumPredictor:
    """Fits one scalar on the training videos, then extrapolates every pixel of every view on its own."""

    def __init__(self, cfg: MomentumConfig) -> None:
        if cfg.max_gain < 0:
            raise ClodsError(f"must be >= 0, got {cfg.max_gain}", where="video_config.momentum.max_gain")
        self.cfg = cfg
        self.gain = 0.0

    def fit(self, videos: Sequence[np.ndarray], ctx: FitContext) -> dict[str, float]:
        """Least-squares gain over every single-view video (T_i,H,W,3) in [0,1]; returns it as a statistic."""
        num = den = 0.0
        for i, video in enumerate(videos):
            v = check_video(video, where=f"momentum.fit: video {i}").astype(np.float64)
            d = np.diff(v, axis=0)  # (T-1,H,W,3) frame changes
            num += float(np.sum(d[1:] * d[:-1]))
            den += float(np.sum(d[:-1] * d[:-1]))
        self.gain = float(np.clip(num / den, 0.0, self.cfg.max_gain)) if den > 0 else 0.0
        return {"gain": self.gain}

    def predict(self, context: np.ndarray, num_frames: int, cameras: Sequence[Any] = ()) -> np.ndarray:
        """(N,num_frames,H,W,3) in [0,1] from each view's context (N,C,H,W,3); the cameras are not needed."""
        ctx = check_video(context, where="momentum.predict: context", ndim=5).astype(np.float64)
        last = ctx[:, -1]
        change = last - ctx[:, -2] if ctx.shape[1] > 1 else np.zeros_like(last)
        factors = np.cumsum(self.gain ** np.arange(1, num_frames + 1))  # g, g + g^2, ...
        out = last[:, None] + factors[None, :, None, None, None] * change[:, None]
        return np.clip(out, 0.0, 1.0).astype(np.float32)


@hookimpl
def clods_bench_video_predictors() -> list[PluginSpec]:
    """The one hook: the plugin's name, description, factory and config class."""
    return [
        PluginSpec(
            name="momentum",
            description="Example plugin: every pixel keeps its last change, scaled by a gain fitted to the videos.",
            build=lambda cfg, ctx: MomentumPredictor(cfg),
            config_cls=MomentumConfig,
        )
    ]
