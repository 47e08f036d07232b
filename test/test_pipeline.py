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
from laser_tracker.core.difference import PoseQuality
from laser_tracker.core.person_detector import PersonDetector, PersonDetectorConfig
from laser_tracker.core.pipeline import Pipeline, PipelineConfig
from laser_tracker.core.scan import Scan
from laser_tracker.core.stages import Detector, StampedPose, Tracker
from laser_tracker.tools.sim.world import World, cast

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


def stamped(stamp, pose, quality=None, body=None):
    """A StampedPose as the detection node builds it from the ego_motion topics."""
    return StampedPose(stamp=stamp, pose=np.asarray(pose, float), motion=np.zeros(3),
                       motion_covariance=np.zeros((3, 3)), pose_covariance=np.zeros((3, 3)),
                       quality=quality or PoseQuality(), body=body)


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
        blobs += pipeline.step(make_scan(world, moving(t), t)).detections.blobs.count
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
        assert same.skipped == 'ego-motion: duplicate stamp'
        back = pipeline.step(make_scan(world, still(0), 0.5, mover(0.5)))   # backwards
        assert back.skipped is None
    assert any(r.detections.blobs.count for r in res[6:])   # 181 beams still detect
    events = pipeline.events()
    assert events['ego_motion']['restart'] == 1
    assert events['ego_motion']['scan skipped: duplicate stamp'] == 1
    assert events['detection']['restart'] == 1 and events['tracking']['restart'] == 1
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
        # the returns ego-motion masked (the body, mixed returns) travel with the pose
        det = detector.update(scan, stamped(r.stamp, r.pose, body=r.ego.body))
        assert np.allclose(det.detections.blobs.xy, r.detections.blobs.xy)
        frame = tracker.update(det.detections)
        assert np.array_equal(frame.hypotheses.track_id, r.hypotheses.track_id)
        assert np.allclose(frame.hypotheses.position, r.hypotheses.position)


def test_the_view_keeps_the_returns_of_the_robots_body():
    """The view that goes to tracking is the scan as measured: the beams the self-mask takes
    as the robot's body keep their returns (the body hides what lies behind it), while
    detection does not see them."""
    world = room()
    detector = Detector()
    scan = make_scan(world, still(0), 1.0)
    body = np.full(scan.n_beams, np.nan)
    body[170:190] = scan.ranges[170:190] + 0.01
    det = detector.update(scan, stamped(1.0, still(0), body=body))
    assert len(det.detections.view) == scan.n_beams
    np.testing.assert_array_equal(det.detections.view.reach[170:190], scan.ranges[170:190])
    np.testing.assert_allclose(det.detections.view.bearing, scan.angles)


def test_detection_passes_the_bodys_returns_to_the_person_detector():
    """The person detector does not see the returns of the robot's body, but learns where
    they were: a lone leg-like segment that the body cuts is no person (masked_edge), one
    the body does not touch is."""
    from test_person_detector import width_classifier

    world = room()
    found = {}
    for name, body_bearing in (('cut', 0.14), ('apart', 0.6)):
        scan = make_scan(world, still(0), 1.0, [(1.4, 0.0, 0.06), (0.5 * math.cos(body_bearing),
                                                                   0.5 * math.sin(body_bearing),
                                                                   0.05)], noise=0.0)
        body = np.where(scan.ranges < 1.0, scan.ranges + 0.01, np.nan)
        detector = Detector()
        detector.person_detector = PersonDetector(PersonDetectorConfig(), width_classifier())
        det = detector.update(scan, stamped(1.0, still(0), body=body))
        people = det.persons
        at = int(np.argmin(np.hypot(*(people.leg_xy - [1.4, 0.0]).T)))
        found[name] = people.leg_probability[at], people.count
    assert found['cut'] == (detector.person_detector.partner_threshold, 0)
    assert found['apart'][1] == 1 and found['apart'][0] > found['cut'][0]


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


