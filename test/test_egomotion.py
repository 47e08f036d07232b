"""Ego-motion (odometry prior + point-to-line ICP): synthetic scans of known motion, bad
input, the adaptive prior, coasting, and the accuracy protocol on the real CARMEN logs."""
from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from laser_tracker.config import ConfigError, describe, from_dict
from laser_tracker.core.difference import pose_quality
from laser_tracker.core.egomotion import (SOURCE_CONSTANT_VELOCITY, SOURCE_ICP, SOURCE_INIT,
                                          SOURCE_NONE, SOURCE_ODOMETRY, SOURCE_PARTIAL,
                                          AdaptiveNoise, EgoMotionConfig, EgoMotionEstimator,
                                          OdometryBuffer, estimate_track)
from laser_tracker.core.geometry import between, compose
from laser_tracker.core import icp
from laser_tracker.core.icp import LocalMap, align, scan_normals
from laser_tracker.core.scan import Scan
from laser_tracker.core.self_mask import SelfMask, SelfMaskConfig
from laser_tracker.tools.bag import PoseTrack
from laser_tracker.tools.data import real_data

DATA = real_data() / 'carmen'
DEG = math.pi / 180.0
#: the tests below that inject 3-8 cm odometry errors tell the estimator its odometry is
#: that noisy (the defaults assume 1 cm + 5 % per step, a good wheel odometry)
NOISY_ODOMETRY = EgoMotionConfig(odom_sigma_xy=0.05, odom_sigma_xy_per_m=0.0,
                                 odom_sigma_theta=2 * DEG, odom_sigma_theta_per_rad=0.0)

# ------------------------------------------------------------------ synthetic worlds


def segments_of(polylines) -> np.ndarray:
    """(m, 4) segments from closed or open polylines [(x, y), ...]."""
    out = []
    for line in polylines:
        pts = np.asarray(line, dtype=float)
        out.extend(np.hstack((pts[:-1], pts[1:])))
    return np.array(out)


def box(x0, y0, x1, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]


ROOM = segments_of([
    box(-4.0, -3.0, 6.0, 4.0),                       # walls
    box(2.0, 1.0, 2.6, 1.5), box(3.5, -2.2, 4.4, -1.6),  # furniture
    [(-1.0, 4.0), (-1.0, 2.8)], [(4.5, 0.5), (6.0, 0.5)],  # wall stubs
    box(0.8, -1.0, 1.0, -0.8),                        # a pillar
])

CORRIDOR = segments_of([[(-60.0, 1.5), (60.0, 1.5)], [(-60.0, -1.5), (60.0, -1.5)]])


def cast(segments, pose, n_beams=361, fov=math.pi, max_range=8.0, sigma=0.0, rng=None,
         stamp=0.0) -> Scan:
    """A scan from ``pose`` (x, y, theta) against line segments (ray casting)."""
    a = pose[2] + np.linspace(-fov / 2.0, fov / 2.0, n_beams)
    d = np.column_stack((np.cos(a), np.sin(a)))
    p0 = segments[:, :2]
    e = segments[:, 2:] - p0
    w = p0 - np.asarray(pose[:2], dtype=float)
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
        u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / den
    hit = np.isfinite(t) & (t > 1e-6) & (u >= 0.0) & (u <= 1.0)
    r = np.where(hit, t, np.inf).min(axis=1)
    if sigma and rng is not None:
        r = r + rng.normal(0.0, sigma, r.shape)
    r[r >= max_range] = np.inf
    return Scan(stamp=stamp, ranges=r, angle_min=-fov / 2.0,
                angle_increment=fov / (n_beams - 1), range_min=0.0, range_max=max_range)


def two_scans(world, pose0, motion, odo_error, sigma=0.005, seed=1, config=None, dt=0.5):
    """Feed scan 0 at pose0 and scan 1 at pose0 (+) motion; odometry = motion + odo_error."""
    rng = np.random.default_rng(seed)
    pose1 = compose(pose0, motion)
    est = EgoMotionEstimator(config or EgoMotionConfig())
    est.add_odometry(10.0, pose0)
    est.add_odometry(10.0 + dt, compose(pose0, np.asarray(motion) + np.asarray(odo_error)))
    e0 = est.update(cast(world, pose0, sigma=sigma, rng=rng, stamp=10.0))
    e1 = est.update(cast(world, pose1, sigma=sigma, rng=rng, stamp=10.0 + dt))
    return est, e0, e1


def motion_error(est_motion, true_motion):
    d = between(true_motion, est_motion)
    return math.hypot(d[0], d[1]), abs(d[2])


# ------------------------------------------------------------------------- ICP core


def test_normals_face_the_scanner_and_follow_the_wall():
    scan = cast(ROOM, (0.0, 0.0, 0.0))
    pts = scan.points()
    nrm, ok = scan_normals(pts)
    assert ok.mean() > 0.9
    assert np.allclose(np.hypot(nrm[ok, 0], nrm[ok, 1]), 1.0)
    assert np.all(np.einsum('ij,ij->i', nrm[ok], pts[ok]) < 0)  # towards the scanner
    on_far_wall = (np.abs(pts[:, 0] - 6.0) < 1e-6) & (np.abs(pts[:, 1]) < 0.4)
    assert on_far_wall.sum() > 5
    assert np.allclose(nrm[on_far_wall], [-1.0, 0.0], atol=1e-6)


def test_align_recovers_a_displaced_pose_from_a_local_map():
    ref_scan = cast(ROOM, (0.0, 0.0, 0.0))
    local = LocalMap(3)
    local.add_scan((0.0, 0.0, 0.0), ref_scan.points())
    true_pose = np.array([0.3, -0.2, 8 * DEG])
    src = cast(ROOM, true_pose).points()
    res = align(src, local, true_pose + [0.08, -0.06, 3 * DEG])
    assert res.converged
    assert np.allclose(res.pose[:2], true_pose[:2], atol=0.01)
    assert abs(res.pose[2] - true_pose[2]) < 0.2 * DEG
    assert res.eigenvalues[0] > 0.05  # a room constrains every direction


