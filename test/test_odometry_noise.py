"""The odometry noise models shared by ``bench egomotion`` and ``import-carmen``."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.core.geometry import wrap_angle
from laser_tracker.tools.odometry_noise import (MODELS, POOR_SIGMA, chain, increments_of,
                                                noisy_increments, noisy_odometry)

DEG = math.pi / 180.0


def _walk(n=4000, step=0.1, turn=2 * DEG, seed=0):
    rng = np.random.default_rng(seed)
    inc = np.column_stack((rng.uniform(0.5, 1.5, n) * step, rng.normal(0.0, 0.1 * step, n),
                           rng.normal(0.0, turn, n)))
    return inc


def test_poor_model_is_white_noise_per_step():
    ref = _walk()
    err = noisy_increments(ref, 'poor', seed=1) - ref
    np.testing.assert_allclose(err.std(axis=0), POOR_SIGMA, rtol=0.05)
    assert abs(np.corrcoef(err[:-1, 0], err[1:, 0])[0, 1]) < 0.05


def test_realistic_model_grows_with_distance_and_drifts_slowly():
    ref = _walk()
    err = noisy_increments(ref, 'realistic', seed=1) - ref
    d = np.hypot(ref[:, 0], ref[:, 1])
    # per metre: 2 % white on x and y plus a 1 % scale bias; 1 deg/m white plus bias terms
    rel = err[:, 1] / d
    assert 0.015 < rel.std() < 0.03
    heading_per_m = np.degrees(err[:, 2] / d)
    assert 0.8 < heading_per_m.std() < 2.0
    # the bias drifts slowly: heading errors of neighbouring steps are correlated
    bias = err[:, 2] - np.mean(err[:, 2])
    assert np.corrcoef(bias[:-1], bias[1:])[0, 1] > 0.1
    # standing still: no odometry motion at all
    still = np.zeros((10, 3))
    np.testing.assert_array_equal(noisy_increments(still, 'realistic', seed=3), still)


def test_same_seed_same_noise_and_none_is_the_reference():
    ref = _walk(200)
    for model in MODELS:
        a = noisy_increments(ref, model, seed=7)
        np.testing.assert_array_equal(a, noisy_increments(ref, model, seed=7))
    np.testing.assert_array_equal(noisy_increments(ref, 'none'), ref)
    assert not np.allclose(noisy_increments(ref, 'poor', seed=7),
                           noisy_increments(ref, 'poor', seed=8))
    with pytest.raises(ValueError, match='unknown odometry noise model'):
        noisy_increments(ref, 'awful')


def test_noisy_odometry_chains_from_the_reference_start():
    ref_poses = chain((1.0, -2.0, 0.3), _walk(300))
    odo = noisy_odometry(ref_poses, 'poor', seed=2)
    assert odo.shape == ref_poses.shape
    np.testing.assert_allclose(odo[0], ref_poses[0])
    exact = noisy_odometry(ref_poses, 'none')
    np.testing.assert_allclose(exact[:, :2], ref_poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(wrap_angle(exact[:, 2] - ref_poses[:, 2]), 0.0, atol=1e-9)
    np.testing.assert_allclose(increments_of(exact), increments_of(ref_poses), atol=1e-9)