def test_config_replace_validates():
    config = PipelineConfig()
    assert config.replace(hypotheses={'w_inc': 55}).hypotheses.w_inc == 55.0
    with pytest.raises(ConfigError, match='hypotheses.gate'):
        config.replace(hypotheses={'gate': -1.0})
    nodes = config.to_ros_params()
    assert set(nodes) == {'ego_motion', 'detection', 'tracking'}
    assert 'grid.resolution' in nodes['detection'] and 'kalman.q' in nodes['tracking']


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
        assert np.array_equal(ra.detections.blobs.xy, rb.detections.blobs.xy)
    assert any(r.hypotheses.confirmed.any() for r in a)
    # Moving platform: a person in open space is still confirmed, moving the right way.
    res = run(Pipeline(), world, moving, mover, 25)
    confirmed = [r.hypotheses.take(r.hypotheses.confirmed) for r in res]
    vel = np.concatenate([h.velocity for h in confirmed if len(h)])
    assert vel.shape[0] >= 5
    assert np.median(vel[:, 1]) > 0.6


# ------------------------------------------------------------- ego-motion quality gate


def _estimate(source, inlier_ratio=0.9, var=1e-4, rms=0.02):
    """An ego-motion estimate; ``rms`` NaN = no ICP match was tried."""
    from laser_tracker.core.egomotion import EgoMotionEstimate
    return EgoMotionEstimate(stamp=1.0, pose=np.zeros(3), motion=np.zeros(3),
                             covariance=np.diag([var, var, var / 10]), source=source,
                             reason='test', inlier_ratio=inlier_ratio, rms=rms)


def test_pose_quality_of_estimates_and_its_covariance_form():
    from laser_tracker.conversions import (bag_factory, ego_motion_from_msgs,
                                           ego_motion_to_msgs)
    from laser_tracker.core.difference import DifferenceConfig, pose_quality, pose_trusted
    from laser_tracker.tools.bag import TYPESTORE
    factory = bag_factory(TYPESTORE)
    on = DifferenceConfig()
    off = DifferenceConfig(pose_gate=False)
    assert on.pose_gate and on.pose_min_inlier_ratio == 0.6
    cases = [  # estimate, trusted by the default gate
        (_estimate('icp', 0.9), True),
        (_estimate('icp_partial', 0.7), True),
        (_estimate('init', 0.0, rms=np.nan), True),    # first scan: nothing to match yet
        (_estimate('icp', 0.5), False),                # poor overlap
        (_estimate('odometry', 0.95), False),          # match tried and refused: odometry
        (_estimate('odometry', 0.0), False),
        (_estimate('odometry', 0.0, rms=np.inf), False),   # tried, nothing associated
        (_estimate('odometry', 0.0, rms=np.nan), True),    # no match possible: odometry
        (_estimate('none', 0.0, rms=np.nan), False),
        (_estimate('icp', 0.9, var=np.nan), False),    # a covariance that is not a number
    ]
    for est, trusted in cases:
        q = pose_quality(est)
        assert pose_trusted(q, on) is trusted, est.source
        assert pose_trusted(q, off)                # off: the previous behaviour
        # Across the ego_motion / ego_motion/status messages, bit for bit.
        msgs = ego_motion_to_msgs(factory, stamped(1.0, (1.0, 2.0, 0.3), q))
        back = ego_motion_from_msgs(*msgs).quality
        assert pose_trusted(back, on) is trusted
        assert back == q or (q.failed and back.failed)
    assert pose_quality(_estimate('icp', 0.9)).variance[0] == pytest.approx(1e-4)
    assert not pose_trusted(pose_quality(_estimate('icp', 0.5)),
                            DifferenceConfig(pose_min_inlier_ratio=0.6))
    assert pose_trusted(pose_quality(_estimate('icp', 0.5)),
                        DifferenceConfig(pose_min_inlier_ratio=0.0))
    # A pose without a status (another publisher) is trusted.
    odometry, _ = ego_motion_to_msgs(factory, stamped(1.0, (0.0, 0.0, 0.0)))
    assert pose_trusted(ego_motion_from_msgs(odometry).quality, on)
    assert pose_trusted(None, on) and pose_trusted(PoseQuality(), on)


