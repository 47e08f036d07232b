"""The whole pipeline on synthetic scans: a moving object is tracked with the right velocity,
a static scene seen from a moving platform gives no confirmed track, bad input is survived,
and detection + tracking called separately equal the pipeline."""
from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import pytest

from laser_tracker.config import ConfigError
from laser_tracker.core.hypotheses import Tracker
from laser_tracker.core.pipeline import Detector, Pipeline, PipelineConfig
from laser_tracker.core.scan import Scan
from laser_tracker.sim.world import World, cast

DT = 0.2


def room() -> World:
    w = World().room(-4.0, -4.0, 6.0, 4.0)
    w.box(4.5, 2.5, 1.0, 0.6)
    w.box(-2.0, -3.0, 0.8, 0.8)
    w.circle(3.0, -2.5, 0.2)
    return w


def make_scan(world: World, pose, t, movers=(), beams=361, noise=0.005, seed=0):
    """A 180 deg scan from scanner ``pose`` (world frame) with circles ``movers``."""
    angles = np.linspace(-math.pi / 2, math.pi / 2, beams)
    x, y, th = pose
    origins = np.tile([x, y], (beams, 1))
    directions = np.column_stack((np.cos(th + angles), np.sin(th + angles)))
    segs = [(world.segments, np.zeros(len(world.segments), np.int64))]
    circles = world.circles
    if len(movers):
        circles = np.vstack((circles, np.asarray(movers, float).reshape(-1, 3)))
    rng, _ = cast(origins, directions, segs, [(circles, np.zeros(len(circles), np.int64))])
    rng = rng + np.random.default_rng(seed).normal(0, noise, beams)
    rng = np.where(rng < 8.0, rng, np.inf)
    return Scan(stamp=t, ranges=rng, angle_min=-math.pi / 2,
                angle_increment=math.pi / (beams - 1), range_min=0.05, range_max=8.0)


def run(pipeline, world, poses, movers_at, n, beams=lambda k: 361):
    results = []
    for k in range(n):
        t = 1.0 + k * DT
        pose = poses(t)
        pipeline.add_odometry(t - 0.05, poses(t - 0.05))
        pipeline.add_odometry(t, pose)
        pipeline.add_odometry(t + 0.05, poses(t + 0.05))
        results.append(pipeline.step(make_scan(world, pose, t, movers_at(t), beams(k), seed=k)))
    return results


def still(t):
    return np.array([0.0, 0.0, 0.0])


def test_a_moving_object_is_confirmed_with_its_velocity():
    world = room()
    v = np.array([0.0, 1.0])

    def mover(t):
        p = np.array([3.0, -3.0]) + v * (t - 1.0)
        return [(p[0], p[1], 0.12)]

    res = run(Pipeline(), world, still, mover, 30)
    first = next(k for k, r in enumerate(res) if r.newly_confirmed.size)
    assert first <= 8                             # two scans to create, four samples
    r = res[first]
    j = r.newly_confirmed[0]
    truth = np.array([3.0, -3.0]) + v * (r.stamp - 1.0)
    assert np.linalg.norm(r.hypotheses.position[j] - truth) < 0.3
    confirmed = [r.hypotheses.take(r.hypotheses.confirmed) for r in res[first:]]
    speeds = np.concatenate([h.velocity for h in confirmed if len(h)])
    assert np.allclose(np.median(speeds, axis=0), v, atol=0.25)
    ids = {int(i) for h in confirmed for i in h.track_id}
    assert len(ids) <= 2                          # one object, one (at most two) identity


def test_static_scene_from_a_moving_platform_gives_no_confirmed_track():
    world = room()

    def moving(t):                                # translating and turning
        return np.array([0.4 * (t - 1.0), 0.1 * math.sin(t), 0.25 * (t - 1.0)])

    pipeline = Pipeline()
    res = run(pipeline, world, moving, lambda t: [], 30)
    assert not any(r.hypotheses.confirmed.any() for r in res)
    assert all(r.skipped is None for r in res)
    assert sum(pipeline.sources.values()) == 30


def test_without_ego_motion_compensation_the_same_scene_lights_up():
    """The check above is not vacuous: with the platform's motion ignored (odometry
    claiming it stands still, ICP off) the static scene produces blobs."""
    world = room()

    def moving(t):
        return np.array([0.4 * (t - 1.0), 0.0, 0.25 * (t - 1.0)])

    config = PipelineConfig().replace(ego_motion={'min_points': 100000})   # ICP never runs
    pipeline = Pipeline(config)
    blobs = 0
    for k in range(10):
        t = 1.0 + k * DT
        pipeline.add_odometry(t, (0.0, 0.0, 0.0))
        pipeline.add_odometry(t + 0.1, (0.0, 0.0, 0.0))
        blobs += pipeline.step(make_scan(world, moving(t), t)).blobs.count
    assert blobs > 20


def test_bad_input_beam_count_change_nan_ranges_time_backwards(caplog):
    world = room()
    pipeline = Pipeline()

    def mover(t):
        return [(3.0, -3.0 + (t - 1.0), 0.12)]

    with caplog.at_level(logging.WARNING):
        res = run(pipeline, world, still, mover, 12, beams=lambda k: 361 if k < 6 else 181)
        nan_scan = make_scan(world, still(0), 1.0 + 12 * DT, mover(3.4))
        nan_scan.ranges[::3] = np.nan
        nan_scan.ranges[1::7] = -np.inf
        r = pipeline.step(nan_scan)
        assert r.skipped is None
        same = pipeline.step(nan_scan)                   # the same stamp again
        assert same.skipped == 'duplicate stamp'
        back = pipeline.step(make_scan(world, still(0), 0.5, mover(0.5)))   # backwards
        assert back.skipped is None
    assert any(r.blobs.count for r in res[6:])             # 181 beams still detect
    assert pipeline.stats['reset: time went backwards'] == 1
    assert pipeline.stats['skipped: duplicate stamp'] == 1
    assert 'backwards' in caplog.text


