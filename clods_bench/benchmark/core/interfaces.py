"""The plugin interfaces, documented in one place: `Simulator`, `Renderer` and `VideoPredictor`.

They are part of the public, versioned plugin API (`clods_bench.api`): a minor version only adds to them.

Conventions (see also `clods_bench.datasets.types` and `clods_bench.datasets.cameras`):
- positions are world coordinates in metres, float32 numpy arrays at the interface;
- frame t of a trajectory is `t * dt` seconds after frame 0;
- node types follow MeshGraphNets: NORMAL=0 nodes are simulated, every other type
  (HANDLE=3, OBSTACLE=1) is kinematic: its positions are given for all frames;
- cameras are OpenCV pinhole cameras (x right, y down, z forward), world-to-camera;
- videos are float32 arrays in [0,1], channels last: (T,H,W,3) for one view,
  (N,T,H,W,3) for N views.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, Sequence, runtime_checkable

import numpy as np

from clods_bench.benchmark.core import stage_digests
from clods_bench.benchmark.core.plugin_calls import plugin_call
from clods_bench.datasets.types import HANDLE, NORMAL, OBSTACLE, Trajectory
from clods_bench.errors import ClodsError

if TYPE_CHECKING:
    from clods_bench.datasets.cameras import Camera


@dataclass(frozen=True)
class RolloutInput:
    """What a simulator gets to roll out one trajectory, and nothing more.

    `init_pos` holds the two given frames (frame 0 and frame 1: the velocity needs two);
    `kinematic_pos` holds, for every frame, the prescribed positions of non-NORMAL nodes
    and NaN at NORMAL nodes, so a simulator cannot read the answer by accident.
    """

    cells: np.ndarray  # (F,3) int32
    mesh_pos: np.ndarray  # (V,2) float32
    node_type: np.ndarray  # (V,) int32
    init_pos: np.ndarray  # (2,V,3) float32: frames 0 and 1
    kinematic_pos: np.ndarray  # (T,V,3) float32: NaN at NORMAL nodes
    dt: float

    @property
    def num_frames(self) -> int:
        """Total frames T the rollout must return (the 2 given ones included)."""
        return int(self.kinematic_pos.shape[0])

    @property
    def kinematic_mask(self) -> np.ndarray:
        """(V,) bool: nodes whose positions are prescribed."""
        return self.node_type != NORMAL

    @classmethod
    def from_trajectory(cls, traj: Trajectory, num_frames: int | None = None) -> "RolloutInput":
        """Build the input for rolling out `traj` from its first two frames for `num_frames` frames."""
        frames = traj.num_steps if num_frames is None else num_frames
        if frames < 2 or frames > traj.num_steps:
            raise ClodsError(f"rollout needs 2..{traj.num_steps} frames, got {frames}", where="rollout")
        kin = traj.world_pos[:frames].astype(np.float32).copy()
        kin[:, traj.node_type == NORMAL] = np.nan
        return cls(traj.cells, traj.mesh_pos, traj.node_type, traj.world_pos[:2].astype(np.float32), kin, traj.dt)


@dataclass(frozen=True)
class FitContext:
    """Where and how a simulator trains: a working directory for checkpoints, a seed, a progress flag.

    `snapshot_every` > 0 asks a learned simulator to keep its weights every that many optimiser steps (and at
    the last) as `snapshots/step_NNNNNNN.pt` in the work directory, for training curves; others ignore it.
    """

    work_dir: Path
    seed: int
    progress: bool = True
    snapshot_every: int = 0


@runtime_checkable
class Simulator(Protocol):
    """A cloth simulator: optionally trained on trajectories, then rolled out from two frames.

    `fit` receives training trajectories (mesh supervision; a video-trained pipeline passes
    meshes it extracted) and returns training statistics (floats, e.g. 'train_seconds',
    'final_loss'); non-learned simulators return {}. `rollout` returns (T,V,3) float32
    positions for all T = `inp.num_frames` frames, frames 0 and 1 equal to `inp.init_pos`
    and kinematic nodes equal to `inp.kinematic_pos`. A diverging rollout may contain
    NaN/Inf; the task detects and records it. Nothing here needs to be differentiable.
    """

    def fit(self, train: Sequence[Trajectory], ctx: FitContext) -> dict[str, float]: ...

    def rollout(self, inp: RolloutInput) -> np.ndarray: ...


@runtime_checkable
class Renderer(Protocol):
    """A mesh-driven renderer (GaMeS, SMGS, ...) or a per-frame one (3DGS).

    `fit(verts, cells, mesh_pos, images, cameras)` builds the representation from one or
    more frames: verts (B,V,3) float32 world positions, images (B,N,H,W,3) float32 in [0,1]
    seen by the N `cameras`; returns statistics. `render(verts, cameras)` takes a torch
    tensor (V,3) (world positions of the same mesh) and returns a torch tensor (N,H,W,3) in
    [0,1]; for mesh-driven renderers it is differentiable with respect to `verts` (used by
    mesh extraction). Cameras follow `clods_bench.datasets.cameras` (OpenCV convention).
    """

    def fit(self, verts: Any, cells: np.ndarray, mesh_pos: np.ndarray, images: Any, cameras: Sequence["Camera"]) -> dict[str, float]: ...

    def render(self, verts: Any, cameras: Sequence["Camera"]) -> Any: ...


class ContractError(ClodsError):
    """A plugin's output broke its interface's contract (non-numeric output, a wrong shape; for a rollout, given
    frames or kinematic nodes changed): a plugin bug, never a divergence."""


NODE_TYPE_NAMES = {NORMAL: "NORMAL", OBSTACLE: "OBSTACLE", HANDLE: "HANDLE"}
CONTRACT_ULPS = 4
"""Tolerance of the given positions a rollout must return: this many float32 ulps of the largest given coordinate
(both sides cast to float32 first). Returning the float32 input through float64 arithmetic is exact; the ulps
leave room for a simulator that re-derives them in another precision, and nothing more."""


def check_rollout(out: Any, inp: RolloutInput, sim_name: str) -> np.ndarray:
    """Check a simulator's rollout against the contract; return it as float32 (NaN/Inf allowed from frame 2 on:
    divergence is data).

    The output must be numeric, of shape (T,V,3), and return unchanged (within `CONTRACT_ULPS`) the two given frames
    and every finite position of a kinematic node (NaN/Inf from frame 2 on is a divergence, at any node); a violation
    is one `ContractError` naming the plugin, the first node and frame that differ."""
    where = f"simulator '{sim_name}'"
    arr = numeric_array(out, "rollout", "a (T,V,3) float32 array of positions", where)
    expected = (inp.num_frames, inp.node_type.shape[0], 3)
    if arr.shape != expected:
        raise ContractError(f"rollout returned shape {arr.shape}, expected {expected}", where=where)
    out = arr.astype(np.float32, copy=False)
    _check_given_positions(out, inp, where)
    stage_digests.record("rollout", out)
    return out


def numeric_array(out: Any, call: str, expected: str, where: str) -> np.ndarray:
    """`out` as a numpy array of integers or floats; anything else (None, objects, strings, booleans) is a
    `ContractError` saying what `call` returned instead of `expected`, before numpy can warn or cast."""
    arr = None
    if isinstance(out, np.ndarray):
        arr = out
    elif isinstance(out, (list, tuple)) or hasattr(out, "__array__"):
        try:
            arr = np.asarray(out)
        except (ValueError, TypeError):
            arr = None
    if arr is None or arr.dtype.kind not in "iuf":
        what = type(out).__name__ if arr is None else f"an array of dtype {arr.dtype}"
        raise ContractError(f"{call} returned {what}, expected {expected}", where=where)
    return arr


def _check_given_positions(out: np.ndarray, inp: RolloutInput, where: str) -> None:
    """Raise ContractError at the first frame 0/1 node, or finite kinematic node of a later frame, that differs
    from the given position by more than `CONTRACT_ULPS` ulps of the largest given coordinate."""
    given = np.asarray(inp.init_pos, np.float32)
    kinematic = inp.kinematic_mask
    kin_given = np.asarray(inp.kinematic_pos, np.float32)[:, kinematic]
    finite = [a[np.isfinite(a)] for a in (given, kin_given)]
    scale = max([float(np.abs(a).max()) for a in finite if a.size] + [1.0])
    tol = CONTRACT_ULPS * float(np.spacing(np.float32(scale)))
    checks = ((True, out[:2], given, np.arange(given.shape[1]), 0), (False, out[2:, kinematic], kin_given[2:], np.flatnonzero(kinematic), 2))
    for frames_given, got, want, nodes, first in checks:
        with np.errstate(invalid="ignore"):
            bad = ~((np.abs(got - want) <= tol) | (np.isnan(want) & np.isnan(got)))
        if not frames_given:
            bad &= np.isfinite(got)  # NaN/Inf after frame 1 is a divergence (data), at any node
        if not bad.any():
            continue
        t, j = (int(i) for i in np.argwhere(bad.any(axis=2))[0])
        code = int(inp.node_type[nodes[j]])
        node = f"node {int(nodes[j])} ({NODE_TYPE_NAMES.get(code, f'node type {code}')})"
        values = f"{_xyz(got[t, j])}, given {_xyz(want[t, j])} (tolerance {tol:.3g} m)"
        what = f"changed given frame {first + t}: {node} is {values}" if frames_given else f"moved kinematic {node} at frame {first + t}: {values}"
        raise ContractError(f"rollout {what}", where=where, hint="return frames 0 and 1 and every non-NORMAL node's kinematic_pos unchanged")


def _xyz(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{float(v):.7g}" for v in p) + ")"


def rollout_checked(sim: Simulator, inp: RolloutInput, sim_name: str) -> np.ndarray:
    """`sim.rollout(inp)` as a named plugin call (`plugin_call`), its output checked by `check_rollout`."""
    with plugin_call("simulator", sim_name, "rollout", sim):
        out = sim.rollout(inp)
    return check_rollout(out, inp, sim_name)


@runtime_checkable
class VideoPredictor(Protocol):
    """A pixel-space video predictor (copy-last-frame, SimVP, ...): the DVC forward task's baselines.

    `fit(videos, ctx)` trains on single-view videos, each a float32 (T_i,H,W,3) array in [0,1]
    (lengths may differ, sizes may not), and returns statistics (floats; {} for untrained
    predictors). `predict(context, num_frames, cameras)` gets N views' observed frames,
    context (N,C,H,W,3) float32 in [0,1] (frame C-1 is the last observed one), and returns
    the next `num_frames` frames of every view, (N,num_frames,H,W,3) in [0,1]. `cameras`
    are the N views' cameras (OpenCV convention); a purely 2D predictor may ignore them.
    Each view is predicted from its own frames only.
    """

    def fit(self, videos: Sequence[np.ndarray], ctx: FitContext) -> dict[str, float]: ...

    def predict(self, context: np.ndarray, num_frames: int, cameras: Sequence["Camera"]) -> np.ndarray: ...


def check_video(arr: Any, where: str, ndim: int = 4) -> np.ndarray:
    """`arr` as float32 video(s): (T,H,W,3) for ndim=4, (N,T,H,W,3) for ndim=5, finite; ClodsError naming `where` otherwise."""
    out = np.asarray(arr)
    layout = "(T,H,W,3)" if ndim == 4 else "(N,T,H,W,3)"
    if out.ndim != ndim or out.shape[-1] != 3 or min(out.shape) < 1:
        raise ClodsError(f"expected a video of shape {layout}, got shape {out.shape}", where=where)
    out = out.astype(np.float32, copy=False)
    if not np.isfinite(out).all():
        raise ClodsError("video has NaN/Inf values", where=where)
    return out


def check_prediction(out: Any, context: np.ndarray, num_frames: int, predictor: str) -> np.ndarray:
    """Check a predictor's output against its (N,C,H,W,3) context: shape (N,num_frames,H,W,3), finite; clipped to [0,1]."""
    n, _, h, w, _ = context.shape
    arr = numeric_array(out, "predict", "an (N,T,H,W,3) float32 array of frames", f"video predictor '{predictor}'")
    expected = (n, num_frames, h, w, 3)
    if arr.shape != expected:
        raise ClodsError(f"predict returned shape {arr.shape}, expected {expected}", where=f"video predictor '{predictor}'")
    if not np.isfinite(arr).all():
        raise ClodsError("predict returned NaN/Inf pixels", where=f"video predictor '{predictor}'")
    frames = np.clip(arr.astype(np.float32, copy=False), 0.0, 1.0)
    stage_digests.record("rollout", frames)
    return frames