def test_untrusted_pose_reports_no_blobs_and_keeps_the_grid_history():
    from laser_tracker.core.difference import pose_quality
    world = room()

    def moving(t):
        return np.array([0.3 * (t - 1.0), 0.0, 0.1 * (t - 1.0)])

    def mover(t):                                 # crosses in front of the platform
        return [(2.0 + 1.0 * (t - 1.0), 1.5, 0.15)]

    scans = [make_scan(world, moving(1.0 + k * DT), 1.0 + k * DT, mover(1.0 + k * DT), seed=k)
             for k in range(6)]
    good = pose_quality(_estimate('icp', 0.9))
    bad = {'odometry': pose_quality(_estimate('odometry', 0.9)),
           'low overlap': pose_quality(_estimate('icp', 0.45)),
           'failed variance': PoseQuality((1e6, 1e6, 1e6), 0.0)}
    config = PipelineConfig()
    for name, quality in bad.items():
        reference = Detector(config.grid, config.difference, config.blobs)
        gated = Detector(config.grid, config.difference, config.blobs)
        off = Detector(config.grid, dataclasses.replace(config.difference, pose_gate=False),
                       config.blobs)
        for k, scan in enumerate(scans):
            pose = moving(scan.stamp)
            q = quality if k == 3 else good
            ref = reference.update(scan, stamped(scan.stamp, pose, good))
            det = gated.update(scan, stamped(scan.stamp, pose, q))
            det_off = off.update(scan, stamped(scan.stamp, pose, q))
            assert np.array_equal(det_off.detections.blobs.xy,        # off: as before
                                  ref.detections.blobs.xy)
            if k == 3:
                assert ref.detections.blobs.count > 0, \
                    'the mover should be a blob on a trusted scan'
                assert det.gated and det.detections.blobs.count == 0 and det.changed == 0, name
                assert not ref.gated and not det_off.gated
            else:
                assert not det.gated
                # The gated scan's grid stayed in the history: the next scan is compared
                # with it exactly as without the gate (no restart, no lost scan).
                assert np.array_equal(det.detections.blobs.xy, ref.detections.blobs.xy), (name, k)
            if k == 4:
                assert det.detections.blobs.count > 0, 'the scan after the gated one reports'


def test_pipeline_withholds_blobs_of_a_scan_placed_by_odometry_and_tracking_coasts():
    world = room()

    def mover(t):
        return [(3.0, -3.0 + 1.0 * (t - 1.0), 0.12)]

    def run_with(config, bad_scans):
        pipeline = Pipeline(config)
        update = pipeline.ego.estimator.update
        k = {'n': 0}

        def degraded(scan):   # ICP "refused" on the chosen scans: odometry used
            est = update(scan)
            if k['n'] in bad_scans:
                est = dataclasses.replace(est, source='odometry', reason='test: ICP refused')
            k['n'] += 1
            return est

        pipeline.ego.estimator.update = degraded
        return pipeline, run(pipeline, world, still, mover, 16)

    bad = {10}
    pipeline, res = run_with(PipelineConfig(), bad)
    _, ref = run_with(PipelineConfig(), set())
    _, off = run_with(PipelineConfig().replace(difference={'pose_gate': False}), bad)
    count = [r[10].detections.blobs.count for r in (ref, off)]
    assert count[0] > 0 and count[1] == count[0]
    assert res[10].detections.blobs.count == 0 and res[10].detection.gated
    assert pipeline.events()['detection']['gated'] == 1
    for k in range(10):
        assert np.array_equal(res[k].detections.blobs.xy, ref[k].detections.blobs.xy)
    assert res[11].detections.blobs.count > 0        # the next scan reports again
    # The confirmed track coasts through the gated scan and keeps its identity.
    before = set(res[9].hypotheses.track_id[res[9].hypotheses.confirmed].tolist())
    during = set(res[10].hypotheses.track_id[res[10].hypotheses.confirmed].tolist())
    after = set(res[12].hypotheses.track_id[res[12].hypotheses.confirmed].tolist())
    assert before and before & during & after


def _same_results(a, b):
    """Every scan's pose, detections and hypotheses, to the bit."""
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.skipped == y.skipped and x.source == y.source
        for u, v in ((x.pose, y.pose), (x.motion, y.motion),
                     (x.detections.blobs.xy, y.detections.blobs.xy),
                     (x.detections.people.xy, y.detections.people.xy),
                     (x.detections.segments.xy, y.detections.segments.xy),
                     (x.newly_confirmed, y.newly_confirmed)):
            assert u.dtype == v.dtype and u.shape == v.shape and u.tobytes() == v.tobytes()
        rows, others = x.hypotheses.rows, y.hypotheses.rows
        assert rows.dtype == others.dtype and rows.shape == others.shape
        for name in rows.dtype.names:                  # field by field: not the padding
            assert rows[name].tobytes() == others[name].tobytes(), name