def test_detection_and_tracking_separately_equal_the_pipeline():
    world = room()
    config = PipelineConfig()

    def mover(t):
        return [(2.0 + 0.8 * (t - 1.0), 1.0, 0.1), (4.0, -2.0 + 0.9 * (t - 1.0), 0.1)]

    pipeline = Pipeline(config)
    res = run(pipeline, world, still, mover, 20)
    detector = Detector(config.grid, config.difference, config.blobs)
    tracker = Tracker(config.hypotheses, config.kalman)
    for r in res:
        scan = make_scan(world, still(r.stamp), r.stamp, mover(r.stamp),
                         seed=int(round((r.stamp - 1.0) / DT)))
        det = detector.detect(scan, r.pose)
        assert np.allclose(det.blobs.xy, r.blobs.xy)
        frame = tracker.update(det.blobs)
        assert np.array_equal(frame.hypotheses.track_id, r.hypotheses.track_id)
        assert np.allclose(frame.hypotheses.position, r.hypotheses.position)


def test_grids_on_request():
    world = room()
    pipeline = Pipeline()
    run(pipeline, world, still, lambda t: [], 2)
    r = pipeline.step(make_scan(world, still(0), 1.6, [(3.0, 0.0, 0.12)]), want_grids=True)
    n = pipeline.config.grid.cells
    det = r.detection
    assert det.grid.shape == det.previous.shape == det.difference.shape == (n, n)
    assert det.difference.any()                   # the object that appeared
    plain = pipeline.step(make_scan(world, still(0), 1.8, [(3.0, 0.0, 0.12)]))
    assert plain.detection.grid is None


def test_config_round_trip_and_errors():
    config = PipelineConfig()
    nodes = config.to_ros_params()
    assert set(nodes) == {'ego_motion', 'detection', 'tracking'}
    assert 'grid.resolution' in nodes['detection'] and 'kalman.q' in nodes['tracking']
    assert PipelineConfig.from_ros_params(nodes) == config
    nodes['tracking']['hypotheses.w_inc'] = 55.0
    nodes['other_node'] = {'anything': 1}          # other nodes of the file are left alone
    assert PipelineConfig.from_ros_params(nodes).hypotheses.w_inc == 55.0
    with pytest.raises(ConfigError, match='hypotheses.gate'):
        config.replace(hypotheses={'gate': -1.0})
    bad = config.to_ros_params()
    bad['detection']['grid.colour'] = 'red'
    with pytest.raises(ConfigError, match='colour'):
        PipelineConfig.from_ros_params(bad)
    bad = config.to_ros_params()
    bad['detection']['kalman.q'] = 0.1             # a tracking section under detection
    with pytest.raises(ConfigError, match='kalman.q'):
        PipelineConfig.from_ros_params(bad)


def test_paper_values_are_the_defaults_where_the_paper_gives_them():
    c = PipelineConfig()
    assert c.grid.resolution == 0.1
    assert (c.hypotheses.w_inc, c.hypotheses.w_dec) == (60.0, 15.0)
    assert c.hypotheses.confirm_samples == 4 and c.hypotheses.wall_factor == 0.5
    assert c.hypotheses.blob_radius == 50.0 and c.hypotheses.distance_unit == 0.1
    assert (c.kalman.mode, c.kalman.q, c.kalman.r) == ('paper', 0.0005, 0.006)
    assert dataclasses.is_dataclass(c) and c.difference.free_neighbourhood == 0


def test_motion_depth_keeps_movers_and_leaves_a_stationary_scanner_alone():
    world = room()

    def mover(t):                                 # crosses open space at 1 m/s
        return [(3.0, -3.0 + 1.0 * (t - 1.0), 0.12)]

    def near_wall(t):                             # walks along the x = 6 m wall, 0.3 m off
        return [(5.58, -3.0 + 1.0 * (t - 1.0), 0.12)]

    def moving(t):                                # the platform translates and turns
        return np.array([0.3 * (t - 1.0), 0.0, 0.1 * (t - 1.0)])

    paper = PipelineConfig().replace(difference={'motion_depth': 0.0})
    assert PipelineConfig().difference.motion_depth > 0
    # Stationary scanner: the motion-induced displacement is zero, so nothing changes, even
    # for an object right in front of a wall.
    a = run(Pipeline(), world, still, near_wall, 20)
    b = run(Pipeline(paper), world, still, near_wall, 20)
    for ra, rb in zip(a, b):
        assert np.array_equal(ra.blobs.xy, rb.blobs.xy)
    assert any(r.hypotheses.confirmed.any() for r in a)
    # Moving platform: a person in open space is still confirmed, moving the right way.
    res = run(Pipeline(), world, moving, mover, 25)
    confirmed = [r.hypotheses.take(r.hypotheses.confirmed) for r in res]
    vel = np.concatenate([h.velocity for h in confirmed if len(h)])
    assert vel.shape[0] >= 5
    assert np.median(vel[:, 1]) > 0.6
