"""Small products of 3-vectors written out term by term, so that generated data are the same bits on every CPU.

numpy hands `@` to BLAS, and OpenBLAS picks its kernels per CPU (Haswell, SkylakeX, Sandybridge, ...): they sum
and fuse multiply-adds in different orders, so a rotation or a dot product of the scene setup rounded differently
on an AVX-512 host than on an AVX2 one, and the cloth solver carried that into different ground truth. Elementwise
numpy arithmetic has one order everywhere; these helpers replace `@` wherever data generation needs a 3-term sum.
"""

from __future__ import annotations

import numpy as np


def dot3(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise a . v for a (..., 3) array and a 3-vector (or a (..., 3) array of the same shape): (...,)."""
    a = np.asarray(a, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    return a[..., 0] * v[..., 0] + a[..., 1] * v[..., 1] + a[..., 2] * v[..., 2]


def apply3(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """points @ m.T for a (3, 3) matrix m and (N, 3) points, summed in a fixed order: (N, 3)."""
    m = np.asarray(m, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return np.stack([dot3(p, m[r]) for r in range(3)], axis=-1)
