"""The cloth: a swallowtail banner read from the shipped OBJ, pinned along its top edge to a bar that sways."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from clods_bench.api import ClodsError, MeshCloth, mesh_cloth_from_file

BANNER_OBJ = Path(__file__).with_name("banner.obj")


@dataclass(frozen=True, eq=False)
class SwayingBanner(MeshCloth):
    """A mesh cloth whose handles (the top edge) move with the bar: start + sway * sin(2 pi t / period)."""

    kind: ClassVar[str] = "banner"
    sway: tuple[float, float, float] = (0.0, 0.08, 0.0)
    """Amplitude vector of the bar's motion, metres (along the bar, y, by default)."""
    period: float = 2.0
    """Period of the sway, seconds."""

    def handle_positions(self, t: float, start: np.ndarray) -> np.ndarray:
        """The top edge at time t: its start position moved along `sway` (0 at t = 0, so it starts where it is)."""
        if not self.period > 0:
            raise ClodsError(f"period must be positive, got {self.period}", where="banner cloth")
        return start + np.asarray(self.sway) * math.sin(2.0 * math.pi * t / self.period)


@functools.cache
def load_banner(top_tol: float = 1e-6) -> SwayingBanner:
    """The banner of `banner.obj`: nodes within `top_tol` m of the top are handles, mesh_pos from the OBJ's UVs."""
    base = mesh_cloth_from_file(BANNER_OBJ, top_tol=top_tol)
    return SwayingBanner(cells=base.cells, rest_pos=base.rest_pos, handles=base.handles, uv=base.uv)
