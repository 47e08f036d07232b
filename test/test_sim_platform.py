"""Simulated odometry: its error statistics are those its parameters say."""
import math

import numpy as np
import pytest

from laser_tracker.core.geometry import interpolate_poses, wrap_angle
from laser_tracker.tools.sim.agents import PathBuilder
from laser_tracker.tools.sim.platform import OdometryConfig, simulate_odometry

QUIET = dict(scale_error=0.0, rotation_scale_error=0.0, heading_drift=0.0,
             translation_noise=0.0, rotation_noise=0.0, latency=0.0, latency_jitter=0.0)


def _straight(length=200.0, speed=0.5):
    return PathBuilder(0.0, 1.0, -2.0, 0.3).go(1.0 + length * math.cos(0.3),
                                                -2.0 + length * math.sin(0.3), speed).build()


def _run(trajectory, seed=0, **errors):
    config = OdometryConfig(**{**QUIET, **errors})
    return simulate_odometry(trajectory, trajectory.t_end, config, np.random.default_rng(seed))


def _body_increments(poses):
    d = np.diff(poses, axis=0)
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1],
                            wrap_angle(d[:, 2])])


def test_perfect_odometry_follows_the_true_path_from_the_true_start():
    tr = _straight(20.0)
    odo = _run(tr)
    assert np.allclose(odo.poses, tr.pose(odo.true_times), atol=2e-6)
    assert np.allclose(odo.stamps, odo.true_times)
    assert odo.twists[10] == pytest.approx([0.5, 0.0, 0.0], abs=1e-5)


def test_scale_error_is_recovered_from_the_distance_travelled():
    tr = _straight()
    odo = _run(tr, scale_error=0.03, translation_noise=0.005)
    measured = np.sum(np.hypot(*np.diff(odo.poses[:, :2], axis=0).T))
    assert measured / 200.0 - 1.0 == pytest.approx(0.03, abs=0.002)


def test_heading_drift_is_recovered_per_metre():
    tr = _straight()
    odo = _run(tr, heading_drift=0.004, rotation_noise=0.005)
    err = np.unwrap(odo.poses[:, 2]) - 0.3
    distance = 0.5 * (odo.true_times - odo.true_times[0])
    slope = np.polyfit(distance, err, 1)[0]
    assert slope == pytest.approx(0.004, rel=0.05)
    assert abs(wrap_angle(odo.poses[-1, 2] - 0.3)) == pytest.approx(0.8, rel=0.05)


def test_translation_noise_grows_with_the_square_root_of_distance():
    tr = _straight()
    odo = _run(tr, translation_noise=0.01)
    true = _body_increments(tr.pose(odo.true_times))
    meas = _body_increments(odo.poses)
    ds = np.hypot(true[:, 0], true[:, 1])
    z = (meas[:, :2] - true[:, :2]) / np.sqrt(ds)[:, None]   # N(0, sigma^2) per axis
    assert z.std() == pytest.approx(0.01, rel=0.05)
    assert abs(z.mean()) < 0.001


def test_rotation_scale_error_and_noise_in_place():
    tr = PathBuilder(0.0, 0.0, 0.0, 0.0).turn_by(60 * 2 * math.pi, math.radians(30)).build()
    odo = _run(tr, rotation_scale_error=-0.02, rotation_noise=0.01)
    turned = np.unwrap(odo.poses[:, 2])[-1] - odo.poses[0, 2]
    assert turned / (60 * 2 * math.pi) - 1.0 == pytest.approx(-0.02, abs=0.001)
    meas = _body_increments(odo.poses)[:, 2]
    true = _body_increments(tr.pose(odo.true_times))[:, 2]
    z = (meas - 0.98 * true) / np.sqrt(np.abs(true))
    assert z.std() == pytest.approx(0.01, rel=0.05)
    assert np.allclose(odo.poses[:, :2], 0.0)               # no translation while turning


def test_standing_still_gives_constant_odometry():
    tr = PathBuilder(0.0, 2.0, 3.0, 1.0).wait(30.0).build()
    defaults = {name: getattr(OdometryConfig(), name) for name in QUIET}   # every error on
    odo = _run(tr, seed=3, **defaults)
    assert np.all(odo.poses == odo.poses[0])
    assert odo.poses[0] == pytest.approx([2.0, 3.0, 1.0])


def test_latency_is_recovered_by_aligning_odometry_with_the_true_motion():
    """The stamp says t + latency (+ jitter) for the pose true at t: find the delay that best
    aligns the stamped poses with the truth, as a consumer would, on a stop-and-go path."""
    b = PathBuilder(0.0, 0.0, 0.0, 0.0)
    for k in range(20):
        b.go(b.pose[0] + 2.0, 0.0, 0.4 + 0.3 * (k % 3)).wait(0.7 + 0.2 * (k % 2))
    tr = b.build()
    odo = _run(tr, latency=0.08, latency_jitter=0.01, translation_noise=0.002)
    delays = np.arange(0.0, 0.2, 0.001)
    # Compare displacements over 0.2 s (noise does not accumulate in them).
    moved = odo.poses[10:, :2] - odo.poses[:-10, :2]
    cost = [np.mean(np.sum((tr.position(odo.stamps[10:] - d) - tr.position(odo.stamps[:-10] - d)
                            - moved) ** 2, axis=-1)) for d in delays]
    best = delays[np.argmin(cost)]
    assert best == pytest.approx(0.08 + 0.005, abs=0.002)             # latency + mean jitter
    assert np.all(np.diff(odo.stamps) > 0)                             # still in order
    # The same poses stamped honestly would need no shift at all.
    honest = interpolate_poses(odo.true_times, odo.poses, odo.true_times)
    assert np.allclose(honest[:, :2], tr.position(odo.true_times), atol=0.05)


def test_jitter_must_stay_below_the_period():
    with pytest.raises(ValueError, match='jitter'):
        _run(_straight(1.0), latency_jitter=0.03)