def test_map_neighbours_are_the_kd_trees_ties_included():
    """The local map answers as cKDTree(leafsize 16, sliding midpoint) does, also where
    points are exactly as near (quantised ranges make such ties common)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(11)
    for trial in range(30):
        n = int(rng.integers(20, 1500))
        local = LocalMap(1, max_gap=10.0)           # every point keeps its normal
        if trial % 3 == 0:                          # a lattice: ties everywhere
            pts = np.unique(rng.integers(-30, 30, size=(n, 2)) * 0.05, axis=0)
            q = rng.integers(-64, 64, size=(400, 2)) * 0.025
        elif trial % 3 == 1:                        # mm-quantised ranges of a room
            a = np.linspace(-1.5, 1.5, n)
            r = np.round(3.0 + np.sin(3.0 * a) + 0.2 * np.sin(17.0 * a), 3)
            pts = np.column_stack((r * np.cos(a), r * np.sin(a)))
            q = pts[rng.integers(0, n, 400)] + np.round(rng.normal(0.0, 0.05, (400, 2)), 3)
        else:
            pts = rng.normal(size=(n, 2)) * 4.0
            q = rng.normal(size=(400, 2)) * 5.0
        order = np.argsort(np.arctan2(pts[:, 1], pts[:, 0]), kind='stable')
        pts = pts[order]
        local.add_scan((0.0, 0.0, 0.0), pts)
        tree = cKDTree(local.rows[:, :2], leafsize=16, balanced_tree=False,
                       compact_nodes=False)
        for d in (0.05, 0.3, 1.0, 50.0):
            _, want = tree.query(q, k=1, distance_upper_bound=d)
            got = icp.nearest(local, q, d)
            np.testing.assert_array_equal(np.where(got < 0, local.n_points, got), want)


# ---------------------------------------------------------------- synthetic motions


def test_room_small_motion_recovered_by_icp():
    motion = np.array([0.25, 0.04, 4 * DEG])
    est, e0, e1 = two_scans(ROOM, (0.0, 0.0, 0.0), motion, (0.025, -0.02, 1.5 * DEG),
                            config=NOISY_ODOMETRY)
    assert e0.source == SOURCE_INIT and e0.ok
    assert e1.source == SOURCE_ICP, e1.reason
    t_err, r_err = motion_error(e1.motion, motion)
    # odometry was 3.2 cm / 1.5 deg off; the fused estimate (range noise 5 mm) is within
    # a few mm (the fusion gives odometry about 10 % weight per direction, by design)
    assert t_err < 0.005 and r_err < 0.1 * DEG
    assert np.allclose(e1.pose, compose(e0.pose, e1.motion))
    assert e1.covariance.shape == (3, 3) and np.all(np.linalg.eigvalsh(e1.covariance) > 0)
    np.testing.assert_allclose(e1.odometry_motion, motion + [0.025, -0.02, 1.5 * DEG],
                               atol=1e-9)


def test_room_matcher_alone_is_millimetre_precise():
    # with the ICP error model tightened to the synthetic data, odometry gets no weight
    cfg = EgoMotionConfig(icp_model_sigma=0.001)
    motion = np.array([0.25, 0.04, 4 * DEG])
    _, _, e1 = two_scans(ROOM, (0.0, 0.0, 0.0), motion, (0.05, -0.05, 2 * DEG), config=cfg)
    assert e1.source == SOURCE_ICP
    t_err, r_err = motion_error(e1.motion, motion)
    assert t_err < 0.0015 and r_err < 0.05 * DEG


def test_room_large_step_like_intel_recovered():
    # the corrected CARMEN logs step about 0.7 m and 20-30 deg at a time
    motion = np.array([0.7, 0.1, 25 * DEG])
    _, _, e1 = two_scans(ROOM, (-1.0, 0.5, -0.3), motion, (-0.06, 0.05, -2.5 * DEG), dt=1.0,
                         config=NOISY_ODOMETRY)
    assert e1.source == SOURCE_ICP, e1.reason
    t_err, r_err = motion_error(e1.motion, motion)
    assert t_err < 0.015 and r_err < 0.3 * DEG  # odometry was 7.8 cm / 2.5 deg off


def test_corridor_motion_along_the_axis_comes_from_odometry():
    motion = np.array([0.30, 0.05, 2 * DEG])
    odo_error = np.array([0.04, -0.03, 1.0 * DEG])
    _, e0, e1 = two_scans(CORRIDOR, (0.0, 0.0, 0.0), motion, odo_error, config=NOISY_ODOMETRY)
    assert e0.source == SOURCE_INIT
    np.testing.assert_allclose(e0.pose, 0.0, atol=1e-12)  # first pose = odometry = origin
    assert e1.source == SOURCE_PARTIAL, e1.reason
    assert 'degenerate' in e1.reason
    odo = e1.odometry_motion
    # previous pose is the origin: motion = pose in the corridor's (world) axes
    assert abs(e1.motion[0] - odo[0]) < 0.002          # along the corridor: odometry
    assert abs(e1.motion[0] - motion[0]) > 0.03        # ... which was wrong by 4 cm
    assert abs(e1.motion[1] - motion[1]) < 0.005       # across: corrected by the walls
    assert abs(e1.motion[2] - motion[2]) < 0.1 * DEG   # heading: corrected
    # the covariance says so: the odometry's variance along the corridor, less across
    assert e1.covariance[0, 0] == pytest.approx(0.05 ** 2, rel=0.1)
    assert e1.covariance[1, 1] < 0.25 * e1.covariance[0, 0]


def test_corridor_without_odometry_keeps_the_guess_along_the_axis():
    rng = np.random.default_rng(2)
    est = EgoMotionEstimator()
    true1 = np.array([0.3, 0.05, 2 * DEG])
    e0 = est.update(cast(CORRIDOR, (0.0, 0.0, 0.0), sigma=0.005, rng=rng, stamp=1.0))
    e1 = est.update(cast(CORRIDOR, true1, sigma=0.005, rng=rng, stamp=1.5))
    assert e0.source == SOURCE_INIT
    assert e1.source == SOURCE_PARTIAL and 'constant-velocity guess' in e1.reason
    assert abs(e1.motion[0]) < 0.002                  # the guess (no motion yet) along it
    assert abs(e1.motion[1] - true1[1]) < 0.005       # across: from the walls
    assert abs(e1.motion[2] - true1[2]) < 0.1 * DEG
    assert e1.covariance[0, 0] > 10 * e1.covariance[1, 1]


def test_featureless_scan_falls_back_to_odometry_entirely():
    # a single far point cloud: a circle around the scanner constrains no rotation, and a
    # few points nothing else: too few points
    est, _, e1 = two_scans(segments_of([[(7.0, -0.3), (7.0, 0.3)]]), (0.0, 0.0, 0.0),
                           (0.2, 0.0, 0.0), (0.02, 0.0, 0.0))
    assert e1.source == SOURCE_ODOMETRY
    assert 'too few valid points' in e1.reason or 'map too small' in e1.reason
    np.testing.assert_allclose(e1.motion, e1.odometry_motion)


# -------------------------------------------------------------------------- bad input


def _stream(config=None, sigma=0.005, seed=3):
    """An estimator and a helper producing room scans along a gentle path."""
    rng = np.random.default_rng(seed)
    est = EgoMotionEstimator(config or EgoMotionConfig())
    path = [np.array([0.05 * k, 0.02 * k, 1.0 * k * DEG]) for k in range(40)]

    def scan(k, stamp=None, **kw):
        return cast(ROOM, path[k], sigma=sigma, rng=rng,
                    stamp=float(k) * 0.2 if stamp is None else stamp, **kw)
    return est, path, scan


def _third_scan(config=None):
    """:func:`_stream` with odometry for three scans and the first two matched: the
    estimator, the path, the scan maker and the third scan (not given yet)."""
    est, path, scan = _stream(config)
    for k in range(3):
        est.add_odometry(0.2 * k, path[k])
    est.update(scan(0))
    est.update(scan(1))
    return est, path, scan, scan(2)


def test_nan_inf_zero_negative_ranges_are_not_points():
    est, path, scan, s = _third_scan(EgoMotionConfig(max_points=1000))
    bad = np.arange(0, 361, 7)
    s.ranges[bad[0::4]] = np.nan
    s.ranges[bad[1::4]] = np.inf
    s.ranges[bad[2::4]] = 0.0
    s.ranges[bad[3::4]] = -1.5
    e = est.update(s)
    assert e.source == SOURCE_ICP, e.reason
    assert e.n_points == int(np.count_nonzero(s.valid()))
    t_err, r_err = motion_error(e.motion, between(path[1], path[2]))
    assert t_err < 0.005 and r_err < 0.1 * DEG


def test_all_max_range_scan_uses_odometry():
    est, path, scan, s = _third_scan()
    s.ranges[:] = s.range_max  # open space: nothing returned
    e = est.update(s)
    assert e.source == SOURCE_ODOMETRY and 'too few valid points (0' in e.reason
    np.testing.assert_allclose(e.motion, between(path[1], path[2]), atol=1e-9)
    # the next (normal) scan still matches against the map of the earlier scans
    est.add_odometry(0.6, path[3])
    e3 = est.update(scan(3))
    assert e3.source == SOURCE_ICP, e3.reason


@pytest.mark.parametrize('beams', [1, 3, 4096])
def test_scans_of_any_beam_count_get_a_pose(beams):
    """A single beam, three beams, 4,096 beams: never a crash; too few points coast on the
    odometry, many are matched (thinned to max_points)."""
    rng = np.random.default_rng(5)
    path = [np.array([0.05 * k, 0.0, 0.5 * k * DEG]) for k in range(4)]
    est = EgoMotionEstimator()
    for k, p in enumerate(path):
        est.add_odometry(0.2 * k, p)
        scan = cast(ROOM, p, n_beams=max(beams, 3), sigma=0.002, rng=rng, stamp=0.2 * k)
        if beams == 1:                              # straight ahead only
            scan = Scan(stamp=scan.stamp, ranges=scan.ranges[1:2], angle_min=0.0,
                        angle_increment=0.01, range_min=0.0, range_max=scan.range_max)
        e = est.update(scan)
        assert e.ok and np.all(np.isfinite(e.pose)) and np.all(np.isfinite(e.covariance))
        limit = EgoMotionConfig().max_points
        assert e.n_points == beams if beams <= limit else limit / 2 < e.n_points <= limit
        if k == 0:
            assert e.source == SOURCE_INIT
        elif beams < EgoMotionConfig().min_points:
            assert e.source == SOURCE_ODOMETRY and 'too few valid points' in e.reason
            np.testing.assert_allclose(e.motion, between(path[k - 1], p), atol=1e-12)
        else:
            assert e.source == SOURCE_ICP, e.reason
            assert motion_error(e.motion, between(path[k - 1], p))[0] < 0.005


def test_scans_with_every_beam_invalid_coast_and_the_chain_goes_on():
    est, path, scan = _stream()
    for k in range(6):
        est.add_odometry(0.2 * k, path[k])
    out = []
    for k in range(6):
        s = scan(k)
        s.ranges[:] = [np.nan, np.inf, -1.0, 0.0][k % 4] if k > 0 else s.ranges
        out.append(est.update(s))
    assert [e.source for e in out] == [SOURCE_INIT] + [SOURCE_ODOMETRY] * 5
    for e, k in zip(out[1:], range(1, 6)):
        assert e.n_points == 0 and e.coasting and 'too few valid points (0' in e.reason
        np.testing.assert_allclose(e.pose, path[k], atol=1e-9)


def test_too_few_points_uses_odometry():
    est, path, scan, s = _third_scan()
    s.ranges[10:] = np.inf  # ten returns left
    e = est.update(s)
    assert e.source == SOURCE_ODOMETRY and 'too few valid points (10 < 30)' in e.reason


def test_no_odometry_at_all_icp_alone_then_coasts_without_points(caplog):
    est, path, scan = _stream()
    with caplog.at_level(logging.WARNING, logger='laser_tracker.core.egomotion'):
        e0 = est.update(scan(0))
        e1 = est.update(scan(1))
        s = scan(2)
        s.ranges[:] = np.inf
        e2 = est.update(s)
    assert e0.source == SOURCE_INIT and 'no odometry received' in e0.reason
    np.testing.assert_allclose(e0.pose, 0.0)
    assert e1.source == SOURCE_ICP and 'without odometry' in e1.reason
    t_err, _ = motion_error(e1.motion, between(path[0], path[1]))
    assert t_err < 0.005
    # neither ICP nor odometry: the platform coasts at constant velocity, flagged
    assert e2.source == SOURCE_CONSTANT_VELOCITY and e2.ok and e2.coasting
    np.testing.assert_allclose(e2.motion, e1.motion)       # same time step: same motion
    np.testing.assert_allclose(e2.pose, compose(e1.pose, e1.motion))
    assert 'no odometry' in e2.reason and 'too few valid points' in e2.reason
    assert np.all(np.isfinite(e2.covariance)) and np.all(np.diag(e2.covariance) > 0)
    assert pose_quality(e2).failed                         # detection gates it
    assert any('constant-velocity motion' in r.message for r in caplog.records)


def test_late_odometry_is_not_extrapolated_far():
    est, path, scan = _stream()
    est.add_odometry(0.0, path[0])
    est.add_odometry(0.2, path[1])
    est.update(scan(0))
    est.update(scan(1))
    # odometry stops; the scan 1 s later is beyond the extrapolation limit (0.1 s)
    e = est.update(scan(6, stamp=1.2))
    assert e.source == SOURCE_ICP and 'odometry late' in e.reason
    assert e.odometry_motion is None
    # within the limit it is extrapolated at the last velocity
    est2, _, scan2 = _stream()
    est2.add_odometry(0.0, path[0])
    est2.add_odometry(0.2, path[1])
    est2.update(scan2(0))
    e2 = est2.update(scan2(1, stamp=0.25))
    np.testing.assert_allclose(e2.odometry_motion, 1.25 * np.asarray(path[1]), atol=1e-9)


def test_out_of_order_odometry_is_inserted_in_time_order():
    est, path, scan = _stream()
    stamps = [0.2 * k for k in range(4)]
    for k in (0, 2, 1, 3):  # one sample late
        est.add_odometry(stamps[k], path[k])
    assert est.stats['note: odometry out of order'] == 1
    est.update(scan(0))
    e1 = est.update(scan(1))
    np.testing.assert_allclose(e1.odometry_motion, between(path[0], path[1]), atol=1e-9)


def test_odometry_jump_is_not_used_and_odometry_recovers_after():
    est, path, scan = _stream()
    est.add_odometry(0.0, path[0])
    est.add_odometry(0.2, path[1])
    est.update(scan(0))
    est.update(scan(1))
    # the odometry frame jumps by 5 m (a reset of the wheel encoders, a glitch)
    jump = np.array([5.0, 0.0, 0.0])
    est.add_odometry(0.4, path[2] + jump)
    est.add_odometry(0.6, path[3] + jump)
    assert est.stats['note: odometry jumped'] == 1
    e2 = est.update(scan(2))
    assert e2.source == SOURCE_ICP and 'jumped' in e2.reason
    assert motion_error(e2.motion, between(path[1], path[2]))[0] < 0.005
    e3 = est.update(scan(3))
    assert e3.source == SOURCE_ICP and e3.reason == 'icp'  # odometry usable again
    np.testing.assert_allclose(e3.odometry_motion, between(path[2], path[3]), atol=1e-9)


def test_non_finite_odometry_sample_is_ignored():
    est, path, scan = _stream()
    est.add_odometry(0.0, path[0])
    est.add_odometry(0.1, (np.nan, 0.0, 0.0))
    est.add_odometry(0.2, path[1])
    assert est.stats['note: bad odometry'] == 1
    est.update(scan(0))
    e1 = est.update(scan(1))
    np.testing.assert_allclose(e1.odometry_motion, between(path[0], path[1]), atol=1e-9)


def test_time_going_backwards_resets_and_same_stamp_is_skipped(caplog):
    est, path, scan = _stream()
    for k in range(4):
        est.add_odometry(0.2 * k, path[k])
    est.update(scan(0))
    est.update(scan(1))
    e = est.update(scan(2))
    pose_before = e.pose.copy()
    dup = est.update(scan(2))  # same stamp again
    assert dup.source == SOURCE_NONE and 'equals the previous' in dup.reason
    with caplog.at_level(logging.WARNING, logger='laser_tracker.core.egomotion'):
        looped = est.update(scan(0))  # the bag starts again
    assert looped.source == SOURCE_INIT
    assert est.stats['resets'] == 1
    assert any('time went backwards' in r.message for r in caplog.records)
    np.testing.assert_allclose(looped.pose, path[0], atol=1e-9)  # odometry at t = 0
    again = est.update(scan(1))
    assert again.source == SOURCE_ICP
    assert not np.allclose(again.pose, pose_before)


def test_match_faster_than_the_platform_is_refused():
    # odometry and ICP both imply 0.5 m/s; the platform is declared to do 0.2 m/s at most:
    # the odometry step is a jump, the match is refused, the platform coasts (no motion known
    # yet: standing)
    cfg = EgoMotionConfig(max_translation_speed=0.2)
    _, e0, e1 = two_scans(ROOM, (0.0, 0.0, 0.0), (0.25, 0.0, 0.0), (0.0, 0.0, 0.0),
                          config=cfg, dt=0.5)
    assert e1.source == SOURCE_CONSTANT_VELOCITY and e1.coasting and e1.ok
    assert 'm/s > 0.2 m/s' in e1.reason
    np.testing.assert_allclose(e1.pose, e0.pose)
    assert pose_quality(e1).failed


def test_speed_check_allows_stamp_jitter():
    # freiburg-079 has 16 cm steps stamped 0.07 s apart (2.2 m/s by the stamps, the robot
    # drives 0.4 m/s): the check allows speed_check_jitter on top of the time step
    motion = (0.16, 0.0, 0.0)
    _, _, e1 = two_scans(ROOM, (0.0, 0.0, 0.0), motion, (0.0, 0.0, 0.0), dt=0.07)
    assert e1.source == SOURCE_ICP, e1.reason
    _, _, e2 = two_scans(ROOM, (0.0, 0.0, 0.0), motion, (0.0, 0.0, 0.0), dt=0.07,
                         config=EgoMotionConfig(speed_check_jitter=0.0))
    assert e2.coasting and 'm/s > 2 m/s' in e2.reason


def test_match_disagreeing_with_odometry_is_refused():
    cfg = EgoMotionConfig(max_correction_translation=0.02)
    _, _, e1 = two_scans(ROOM, (0.0, 0.0, 0.0), (0.25, 0.0, 0.0), (0.06, 0.0, 0.0), config=cfg)
    assert e1.source == SOURCE_ODOMETRY and 'disagrees with odometry' in e1.reason
    assert e1.coasting and pose_quality(e1).failed       # a match was tried and refused
    np.testing.assert_allclose(e1.motion, (0.31, 0.0, 0.0), atol=1e-9)


def test_refused_matches_never_restart_and_reseed_the_map():
    """Scans from a place the map does not know: ICP is refused, the platform coasts, and
    after max_lost_scans the map is re-seeded from the current scan; the pose chain goes
    on (no init) and the next scans match the new map."""
    cfg = EgoMotionConfig(max_lost_scans=2)
    est, path, scan = _stream(cfg)
    for k in range(3):
        est.update(scan(k))
    rng = np.random.default_rng(4)
    elsewhere = segments_of([box(-20.0, -9.0, 20.0, 9.0), [(3.0, -9.0), (3.0, -5.0)],
                             box(1.0, 2.0, 1.6, 2.3)])
    out = [est.update(cast(elsewhere, (0.1 * j, 0.0, 0.0), sigma=0.005, rng=rng,
                           stamp=1.0 + 0.2 * j)) for j in range(6)]
    sources = [e.source for e in out]
    assert SOURCE_INIT not in sources and all(e.ok for e in out)
    assert sources[:2] == [SOURCE_CONSTANT_VELOCITY] * 2, [e.reason for e in out[:2]]
    assert 're-seeded' in out[1].reason and est.stats['map re-seeded'] == 1
    assert all(e.coasting for e in out[:2]) and all(pose_quality(e).failed for e in out[:2])
    assert not pose_quality(out[1]).restarted
    # the chain is continuous: each pose is the previous one moved by its motion
    for a, b in zip(out, out[1:]):
        np.testing.assert_allclose(b.pose, compose(a.pose, b.motion), atol=1e-9)
    assert all(s in (SOURCE_ICP, SOURCE_PARTIAL) for s in sources[2:]), sources
    for a, b in zip(out[2:], out[3:]):
        assert motion_error(b.motion, (0.1, 0.0, 0.0))[0] < 0.005


def test_after_a_gap_without_odometry_the_map_is_reseeded_at_once_when_asked():
    """No scans for 3 s and no odometry, while the platform went from a room into a hall
    the map does not know: the first match is refused. With ``max_gap`` 2 s the map is
    re-seeded from that scan at once and the next scans match (the motion right from the
    second scan after the gap); by default (0) the platform coasts for ``max_lost_scans``
    scans first."""
    def run(max_gap):
        est, path, scan = _stream(EgoMotionConfig(max_gap=max_gap))
        for k in range(3):
            est.update(scan(k))
        rng = np.random.default_rng(4)
        hall = segments_of([box(-20.0, -9.0, 20.0, 9.0), [(3.0, -9.0), (3.0, -5.0)],
                            box(1.0, 2.0, 1.6, 2.3)])
        return [est.update(cast(hall, (0.1 * j, 0.0, 0.0), sigma=0.005, rng=rng,
                                stamp=3.4 + 0.2 * j)) for j in range(7)]
    at_once = run(2.0)
    assert at_once[0].source == SOURCE_CONSTANT_VELOCITY and 're-seeded' in at_once[0].reason
    assert all(e.source in (SOURCE_ICP, SOURCE_PARTIAL) for e in at_once[1:])
    for e in at_once[2:]:
        assert motion_error(e.motion, (0.1, 0.0, 0.0))[0] < 0.005
    coasting = run(0.0)
    assert [e.source for e in coasting[:5]] == [SOURCE_CONSTANT_VELOCITY] * 5
    assert 're-seeded' in coasting[4].reason and 're-seeded' not in coasting[0].reason


def test_odometry_jump_and_refused_match_coast_on_constant_velocity():
    est, path, scan = _stream()
    for k in range(3):
        est.add_odometry(0.2 * k, path[k])
        e = est.update(scan(k))
    est.add_odometry(0.6, path[3] + np.array([5.0, 0.0, 0.0]))  # odometry jumps 5 m
    s = scan(3)
    s.ranges[20:] = np.inf                                       # and nothing to match
    e3 = est.update(s)
    assert e3.source == SOURCE_CONSTANT_VELOCITY and e3.coasting
    assert 'jump' in e3.reason
    np.testing.assert_allclose(e3.motion, e.motion)
    np.testing.assert_allclose(e3.pose, compose(e.pose, e.motion))


def test_odometry_buffer_gap_and_restart():
    buf = OdometryBuffer(EgoMotionConfig(odom_max_gap=0.5))
    buf.add(0.0, (0.0, 0.0, 0.0))
    buf.add(1.0, (0.5, 0.0, 0.0))
    pose, _, reason = buf.pose_at(0.5)
    assert pose is None and 'gap' in reason
    note = buf.add(10.0, (1.0, 0.0, 0.0))
    assert note is None
    note = buf.add(2.0, (0.0, 0.0, 0.0))  # 8 s back: a replayed bag
    assert note[0] == 'odometry restart' and len(buf) == 1


# ------------------------------------------------------------------- adaptive prior


def test_adaptive_noise_recovers_a_per_step_and_per_metre_model():
    rng = np.random.default_rng(11)
    noise = AdaptiveNoise((1e-4, 0.0, 0.0), (1e-4, 0.0, 0.0), memory=5000, weight=5.0,
                          clip=4.0)
    icp_var = (1e-5, 1e-5, 1e-7)
    # truth: 2 cm per step + 5 % per metre on x and y; 1 deg per step + 2 deg per radian
    for _ in range(20000):
        d = rng.uniform(0.0, 0.8)
        a = rng.uniform(-0.5, 0.5)
        sxy2 = 0.02 ** 2 + (0.05 * d) ** 2
        sth2 = DEG ** 2 + (2 * DEG * a) ** 2
        err = rng.normal(0.0, 1.0, 3) * np.sqrt([sxy2 + icp_var[0], sxy2 + icp_var[1],
                                                 sth2 + icp_var[2]])
        noise.update((d, 0.0, a), err, icp_var)
    for d, a in ((0.0, 0.0), (0.4, 0.25), (0.8, 0.5)):
        vxy, vth = noise.variance((d, 0.0, a))
        assert math.sqrt(vxy) == pytest.approx(math.hypot(0.02, 0.05 * d), rel=0.1)
        assert math.sqrt(vth) == pytest.approx(DEG * math.hypot(1.0, 2 * a), rel=0.1)


def test_adaptive_noise_resists_outliers():
    noise = AdaptiveNoise((1e-4, 0.0, 0.0), (1e-4, 0.0, 0.0), memory=50, weight=5.0, clip=3.0)
    rng = np.random.default_rng(2)
    for k in range(300):
        err = rng.normal(0.0, 0.01, 3)
        if k % 20 == 0:
            err = np.array([2.0, -2.0, 1.0])   # a false match now and then
        noise.update((0.1, 0.0, 0.0), err, (0.0, 0.0, 0.0))
    vxy, _ = noise.variance((0.1, 0.0, 0.0))
    assert 0.007 < math.sqrt(vxy) < 0.03


def _room_run(odo_noise, config=None, n=90, seed=8):
    """A room walk with odometry = truth + ``odo_noise(rng, motion)`` per step; returns the
    estimator, the estimates and the true motions."""
    rng = np.random.default_rng(seed)
    est = EgoMotionEstimator(config)
    path = [np.array([1.2 * math.sin(0.05 * k), 0.8 * math.sin(0.035 * k),
                      0.5 * math.sin(0.04 * k)]) for k in range(n)]
    odo = [path[0].copy()]
    for k in range(1, n):
        inc = between(path[k - 1], path[k])
        odo.append(compose(odo[-1], inc + odo_noise(rng, inc)))
    out = []
    for k in range(n):
        est.add_odometry(0.2 * k, odo[k])
        out.append(est.update(cast(ROOM, path[k], sigma=0.005, rng=rng, stamp=0.2 * k)))
    truth = [between(path[k - 1], path[k]) for k in range(1, n)]
    return est, out, truth


def poor_odometry(rng, inc):
    return rng.normal(0.0, 1.0, 3) * (0.05, 0.05, 2 * DEG)


def good_odometry(rng, inc):
    return rng.normal(0.0, 1.0, 3) * (0.0005, 0.0005, 0.02 * DEG)


def test_adaptive_prior_learns_how_poor_the_odometry_is():
    est, out, truth = _room_run(poor_odometry)
    vxy, vth = est.prior.odometry_noise.variance((0.05, 0.0, 0.02))
    assert 0.025 < math.sqrt(vxy) < 0.08 and 1 * DEG < math.sqrt(vth) < 3.5 * DEG
    # the over-confident fixed default (1 cm, 0.5 deg per step) pulls ICP towards the poor
    # odometry; the adapted prior does not
    fixed, out_fixed, _ = _room_run(poor_odometry, EgoMotionConfig(adaptive_prior=False))
    err = np.array([motion_error(e.motion, m) for e, m in zip(out[30:], truth[29:])])
    err_fixed = np.array([motion_error(e.motion, m) for e, m in zip(out_fixed[30:],
                                                                    truth[29:])])
    assert np.median(err[:, 0]) < 0.5 * np.median(err_fixed[:, 0])
    assert np.median(err[:, 1]) < 0.5 * np.median(err_fixed[:, 1])
    # a scan without points coasts on odometry with the learned covariance, not the fixed one
    assert all(e.source in (SOURCE_ICP, SOURCE_PARTIAL) for e in out[1:])


def test_adaptive_prior_comes_to_trust_good_odometry():
    est, out, truth = _room_run(good_odometry)
    vxy, vth = est.prior.odometry_noise.variance((0.05, 0.0, 0.02))
    fixed_sxy = 0.01 + 0.05 * 0.05                       # the starting (fixed) model
    assert math.sqrt(vxy) < 0.5 * fixed_sxy
    # the fused motion is as good as the odometry, better than ICP alone (model sigma 1 cm)
    err = np.array([motion_error(e.motion, m)[0] for e, m in zip(out[30:], truth[29:])])
    assert np.median(err) < 0.002
    # but the prior never silences the laser: at most prior_max_ratio x the match
    e = out[-1]
    assert e.source == SOURCE_ICP and e.covariance[0, 0] > 0


def test_wheel_slip_is_overridden_by_a_good_match():
    def slipping(rng, inc, _state={'k': 0}):
        _state['k'] += 1
        return np.array([0.3, 0.0, 0.0]) if _state['k'] == 60 else good_odometry(rng, inc)
    est, out, truth = _room_run(slipping)
    e = out[60]
    assert e.source == SOURCE_ICP, e.reason
    assert motion_error(e.motion, truth[59])[0] < 0.03      # odometry was 30 cm off
    gated, out_gated, _ = _room_run(lambda rng, inc, _s={'k': 0}: slipping(rng, inc, _s),
                                    EgoMotionConfig(prior_gate=0.0))
    assert motion_error(out_gated[60].motion, truth[59])[0] > 0.1


def test_fixed_prior_keeps_the_configured_model():
    cfg = EgoMotionConfig(adaptive_prior=False)
    est, out, truth = _room_run(poor_odometry, cfg, n=40)
    s = cast(ROOM, (0.0, 0.0, 0.0), stamp=100.0)
    s.ranges[:] = np.inf
    last = est.odometry.pose_at(0.2 * 39)[0]          # the odometry of the last scan
    est.add_odometry(100.0, compose(last, (0.1, 0.0, 0.0)))
    est.add_odometry(99.9, last)
    e = est.update(s)
    # too few points, no match tried: odometry with its fixed covariance (1 cm + 5 %/m)
    assert e.source == SOURCE_ODOMETRY and not pose_quality(e).failed
    assert math.sqrt(e.covariance[0, 0]) == pytest.approx(0.01 + 0.05 * 0.1, rel=1e-6)


# ---------------------------------------------------------------- offline + config


def test_estimate_track_matches_the_online_loop():
    rng = np.random.default_rng(5)
    path = [np.array([0.1 * k, 0.0, 2 * k * DEG]) for k in range(6)]
    scans = [cast(ROOM, p, sigma=0.005, rng=rng, stamp=0.2 * k) for k, p in enumerate(path)]
    odo_stamps = np.arange(0, 1.2, 0.05)
    odo = np.array([[0.5 * t, 0.0, 10 * DEG * t] for t in odo_stamps])
    track = PoseTrack(stamps=odo_stamps, poses=odo)
    offline = estimate_track(scans, track)
    online = EgoMotionEstimator()
    for t, p in zip(odo_stamps, odo):
        online.add_odometry(t, p)
    for scan, off in zip(scans, offline):
        on = online.update(scan)
        assert on.source == off.source
        np.testing.assert_allclose(on.pose, off.pose)
    assert [e.source for e in offline] == [SOURCE_INIT] + [SOURCE_ICP] * 5
    for k in range(1, 6):
        assert motion_error(offline[k].motion, between(path[k - 1], path[k]))[0] < 0.005


def test_config_section_declares_every_field_with_description_and_range():
    for name, f in describe(EgoMotionConfig):
        assert f.metadata['description'], name
    with pytest.raises(ConfigError):
        from_dict(EgoMotionConfig, {'map_scans': 0})
    with pytest.raises(ConfigError):
        from_dict(EgoMotionConfig, {'no_such_field': 1})


# ------------------------------------------------------------------------- real logs

FREIBURG = 'freiburg-079-part1-corrected.log.gz'
#: (log, odometry noise model): the intel and aces protocol, and freiburg-079 at its native
#: rate with both noise models, all with the same (default) configuration
REAL_CASES = [('intel-corrected.log.gz', 'poor'), ('aces-corrected.log.gz', 'poor'),
              (FREIBURG, 'poor'), (FREIBURG, 'realistic')]


def _bench(name, noise):
    path = DATA / name
    if not path.exists():
        pytest.skip(f'{DATA / name} not found '
                    '(the public recordings: $LASER_TRACKER_DATA)')
    from laser_tracker.tools.bench_egomotion import bench_log, kiss_available
    return bench_log(path, seed=0, with_kiss=kiss_available(), noise=noise)


@pytest.fixture(scope='module')
def real_results():
    quiet = ('laser_tracker.core.egomotion', 'laser_tracker.tools.carmen')
    for name in quiet:
        logging.getLogger(name).setLevel(logging.ERROR)
    try:
        return {case: _bench(*case) for case in REAL_CASES}
    finally:
        for name in quiet:
            logging.getLogger(name).setLevel(logging.NOTSET)


@pytest.mark.parametrize('case', [c for c in REAL_CASES if c[1] == 'poor'])
def test_real_log_far_better_than_the_odometry_given(real_results, case):
    r = real_results[case]
    ours, odo = r['ours'], r['odometry']
    assert ours['failed'] == 0
    assert ours['trans_med'] < 0.45 * odo['trans_med']
    assert ours['trans_p95'] < 0.65 * odo['trans_p95']
    assert ours['rot_med'] < 0.3 * odo['rot_med']
    assert ours['rot_p95'] < 0.35 * odo['rot_p95']
    assert ours['drift_trans'] < 0.4 * odo['drift_trans']
    assert r['sources'].get('icp', 0) > 0.9 * (r['scans'] - 1)
    assert r['sources'].get('init', 0) == 1


@pytest.mark.parametrize('case', REAL_CASES)
def test_real_log_better_than_kiss_icp_on_every_figure(real_results, case):
    r = real_results[case]
    if 'kiss' not in r:
        pytest.skip('kiss-icp is not installed (optional benchmark dependency)')
    ours, kiss = r['ours'], r['kiss']
    for key in ('trans_med', 'trans_p95', 'rot_med', 'rot_p95', 'drift_trans', 'drift_rot'):
        assert ours[key] < kiss[key], key


def test_real_log_good_odometry_is_trusted(real_results):
    """Realistic odometry (2 % + 1 deg/m) is better per step than any scan match against the
    corrected poses: the adapted prior comes to lean on it."""
    r = real_results[(FREIBURG, 'realistic')]
    ours, odo = r['ours'], r['odometry']
    assert ours['trans_med'] < 1.5 * odo['trans_med']
    assert ours['rot_med'] < 1.5 * odo['rot_med']
    assert ours['drift_rot'] < odo['drift_rot']     # ... and the map corrects its drift


@pytest.mark.xfail(strict=True, reason=(
    'absolute accuracy targets not all reached: measured (seed 0, defaults) intel '
    '2.017/5.804 cm, 0.314/1.138 deg; aces 2.353/7.121 cm, 0.240/0.775 deg (median/p95). '
    'Converged ICP against 5 scans placed at the reference poses, started 5 mm / 0.2 deg '
    'from the reference, lands as far from it (intel 1.90 cm / 0.272 deg, aces 2.36 / 7.09 '
    'cm median / p95; `bench egomotion --oracle`)'))
@pytest.mark.parametrize('case', REAL_CASES[:2])
def test_real_log_meets_the_accuracy_targets(real_results, case):
    ours = real_results[case]['ours']
    misses = [f'{key} {value:.4g} > {limit}' for key, value, limit in (
        ('trans_med', ours['trans_med'], 0.02), ('trans_p95', ours['trans_p95'], 0.06),
        ('rot_med', ours['rot_med'], 0.25), ('rot_p95', ours['rot_p95'], 1.0))
        if value > limit]
    assert not misses, ', '.join(misses)


def test_standing_scanner_without_odometry_does_not_drift():
    """Key scans: a scanner that does not move keeps matching the same map scans, so its
    pose stays put instead of random-walking scan after scan (as it did with every scan
    joining the map)."""
    rng = np.random.default_rng(7)
    pose = np.array([0.3, -0.2, 0.1])

    def final_drift(config):
        est = EgoMotionEstimator(config)
        first = last = None
        for k in range(400):
            e = est.update(cast(ROOM, pose, sigma=0.01, rng=rng, stamp=0.2 * k))
            assert e.ok
            first = e.pose if first is None else first
            last = e.pose
        return math.hypot(*(last[:2] - first[:2])), abs(last[2] - first[2])

    drift, turn = final_drift(EgoMotionConfig())
    assert drift < 0.005 and turn < 0.2 * DEG
    every_scan = EgoMotionConfig(map_min_translation=0.0, map_min_rotation=0.0)
    assert EgoMotionEstimator(every_scan).config.map_min_translation == 0.0
    drift_all, _ = final_drift(every_scan)
    assert drift_all > 2 * drift


# ------------------------------------------------------------------- fusion kernel


def _fusion_as_numpy(h, sum_w, icp_pose, previous, predicted, prior, sigma2, ratio, gate):
    """The fusion of a fully constrained match as numpy and Python computed it before it
    became a kernel (the reference for bit-for-bit equality)."""
    info = h / (max(sum_w, 1e-12) * sigma2)
    d = between(icp_pose, predicted)
    lam = np.minimum(prior, ratio * info.diagonal())
    # d^T (info^-1 + diag(lam)^-1)^-1 d: info^-1 by cofactors, then Cramer's rule
    (a, b, c), (_, e, f), (_, _, i) = info.tolist()
    ca, cb, cc = e * i - f * f, c * f - b * i, b * f - c * e
    det = a * ca + b * cb + c * cc
    s = [[ca / det, cb / det, cc / det],
         [cb / det, (a * i - c * c) / det, (b * c - a * f) / det],
         [cc / det, (b * c - a * f) / det, (a * e - b * b) / det]]
    for k in range(3):
        s[k][k] += 1.0 / float(lam[k])
    (p, q, r), (u, t, w), (v, y, x) = s
    b0, b1, b2 = d.tolist()
    det = p * (t * x - w * y) - q * (u * x - w * v) + r * (u * y - t * v)
    sol = ((b0 * (t * x - w * y) - q * (b1 * x - w * b2) + r * (b1 * y - t * b2)) / det,
           (p * (b1 * x - w * b2) - b0 * (u * x - w * v) + r * (u * b2 - b1 * v)) / det,
           (p * (t * b2 - b1 * y) - q * (u * b2 - b1 * v) + b0 * (u * y - t * v)) / det)
    m2 = sol[0] * d[0] + sol[1] * d[1] + sol[2] * d[2]
    if m2 > gate ** 2:
        lam = lam * (gate ** 2 / m2) ** 2
    pose = compose(icp_pose, np.linalg.solve(info + np.diag(lam), lam * d))
    cov = np.linalg.inv(info + np.diag(lam))
    return pose, between(previous, pose), info, lam, 0.5 * (cov + cov.T)


def test_the_fusion_kernel_computes_as_numpy_bit_for_bit():
    """Bounded and gated prior (the gate's square is libm's pow, as Python's ``**``, which
    is not always ``x * x``), LAPACK's solve and inverse: the numbers of the numpy code."""
    from laser_tracker.core import egomotion

    rng = np.random.default_rng(12)
    gated = 0
    for _ in range(300):
        m = rng.normal(size=(3, 3))
        h = 50.0 * (m @ m.T) + np.diag(rng.uniform(1.0, 20.0, 3))
        icp_pose, previous = rng.normal(0.0, 0.3, (2, 3))
        predicted = icp_pose + rng.normal(0.0, 0.05, 3) * rng.choice([0.1, 1.0, 10.0])
        prior = 10.0 ** rng.uniform(1.0, 5.0, 3)
        sum_w = float(rng.uniform(10.0, 200.0))
        settings = np.array([1e-4, 10.0, 5.0, 25.0, 2.0])
        got = egomotion._fuse(icp_pose, h, sum_w, 0, previous, predicted, prior, settings)
        want = _fusion_as_numpy(h, sum_w, icp_pose, previous, predicted, prior, 1e-4, 10.0,
                                5.0)
        gated += not np.array_equal(got[3], np.minimum(prior, 10.0 * got[2].diagonal()))
        for a, b in zip(got, want):
            assert np.array_equal(a, b)
    assert 10 < gated < 290                    # both branches of the gate were taken


