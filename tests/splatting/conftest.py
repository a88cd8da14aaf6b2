"""Small scenes shared by the splatting tests."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from clods_bench.datasets.cameras import Camera, camera_rig
from clods_bench.splatting import covariances_from_quats_scales


def head_on_camera(width: int = 40, height: int = 24, f: float = 100.0) -> Camera:
    """Camera at the origin looking down +z (R = I, t = 0), principal point at the image centre."""
    K = np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
    return Camera(K, np.eye(3), np.zeros(3), width, height)


def random_scene(G: int, seed: int = 0, dtype: torch.dtype = torch.float64, sh_degree: int | None = None) -> dict:
    """G random Gaussians in a unit cube around the origin: means, covars, opacities, colors."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(G, 3, generator=g, dtype=dtype) - 0.5) * 1.2
    quats = torch.randn(G, 4, generator=g, dtype=dtype)
    scales = torch.rand(G, 3, generator=g, dtype=dtype) * 0.08 + 0.01
    colors = (
        torch.rand(G, 3, generator=g, dtype=dtype)
        if sh_degree is None
        else torch.randn(G, (sh_degree + 1) ** 2, 3, generator=g, dtype=dtype) * 0.4
    )
    return {
        "means": means,
        "covars": covariances_from_quats_scales(quats, scales),
        "opacities": torch.rand(G, generator=g, dtype=dtype) * 0.85 + 0.1,
        "colors": colors,
    }


@pytest.fixture
def rig() -> list[Camera]:
    """Three 40x28 cameras (sizes not multiples of the tile) looking at the origin from 3 units."""
    return camera_rig(3, np.zeros(3), 3.0, 40, 28)