def test_the_warm_up_keeps_nothing(monkeypatch):
    """The pipeline's warm-up (synthetic scans through a pipeline of its own, once per
    process, its first scan rehearsing the first match) leaves nothing behind: a pipeline
    made after it runs again gives the same results to the bit as one made before, and
    one that rehearses its own first match too."""
    from laser_tracker.core import egomotion, pipeline as pipeline_module, stages

    world = room()

    def mover(t):
        return [(2.0 + 0.8 * (t - 1.0), 1.0, 0.1), (4.0, -2.0 + 0.9 * (t - 1.0), 0.1)]

    def poses(t):
        return np.array([0.1 * (t - 1.0), 0.0, 0.02 * (t - 1.0)])

    before = run(Pipeline(), world, poses, mover, 15)
    assert 'pipeline' in stages._warmed                  # once per process, already run
    monkeypatch.setattr(egomotion, '_rehearsed', [])
    pipeline_module._warm_up_pipeline()
    assert egomotion._rehearsed == [True]                # the warm-up rehearsed, not ...
    after = run(Pipeline(), world, poses, mover, 15)
    assert egomotion._rehearsed == [True]                # ... the pipeline's first scan
    monkeypatch.setattr(egomotion, '_rehearsed', [])
    rehearsing = run(Pipeline(), world, poses, mover, 15)
    assert egomotion._rehearsed == [True]
    assert any(len(r.hypotheses.track_id) for r in before)
    _same_results(before, after)
    _same_results(before, rehearsing)


def _front_and_rear(world, poses, n, frames=('laser_front', 'laser_rear')):
    """Scans of two scanners on one topic, interleaved: one at the platform facing ahead,
    one at the same place facing back (half a scan period later)."""
    scans = []
    for k in range(n):
        t = 1.0 + k * DT
        front = make_scan(world, poses(t), t, seed=k)
        front.frame_id = frames[0]
        x, y, th = poses(t + DT / 2)
        rear = make_scan(world, (x, y, th + math.pi), t + DT / 2, seed=1000 + k)
        rear.frame_id = frames[1]
        scans += [front, rear]
    return scans


def _replay(pipeline, scans, poses):
    results = []
    for scan in scans:
        for dt in (-0.05, 0.0, 0.05):
            pipeline.add_odometry(scan.stamp + dt, poses(scan.stamp + dt))
        results.append(pipeline.step(scan))
    return results


def test_a_second_scanner_on_the_same_topic_is_skipped_with_one_warning(caplog):
    """Two scanners publishing on one topic: the pipeline follows the first scan's frame and
    skips the other's scans, saying why (matching one scanner's view against the other's
    would move every wall); what it makes of the followed scanner's scans is what it makes
    of them alone."""
    world = room()

    def moving(t):
        return np.array([0.4 * (t - 1.0), 0.1 * math.sin(t), 0.25 * (t - 1.0)])

    scans = _front_and_rear(world, moving, 24)
    with caplog.at_level(logging.WARNING):
        both = _replay(Pipeline(), scans, moving)
    alone = _replay(Pipeline(), scans[0::2], moving)
    rear = both[1::2]
    assert all('laser_rear' in r.skipped and 'one scanner per pipeline' in r.skipped
               for r in rear)
    for a, b in zip(both[0::2], alone):
        assert a.skipped is None and b.skipped is None
        assert np.array_equal(a.pose, b.pose)
        assert np.array_equal(a.hypotheses.track_id, b.hypotheses.track_id)
    assert not any(r.hypotheses.confirmed.any() for r in alone)
    warnings = [r for r in caplog.records if 'another scanner' in r.getMessage()]
    assert len(warnings) == 2          # the first and the 10th of 24 (no flood)
    assert "'laser_rear'" in warnings[0].getMessage()
    assert "'laser_front'" in warnings[0].getMessage()


