"""The paper's train/test splits (appendix 'Dataset details'), scaled to a preset's sizes.

Index conventions, stated once (0-based, as stored in a DatasetStore):
- trajectories 0..num_train-1 are training trajectories (paper: 1-100);
- trajectories num_train..num_train+num_test-1 are test trajectories (paper: the 20 after them);
- frame 0 is the initial state; frames 1..interp_steps are interpolation, frames
  interp_steps+1..num_steps-1 extrapolation (paper: 300 training steps, then 100 to predict);
- of the num_views_train + num_views_test cameras of the rig, the num_views_test held-out ones are spread
  evenly through it (every N/k-th, ending on the last: 30 cameras, 5 held out -> 5, 11, 17, 23, 29), as
  novel-view benchmarks hold out every k-th view; the others are used for fitting. A held-out camera thus
  has training neighbours on both sides instead of lying in an arc that no training camera sees.
"""

from __future__ import annotations

from dataclasses import dataclass

from clods_bench.errors import ClodsError


def spread(n: int, k: int) -> list[int]:
    """k of the positions 0..n-1 spread evenly, every n/k-th, ending on the last (spread(6, 2) == [2, 5])."""
    if not 0 <= k <= n:
        raise ClodsError(f"cannot pick {k} of {n}", where="splits.spread")
    return [round((i + 1) * n / k) - 1 for i in range(k)]


TRAIN = "train"
TEST = "test"
SPLITS = (TRAIN, TEST)


