"""The paper's initial-mesh robustness noises (appendix, table 'CDR under different noise conditions').

'gaussian': zero-mean noise of variance `gaussian_variance` on every node; 'translation': one
Gaussian offset of variance `translation_variance` moving the whole mesh along the chosen axes;
'scaling': the mesh scaled about its centroid by a factor uniform in `scale_range`.
"""

from __future__ import annotations

import numpy as np

from clods_bench.benchmark.clods.config import ClodsConfig

AXES = {"x": 0, "y": 1, "z": 2}


def initial_mesh(gt_first: np.ndarray, cfg: ClodsConfig, seed: int, trajectory: int) -> np.ndarray:
    """(V,3) float32 initial mesh for stages 1-2: the ground-truth frame 0 or it with `cfg.init_noise` applied.

    The noise depends only on (`seed`, `trajectory`), so a resumed run draws the same mesh.
    """
    x = np.asarray(gt_first, dtype=np.float64)
    rng = np.random.default_rng([int(seed), int(trajectory), 0xC10D5])
    if cfg.init_noise == "gaussian":
        x = x + rng.normal(0.0, np.sqrt(cfg.gaussian_variance), size=x.shape)
    elif cfg.init_noise == "translation":
        offset = np.zeros(3)
        for axis in sorted(set(cfg.translation_axes)):
            offset[AXES[axis]] = rng.normal(0.0, np.sqrt(cfg.translation_variance))
        x = x + offset
    elif cfg.init_noise == "scaling":
        lo, hi = cfg.scale_range
        centre = x.mean(axis=0)
        x = centre + rng.uniform(lo, hi) * (x - centre)
    return x.astype(np.float32)