def _degenerate_as_numpy(evals, evecs, scale, threshold, predicted, pose, info):
    """The projection of the former numpy formulation: along degenerate directions (scaled
    coordinates z = delta / sv) the prediction, and no ICP information."""
    deg = evals < threshold
    sv = np.array([1.0, 1.0, 1.0 / scale])
    z = between(predicted, pose) / sv
    u = evecs[:, ~deg]
    pose = compose(predicted, sv * (u @ (u.T @ z)))
    v = evecs[:, deg]
    proj = np.eye(3) - v @ v.T
    s_inv = np.diag(1.0 / sv)
    return pose, s_inv @ proj @ np.diag(sv) @ info @ np.diag(sv) @ proj @ s_inv


def test_the_degenerate_fusion_computes_as_numpy_bit_for_bit():
    """Along degenerate directions the kernel keeps the prediction and drops ICP's
    information with numpy's products (its BLAS's order of fused multiply-adds)."""
    from fractions import Fraction

    from laser_tracker.core import egomotion

    rng = np.random.default_rng(21)
    checks = np.array([3.0, 0.3, 0.1, 0.01, 1e-4, 10.0, 5.0, 25.0, 2.0])
    def fma(a, b, c):                  # rounded once
        return float(Fraction(a) * Fraction(b) + Fraction(c))

    probe, z = np.asfortranarray(rng.normal(size=(3, 2))), rng.normal(size=3)
    if (probe.T @ z)[0] != fma(probe[2, 0], z[2], fma(probe[0, 0], z[0], probe[1, 0] * z[1])):
        pytest.skip("numpy's BLAS on this machine multiplies small matrices in another order "
                    "(the kernel gives the same numbers on every machine)")
    for n_deg in (1, 2) * 500:
        evecs, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        evals = np.sort(np.concatenate([rng.uniform(0.0, 0.009, n_deg),
                                        rng.uniform(0.02, 1.0, 3 - n_deg)]))
        scale = float(rng.uniform(0.5, 10.0))
        predicted, previous = rng.normal(0.0, 1.0, (2, 3))
        fused = predicted + rng.normal(0.0, 0.1, 3)
        m = rng.normal(size=(3, 3))
        info = m @ m.T * 10.0 ** rng.uniform(0.0, 6.0)
        lam = 10.0 ** rng.uniform(1.0, 5.0, 3)
        packed = np.full(egomotion._PACKED, np.nan)
        packed[icp.EIGENVALUES:icp.EIGENVALUES + 3] = evals
        packed[icp.EIGENVECTORS:icp.EIGENVECTORS + 9] = evecs.ravel()
        packed[icp._SCALE] = scale
        packed[egomotion._F_POSE:egomotion._F_POSE + 3] = fused
        packed[egomotion._F_INFO:egomotion._F_INFO + 9] = info.ravel()
        packed[egomotion._F_PRIOR:egomotion._F_PRIOR + 3] = lam
        pose, motion, got_info, got_lam, cov = egomotion._fused(packed, n_deg, previous,
                                                                predicted, checks)
        want_pose, want_info = _degenerate_as_numpy(
            evals, packed[icp.EIGENVECTORS:icp.EIGENVECTORS + 9].reshape(3, 3), scale,
            checks[3], predicted, fused, info)
        assert np.array_equal(pose, want_pose) and np.array_equal(got_info, want_info)
        assert np.array_equal(motion, between(previous, want_pose))
        assert np.array_equal(got_lam, lam)
        assert np.array_equal(cov, egomotion._covariance(want_info, lam))


