"""Initial-mesh robustness noises: the paper's stated statistics, checked on large samples."""

from __future__ import annotations

import numpy as np
import pytest

from clods_bench.benchmark.clods.config import ClodsConfig
from clods_bench.benchmark.clods.noise import initial_mesh
from clods_bench.errors import ClodsError

MESH = np.random.default_rng(0).uniform(-1, 1, (20000, 3)).astype(np.float32)


def test_ground_truth_is_returned_unchanged():
    np.testing.assert_array_equal(initial_mesh(MESH, ClodsConfig(), 0, 0), MESH)


def test_gaussian_noise_has_variance_0_001_per_coordinate():
    noise = initial_mesh(MESH, ClodsConfig(init_noise="gaussian"), 0, 3).astype(np.float64) - MESH
    assert abs(noise.mean()) < 3 * np.sqrt(0.001 / noise.size) * 3
    assert noise.var() == pytest.approx(0.001, rel=0.03)  # 60000 samples: std error of the variance ~0.6%
    assert np.abs(np.corrcoef(noise[:, 0], noise[:, 1])[0, 1]) < 0.03


def test_translation_moves_the_whole_mesh_by_one_gaussian_offset():
    small = MESH[:50]
    offsets = np.stack([(initial_mesh(small, ClodsConfig(init_noise="translation", translation_axes="xz"), s, i) - small).astype(np.float64)
                        for s in range(40) for i in range(100)])  # fmt: skip
    np.testing.assert_allclose(offsets, np.broadcast_to(offsets[:, :1], offsets.shape), atol=1e-6)  # rigid: same offset on every node
    per_draw = offsets[:, 0]
    assert np.all(per_draw[:, 1] == 0.0)  # y left alone
    assert per_draw[:, 0].var() == pytest.approx(0.001, rel=0.1) and per_draw[:, 2].var() == pytest.approx(0.001, rel=0.1)


def test_scaling_is_about_the_centroid_within_the_range():
    small = MESH[:50].astype(np.float64)
    centre = small.mean(axis=0)
    factors = []
    for i in range(2000):
        noisy = initial_mesh(small, ClodsConfig(init_noise="scaling"), 1, i).astype(np.float64)
        k = np.linalg.norm(noisy - centre, axis=1) / np.linalg.norm(small - centre, axis=1)
        np.testing.assert_allclose(k, k[0], rtol=1e-5)  # one factor for the whole mesh
        np.testing.assert_allclose(noisy.mean(axis=0), centre, atol=1e-5)
        factors.append(k[0])
    f = np.asarray(factors)
    assert f.min() >= 0.95 - 1e-6 and f.max() <= 1.05 + 1e-6
    assert f.mean() == pytest.approx(1.0, abs=0.002) and f.var() == pytest.approx(0.1**2 / 12, rel=0.1)  # uniform on [0.95, 1.05]


def test_same_seed_same_mesh_and_bad_range_rejected():
    cfg = ClodsConfig(init_noise="gaussian")
    np.testing.assert_array_equal(initial_mesh(MESH, cfg, 2, 7), initial_mesh(MESH, cfg, 2, 7))
    assert not np.array_equal(initial_mesh(MESH, cfg, 2, 7), initial_mesh(MESH, cfg, 2, 8))
    with pytest.raises(ClodsError, match="scale_range"):
        ClodsConfig(scale_range=(1.1, 0.9)).validate()