@dataclass(frozen=True)
class SplitSpec:
    """Sizes of the splits; every derived index set is computed from these six numbers."""

    num_train: int = 100
    """Training trajectories (paper: 100, the first 100 of the FLAGSIMPLE training set)."""
    num_test: int = 20
    """Test trajectories, the 'unviewed' group (paper: 20, FLAGSIMPLE training trajectories 101-120)."""
    num_steps: int = 400
    """Frames T per trajectory including frame 0 (paper: 400 steps; FLAGSIMPLE stores 401, we use the first num_steps)."""
    interp_steps: int = 300
    """Last interpolation frame: frames 1..interp_steps are interpolation, the rest extrapolation (paper: 300)."""
    num_views_train: int = 25
    """Cameras whose images may be used for fitting (the rig's cameras that are not held out)."""
    num_views_test: int = 5
    """Held-out cameras for novel-view synthesis (spread evenly through the rig), never used for fitting."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self, where: str = "splits") -> None:
        """Raise ClodsError naming the field when the sizes cannot form the paper's protocol."""
        for name in ("num_train", "num_test", "num_steps", "interp_steps", "num_views_train", "num_views_test"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ClodsError(f"must be an integer, got {value!r}", where=f"{where}.{name}")
        if self.num_train < 2:
            raise ClodsError(f"need at least 2 training trajectories (two halves), got {self.num_train}", where=f"{where}.num_train")
        if self.num_test < 1:
            raise ClodsError(f"need at least 1 test trajectory, got {self.num_test}", where=f"{where}.num_test")
        if self.num_steps < 3:
            raise ClodsError(f"need at least 3 frames (initial, interpolation, extrapolation), got {self.num_steps}", where=f"{where}.num_steps")
        if not 1 <= self.interp_steps < self.num_steps - 1:
            raise ClodsError(
                f"must be in [1, num_steps-2] = [1, {self.num_steps - 2}] so both interpolation and extrapolation frames exist, got {self.interp_steps}",
                where=f"{where}.interp_steps",
            )
        if self.num_views_train < 1:
            raise ClodsError(f"need at least 1 training camera, got {self.num_views_train}", where=f"{where}.num_views_train")
        if self.num_views_test < 0:
            raise ClodsError(f"must be >= 0, got {self.num_views_test}", where=f"{where}.num_views_test")

    # ------------------------------------------------------------ trajectories

    @property
    def num_trajectories(self) -> int:
        """Train plus test trajectories: how many a dataset for these splits holds."""
        return self.num_train + self.num_test

    @property
    def train(self) -> range:
        """All training trajectories (paper 1-100): MGN / CloDS** mesh or video training."""
        return range(0, self.num_train)

    @property
    def first_half(self) -> range:
        """First half of the training trajectories (paper 1-50): MGN* / CloDS* training, CloDS mesh pre-training."""
        return range(0, self.num_train // 2)

    @property
    def second_half(self) -> range:
        """Second half of the training trajectories (paper 51-100): CloDS video training."""
        return range(self.num_train // 2, self.num_train)

    @property
    def viewed(self) -> range:
        """The 'viewed' test group: the second half of the training trajectories (paper 51-100).

        The main-text table caption says trajectories 1-50, the appendix 'Dataset details'
        says 51-100; we follow the appendix because it states the full protocol (models see
        the initial states of 51-100 in training, except MGN*, which trains on 1-50 only).
        """
        return self.second_half

    @property
    def unviewed(self) -> range:
        """The 'unviewed' test group: every test trajectory (cloth states never seen in training)."""
        return range(self.num_train, self.num_train + self.num_test)

    def split_of(self, index: int) -> str:
        """'train' or 'test' for a trajectory index; ClodsError if it is outside both."""
        if 0 <= index < self.num_train:
            return TRAIN
        if self.num_train <= index < self.num_trajectories:
            return TEST
        raise ClodsError(f"trajectory index {index} outside [0, {self.num_trajectories})", where="splits")

    def train_mesh_subsets(self) -> dict[str, range]:
        """Training trajectories of the mesh-supervised rows of the CDG table: MGN (all) and MGN* (first half)."""
        return {"MGN": self.train, "MGN*": self.first_half}

    # ------------------------------------------------------------------ frames

    @property
    def interp_frames(self) -> range:
        """Interpolation frames 1..interp_steps (frame 0 is the given initial state)."""
        return range(1, self.interp_steps + 1)

    @property
    def extrap_frames(self) -> range:
        """Extrapolation frames interp_steps+1..num_steps-1."""
        return range(self.interp_steps + 1, self.num_steps)

    @property
    def train_frames(self) -> range:
        """Frames a model may fit on: 0..interp_steps (slice(0, interp_steps + 1))."""
        return range(0, self.interp_steps + 1)

    # ----------------------------------------------------------------- cameras

    @property
    def train_views(self) -> tuple[int, ...]:
        """Camera indices used for fitting: every camera of the rig that is not held out, in rig order."""
        held = set(self.test_views)
        return tuple(v for v in range(self.num_views_train + self.num_views_test) if v not in held)

    @property
    def test_views(self) -> tuple[int, ...]:
        """Held-out camera indices for novel-view synthesis, spread evenly through the rig."""
        return tuple(spread(self.num_views_train + self.num_views_test, self.num_views_test))

    # ----------------------------------------------------------------- scaling

    def scaled(self, factor: float) -> "SplitSpec":
        """Trajectory counts and frame numbers scaled by `factor` (cameras unchanged), keeping the protocol valid."""
        if not factor > 0:
            raise ClodsError(f"scale factor must be positive, got {factor}", where="splits.scaled")
        num_steps = max(3, round(self.num_steps * factor))
        interp = min(max(1, round(self.interp_steps * factor)), num_steps - 2)
        return SplitSpec(
            num_train=max(2, round(self.num_train * factor)),
            num_test=max(1, round(self.num_test * factor)),
            num_steps=num_steps,
            interp_steps=interp,
            num_views_train=self.num_views_train,
            num_views_test=self.num_views_test,
        )

    @staticmethod
    def from_data_config(data: object) -> "SplitSpec":
        """Splits from a DataConfig-like object (num_train, num_test, num_steps, interp_steps, num_cameras, num_views_test)."""
        return SplitSpec(
            num_train=getattr(data, "num_train"),
            num_test=getattr(data, "num_test"),
            num_steps=getattr(data, "num_steps"),
            interp_steps=getattr(data, "interp_steps"),
            num_views_train=getattr(data, "num_cameras") - getattr(data, "num_views_test"),
            num_views_test=getattr(data, "num_views_test"),
        )