def test_the_rehearsed_first_match_changes_nothing(monkeypatch):
    """The process's first scan is matched once more on copies of the estimator's state (so
    that the second scan runs at full speed): the estimates and every state are those of an
    estimator that does not rehearse."""
    from laser_tracker.core import egomotion

    monkeypatch.setattr(egomotion, '_rehearsed', [])
    rng = np.random.default_rng(3)
    path = [np.array([0.1 * k, 0.02 * k, 2 * k * DEG]) for k in range(5)]
    scans = [cast(ROOM, p, sigma=0.005, rng=rng, stamp=0.2 * k) for k, p in enumerate(path)]
    runs = []
    for rehearses in (True, False):
        est = EgoMotionEstimator(self_mask=SelfMask(SelfMaskConfig()))
        est.rehearses = rehearses
        out = []
        for k, scan in enumerate(scans):
            est.add_odometry(0.2 * k, path[k])
            out.append(est.update(scan))
        runs.append((est, out))
    assert egomotion._rehearsed == [True]
    (a, out_a), (b, out_b) = runs
    for ea, eb in zip(out_a, out_b):
        for name in ('pose', 'motion', 'covariance', 'pose_covariance'):
            assert np.array_equal(getattr(ea, name), getattr(eb, name))
        assert (ea.source, ea.reason) == (eb.source, eb.reason)
    assert np.array_equal(a.chain, b.chain) and np.array_equal(a.prior.noise, b.prior.noise)
    assert np.array_equal(a.matcher.map.rows, b.matcher.map.rows)
    assert np.array_equal(a.self_mask.state, b.self_mask.state, equal_nan=True)