def test_two_scanners_taken_for_one_would_move_the_walls():
    """The rule above is needed: the same scans with one frame name for both scanners are
    matched against each other, and the static room seen from a moving platform is not
    static any more."""
    world = room()

    def moving(t):
        return np.array([0.4 * (t - 1.0), 0.1 * math.sin(t), 0.25 * (t - 1.0)])

    scans = _front_and_rear(world, moving, 24, frames=('laser', 'laser'))
    mixed = _replay(Pipeline(), scans, moving)
    alone = _replay(Pipeline(), scans[0::2], moving)
    blobs = sum(r.detections.blobs.count for r in mixed if r.skipped is None)
    assert blobs > 4 * sum(r.detections.blobs.count for r in alone) + 20


def test_a_scanner_that_falls_silent_is_followed_by_the_next_frame(caplog):
    """A driver restarted under another frame name: once the followed scanner has sent
    nothing for SCANNER_SILENCE, the pipeline restarts on the new frame (with a warning),
    and a leading slash does not make another frame."""
    from laser_tracker.core.stages import SCANNER_SILENCE
    world = room()
    scans = _front_and_rear(world, still, 40, frames=('laser', 'laser_new'))
    scans[2].frame_id = '/laser'
    stop = 10.0 * DT                       # the front scanner stops here
    stream = [s for s in scans if s.frame_id.lstrip('/') != 'laser' or s.stamp < 1.0 + stop]
    with caplog.at_level(logging.WARNING):
        pipeline = Pipeline()
        results = _replay(pipeline, stream, still)
    last_front = max(s.stamp for s in stream if s.frame_id.lstrip('/') == 'laser')
    for s, r in zip(stream, results):
        if s.frame_id.lstrip('/') == 'laser':
            assert r.skipped is None
        elif s.stamp - last_front <= SCANNER_SILENCE:
            assert 'one scanner per pipeline' in r.skipped
        else:
            assert r.skipped is None, (s.stamp, r.skipped)
    assert pipeline.events()['ego_motion']['scanner changed'] == 1
    assert pipeline.events()['ego_motion']['restart'] == 1
    assert "following 'laser_new'" in caplog.text


def test_a_scanner_hung_upside_down_is_turned_over_by_its_mount_parameter():
    """``ego_motion.mount_upside_down``: the scans of a scanner hung upside down (each the
    mirror image of the level scanner's) give the poses, blobs and tracks of the level
    scanner, and the result's scan is the level one; taken as level they do not."""
    world = room()

    def moving(t):
        return np.array([0.3 * (t - 1.0), 0.0, 0.2 * (t - 1.0)])

    def mover(t):
        return [(3.0, -3.0 + (t - 1.0), 0.12)]

    def replay(config, turn_over):
        pipeline, results = Pipeline(config), []
        for k in range(30):
            t = 1.0 + k * DT
            for dt in (-0.05, 0.0, 0.05):
                pipeline.add_odometry(t + dt, moving(t + dt))
            scan = make_scan(world, moving(t), t, mover(t), seed=k)
            results.append(pipeline.step(scan.mirrored() if turn_over else scan))
        return results

    upside_down = PipelineConfig().replace(ego_motion={'mount_upside_down': True})
    level = replay(PipelineConfig(), False)
    turned = replay(upside_down, True)
    assert any(r.hypotheses.confirmed.any() for r in level)
    for a, b in zip(level, turned):
        assert b.ego.mirrored and not a.ego.mirrored
        np.testing.assert_allclose(b.pose, a.pose, atol=1e-9)
        np.testing.assert_allclose(b.detections.blobs.xy, a.detections.blobs.xy, atol=1e-9)
        assert np.array_equal(b.hypotheses.track_id, a.hypotheses.track_id)
        np.testing.assert_allclose(b.hypotheses.position, a.hypotheses.position, atol=1e-9)
        np.testing.assert_allclose(b.scan.ranges, a.scan.ranges)
    taken_as_level = replay(PipelineConfig(), True)
    drift = max(abs(b.pose[2] - a.pose[2]) for a, b in zip(level, taken_as_level))
    assert drift > 0.5                 # it turns against the odometry
