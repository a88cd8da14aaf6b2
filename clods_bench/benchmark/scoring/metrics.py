"""Rollout metrics: per-step RMSE as in MeshGraphNets and the paper's Table 2 columns."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

GROUPS = ("viewed", "unviewed")
PHASES = ("interp", "extrap")
STATS = ("d_avg", "d_end", "avg")


def rmse_per_step(pred: np.ndarray, gt: np.ndarray, nodes: np.ndarray | None = None) -> np.ndarray:
    """(T,) RMSE per frame: sqrt of the mean over nodes and coordinates of the squared error.

    `nodes` restricts the mean to those node indices (the cloth's, when a scene stores obstacle nodes)."""
    if pred.shape != gt.shape:
        raise ValueError(f"prediction shape {pred.shape} != ground truth shape {gt.shape}")
    if nodes is not None:
        pred, gt = pred[:, nodes], gt[:, nodes]
    diff = pred.astype(np.float64) - gt.astype(np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        return np.sqrt(np.mean(diff * diff, axis=(1, 2)))


def divergence_step(pred: np.ndarray) -> int | None:
    """First frame index holding a NaN/Inf position, or None if the rollout is finite."""
    bad = ~np.isfinite(pred).all(axis=(1, 2))
    return int(np.argmax(bad)) if bad.any() else None


def diverged_max(values: np.ndarray | Sequence[float]) -> float:
    """The largest of `values` (per-frame edge strains of a rollout), inf when any is NaN/Inf: a rollout that diverged
    has no largest strain, and the one of its finite frames would pass a blown-up rollout for a calm one. NaN for
    no values."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return float("nan")
    return float(v.max()) if np.isfinite(v).all() else float("inf")


def recorded_max(value: float) -> float:
    """A largest strain as a run records it: a diverged one (inf, from `diverged_max`) becomes NaN, which JSON
    stores (as null) and seeds average quietly, and which the tables print as diverged next to the record's
    divergence step."""
    return float(value) if np.isfinite(value) else float("nan")


def phase_frames(interp_steps: int, num_steps: int) -> dict[str, np.ndarray]:
    """Frames scored in each phase: interpolation 2..interp_steps (frames 0, 1 are given), extrapolation after it."""
    return {"interp": np.arange(2, interp_steps + 1), "extrap": np.arange(interp_steps + 1, num_steps)}


def cdg_columns(curves: Mapping[str, Sequence[np.ndarray]], interp_steps: int, num_steps: int) -> dict[str, float]:
    """The paper's Table 2 columns from per-trajectory RMSE curves, keyed 'group/phase/stat'.

    d_avg: mean RMSE over the phase's frames; d_end: RMSE at its last frame (t = interp_steps,
    resp. t = num_steps - 1); avg: the mean of the two (the paper's 'Avg.'). Each value is the
    mean over the group's trajectories. A diverged rollout gives NaN.
    """
    frames = phase_frames(interp_steps, num_steps)
    out: dict[str, float] = {}
    for group, group_curves in curves.items():
        if not group_curves:
            continue
        stacked = np.stack([np.asarray(c, dtype=np.float64) for c in group_curves])  # (N,T)
        for phase, idx in frames.items():
            if idx.size == 0:
                continue
            d_avg = float(np.mean(stacked[:, idx]))
            d_end = float(np.mean(stacked[:, idx[-1]]))
            out[f"{group}/{phase}/d_avg"] = d_avg
            out[f"{group}/{phase}/d_end"] = d_end
            out[f"{group}/{phase}/avg"] = 0.5 * (d_avg + d_end)
    return out


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and (population) standard deviation, NaN-propagating."""
    arr = np.asarray(values, dtype=np.float64)
    return float(np.mean(arr)), float(np.std(arr))
