"""The ground-truth renderer's light: one directional light with Lambertian shading and optional cast shadows.

Shading of a visible surface point with unit (smooth) normal n and texture colour c, light direction l
(pointing from the light toward the scene):
- lit point:      c * (ambient + diffuse * |n . l|)   (two-sided: both faces of the thin cloth sheet take the
                                                       diffuse term when nothing else is between them and the light)
- shadowed point: c * ambient                         (only when `shadow_map_size` > 0)
A point is shadowed when other geometry of the frame lies between it and the light: the shadow map is the
depth image of every triangle of the frame seen by an orthographic camera looking along l (see
`shadow_kernels`), offset away from the light by `shadow_bias` + `shadow_slope_bias` texels of each
triangle's depth slope so that a surface never shadows itself (no shadow acne).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import numpy as np

from clods_bench.errors import ClodsError

__all__ = ["DirectionalLight"]

MAX_SHADOW_MAP = 8192


@dataclass(frozen=True)
class DirectionalLight:
    """A distant light and its shadows; checked by `validate` (the renderer and the scene call it, naming themselves)."""

    direction: tuple[float, float, float] = field(default=(0.0, 0.0, -1.0))
    """Direction the light travels, from the light toward the scene (world frame; need not be unit length)."""
    ambient: float = 0.3
    """Shade every visible point gets, lit or shadowed (multiplies the texture colour)."""
    diffuse: float = 0.7
    """Lambertian weight: a lit point gets ambient + diffuse * |n . l|."""
    shadow_map_size: int = 0
    """Texels per side of the shadow map (the light's orthographic depth image of the frame); 0: no shadows."""
    shadow_bias: float = 0.01
    """Constant depth offset (world units, m) of the shadow map away from the light, against shadow acne."""
    shadow_slope_bias: float = 1.0
    """Extra offset per triangle: this many texels times its depth slope (|dz/du| + |dz/dv|); >= 0.5 keeps
    a flat surface free of acne whatever the angle to the light."""

    def __post_init__(self) -> None:
        try:  # hashable and comparable when well formed; `validate` reports anything else
            d = np.asarray(self.direction, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            return
        if d.shape == (3,):
            object.__setattr__(self, "direction", tuple(float(x) for x in d))

    def validate(self, where: str = "light") -> None:
        """Raise one ClodsError naming `where` and the bad field."""
        try:
            d = np.asarray(self.direction, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            d = np.full(1, np.nan)
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0.0:
            raise ClodsError(f"light.direction must be a finite non-zero 3-vector, got {self.direction!r}", where=where)
        for name in ("ambient", "diffuse", "shadow_bias", "shadow_slope_bias"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, numbers.Real) and np.isfinite(value) and value >= 0.0):
                raise ClodsError(f"light.{name} must be a finite number >= 0, got {value!r}", where=where)
        size = self.shadow_map_size
        if isinstance(size, bool) or not isinstance(size, numbers.Integral) or not (size == 0 or 4 <= size <= MAX_SHADOW_MAP):
            raise ClodsError(
                f"light.shadow_map_size must be 0 (no shadows) or an integer in [4, {MAX_SHADOW_MAP}], got {size!r}", where=where
            )

    @property
    def has_shadows(self) -> bool:
        """Whether this light casts shadows (a shadow map is rendered)."""
        return int(self.shadow_map_size) > 0

    def unit_direction(self) -> np.ndarray:
        """(3,) unit vector of `direction`."""
        d = np.asarray(self.direction, dtype=np.float64)
        return d / np.linalg.norm(d)

    def basis(self) -> np.ndarray:
        """(3,3) orthonormal rows (u, v, l): the shadow map's image axes u, v and its depth axis l = unit direction."""
        d = self.unit_direction()
        helper = np.zeros(3)
        helper[int(np.argmin(np.abs(d)))] = 1.0  # the world axis least aligned with d
        u = np.cross(d, helper)
        u /= np.linalg.norm(u)
        return np.stack([u, np.cross(d, u), d])