@pytest.mark.parametrize('retry', [False, True])
def test_a_platform_that_stops_without_odometry_is_found_standing_with_standstill_retry(retry):
    """No odometry: the platform drives and turns fast, then stops. The match from the
    constant-velocity guess (a step the platform no longer makes) is refused and the pose
    coasts on; with standstill_retry the match from standing still is taken instead."""
    config = EgoMotionConfig(standstill_retry=retry)
    est = EgoMotionEstimator(config)
    pose = np.zeros(3)
    for k in range(6):                 # speeding up to 0.5 m/s and 1 rad/s: each step matched
        if k:
            pose = compose(pose, np.array([0.05, 0.0, 0.1]) * k)
        e = est.update(cast(ROOM, pose, stamp=0.5 * k))
        assert k == 0 or e.source in (SOURCE_ICP, 'icp_partial')
    after = [est.update(cast(ROOM, pose, stamp=0.5 * k)) for k in range(6, 9)]    # stopped
    drift = math.hypot(*(after[-1].pose[:2] - e.pose[:2]))
    if retry:
        assert all(a.source in (SOURCE_ICP, 'icp_partial') for a in after)
        for a in after:
            t_err, r_err = motion_error(a.motion, np.zeros(3))
            assert t_err < 0.02 and r_err < 0.02
        assert drift < 0.02
    else:
        assert all(a.source == SOURCE_CONSTANT_VELOCITY and a.coasting for a in after)
        assert drift > 0.5                               # it drove on, in the estimate
