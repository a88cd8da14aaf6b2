"""The turbulent wind field against its definition, evaluated point by point with math.sin."""

from __future__ import annotations

import math

import numpy as np

from clods_bench.datasets.wind import make_wind_field


def test_wind_field_equals_its_definition():
    field = make_wind_field((6.0, 1.0, 0.0), amplitude=1.5, time_scale=0.8, rng=np.random.default_rng(2), num_modes=4)
    points = np.random.default_rng(3).uniform(-1.0, 1.0, (7, 3))
    t = 0.37
    got = field(t, points)
    assert got.shape == (7, 3)
    for n, p in enumerate(points):
        want = field.mean.copy()
        for k in range(field.omegas.shape[0]):
            phase = field.omegas[k] * t - sum(field.wavevecs[k, d] * p[d] for d in range(3)) + field.phases[k]
            want += field.amps[k] * math.sin(phase)
        np.testing.assert_allclose(got[n], want, rtol=1e-12, atol=1e-12)
    # frozen turbulence: along the mean wind every mode's wave number is its frequency over the wind speed
    along = field.mean / np.linalg.norm(field.mean)
    omega_over_speed = field.omegas / np.linalg.norm(field.mean)
    np.testing.assert_allclose(field.wavevecs @ along, omega_over_speed, rtol=1e-12)


def test_calm_field_is_the_mean():
    field = make_wind_field((2.0, 0.0, 0.0), amplitude=0.0, time_scale=1.0, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(field(1.0, np.zeros((3, 3))), np.tile([2.0, 0.0, 0.0], (3, 1)))
