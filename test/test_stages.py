"""The stream rules, one suite against every stage (core.stages): what a misbehaving stream
does (a duplicate, time going backwards, a gap, an invalid stamp, a restarted pose chain)
is answered by the stage itself, identically offline and in the nodes."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.core.detections import Blobs, Detections
from laser_tracker.core.difference import PoseQuality
from laser_tracker.core.scan import Scan, ScanError
from laser_tracker.core.stages import Detector, EgoMotion, Head, StampedPose, Tracker
from laser_tracker.core.stream import OdometryWait, StampPairer, StreamRules

DT = 0.2


def ring_scan(stamp: float, mover_y: float | None = None) -> Scan:
    """A scanner in a 4 m circular room; optionally a 0.15 m post at (2, mover_y)."""
    angles = np.linspace(-math.pi / 2, math.pi / 2, 361)
    r = np.full(angles.size, 4.0)
    if mover_y is not None:
        c = np.array([2.0, mover_y])
        d = np.column_stack((np.cos(angles), np.sin(angles)))
        b = d @ c
        disc = b * b - (c @ c - 0.15 ** 2)
        hit = (disc > 0) & (b > 0)
        r = np.where(hit, np.minimum(r, b - np.sqrt(np.maximum(disc, 0))), r)
    return Scan(stamp=stamp, ranges=r, angle_min=-math.pi / 2,
                angle_increment=math.pi / 360, range_min=0.05, range_max=8.0)


def pose(stamp: float, restarted: bool = False) -> StampedPose:
    return StampedPose(stamp=stamp, pose=np.zeros(3), motion=np.zeros(3),
                       motion_covariance=np.zeros((3, 3)), pose_covariance=np.zeros((3, 3)),
                       quality=PoseQuality(restarted=restarted))


def blobs(stamp: float, x: float, restarted: bool = False) -> Detections:
    return Detections(stamp=stamp, origin=np.zeros(3), restarted=restarted,
                      blobs=Blobs(xy=np.array([[x, 1.0]]), cells=np.array([3]),
                                  extent=np.array([0.2]), structure=np.array([np.nan])))


# --------------------------------------------------------------------- harnesses
# Each feeds one item at a stamp and says whether the stage still holds history from
# before (``remembers``), so that one suite states the rules for all of them.


class EgoHarness:
    gap_rule = False          # ego-motion bridges gaps on its motion model / odometry

    def __init__(self):
        self.stage = EgoMotion()
        self.last = None

    def feed(self, t, restarted=False):
        out = self.stage.update(ring_scan(t))
        self.last = out if out is not None else self.last
        return out

    def remembers(self) -> bool:
        return self.last is not None and not self.last.quality.restarted


class DetectorHarness:
    gap_rule = True

    def __init__(self):
        self.stage = Detector()
        self.y = -2.0

    def feed(self, t, restarted=False):
        self.y = -2.0 + t          # a post walking at 1 m/s: a blob whenever there is history
        return self.stage.update(ring_scan(t, self.y), pose(t, restarted))

    def remembers(self) -> bool:
        return self.stage.previous is not None


class TrackerHarness:
    gap_rule = True

    def __init__(self):
        self.stage = Tracker()

    def feed(self, t, restarted=False):
        return self.stage.update(blobs(t, 1.0 * t, restarted))

    def remembers(self) -> bool:
        return len(self.stage.hypotheses.hyp) > 0


HARNESSES = {'ego_motion': EgoHarness, 'detection': DetectorHarness,
             'tracking': TrackerHarness}


def warm(h, n=6):
    for k in range(n):
        assert h.feed(1.0 + k * DT) is not None
    return 1.0 + (n - 1) * DT


@pytest.mark.parametrize('name', HARNESSES)
def test_a_duplicate_stamp_is_skipped_and_history_is_kept(name):
    h = HARNESSES[name]()
    t = warm(h)
    assert h.remembers()
    assert h.feed(t) is None
    assert h.stage.skipped == 'duplicate stamp'
    assert h.remembers()                                  # not a restart
    assert h.feed(t + DT) is not None


@pytest.mark.parametrize('name', HARNESSES)
def test_time_going_backwards_restarts_the_stage(name):
    h = HARNESSES[name]()
    warm(h)
    out = h.feed(0.5)
    assert out is not None
    assert h.stage.events.counts['restart'] == 1
    if name == 'ego_motion':
        assert out.quality.restarted                      # downstream stages are told
    elif name == 'detection':
        assert out.detections.blobs.count == 0       # a first scan: nothing to compare
    else:
        assert len(out.hypotheses) == 0
    warm(h, 3)                                            # and it carries on from there


@pytest.mark.parametrize('name', HARNESSES)
def test_a_long_gap_drops_what_it_makes_stale(name):
    h = HARNESSES[name]()
    t = warm(h)
    out = h.feed(t + 60.0)
    assert out is not None
    if h.gap_rule:
        stale = h.stage.events.counts['history dropped'] + h.stage.events.counts['restart']
        assert stale == 1
        if name == 'tracking':
            assert len(out.hypotheses) == 0
        else:
            assert out.detections.blobs.count == 0
    else:
        assert not out.quality.restarted                 # the pose chain goes on


@pytest.mark.parametrize('name', ['detection', 'tracking'])
def test_a_restarted_pose_chain_voids_the_history(name):
    h = HARNESSES[name]()
    t = warm(h)
    out = h.feed(t + DT, restarted=True)
    assert out is not None
    if name == 'tracking':
        assert len(out.hypotheses) == 0
    else:
        assert out.detections.blobs.count == 0 and out.detections.restarted


def test_invalid_stamps_never_reach_a_stage():
    for bad in (math.nan, math.inf, -1.0):
        with pytest.raises(ScanError):
            ring_scan(bad)
    tracker = Tracker()
    assert tracker.update(blobs(math.nan, 0.0)) is None
    assert tracker.update(blobs(-3.0, 0.0)) is None
    assert tracker.events.counts['blobs skipped: invalid stamp'] == 2
    head = Head()
    head.add_pose(pose(1.0))
    assert head.update(math.nan, [(1, 1.0, 0.0, 0.0, 0.0, 50.0)]) is None


def test_second_publisher_on_blobs_changes_nothing():
    """Every blobs message twice (two publishers): the tracker output equals one stream."""
    once, twice = Tracker(), Tracker()
    for k in range(12):
        t = 1.0 + k * DT
        a = once.update(blobs(t, t))
        b = twice.update(blobs(t, t))
        assert twice.update(blobs(t, t)) is None
        assert a.hypotheses.rows.tobytes() == b.hypotheses.rows.tobytes()
    assert twice.events.counts['blobs skipped: duplicate stamp'] == 12
    assert 'restart' not in twice.events.counts


def test_head_needs_a_recent_pose_and_restarts_when_time_goes_back():
    head = Head(max_pose_age=0.5)
    track = [(7, 2.0, 0.0, 0.0, 1.0, 80.0)]
    assert head.update(1.0, track) is None                 # no pose yet
    head.add_pose(pose(1.0))
    cmd = head.update(1.1, track)
    assert cmd is not None and cmd.track_id == 7 and cmd.pan > 0   # leads the target left
    assert head.update(2.0, track) is None                 # the pose is 0.9 s old
    head.add_pose(pose(0.2))                               # pose time went backwards
    assert head.events.counts['restart'] == 1
    assert head.update(0.3, track) is not None


# -------------------------------------------------------------------- odometry wait


def test_odometry_that_stops_costs_the_wait_once_then_scans_flow():
    ego = EgoMotion(odom_wait=1.0)
    released = []
    t = 1.0
    for k in range(10):                                   # odometry and scans at 10 Hz
        ego.add_odometry(t, (0.0, 0.0, 0.0), arrival=t)
        released += ego.add_scan(ring_scan(t), arrival=t + 0.01)
        t += 0.1
    assert len(released) == 10
    # Odometry stops. The first scan after it waits the full second...
    delays = []
    for k in range(30):
        scan = ring_scan(t)
        arrival = t + 0.01
        for s, _, _ in ego.add_scan(scan, arrival=arrival):
            delays.append(arrival - s.stamp)
        t += 0.1
    # ...once: after that, every scan flows at once.
    assert ego.wait.stalls == 1
    assert len(delays) >= 25 and max(delays[-15:]) < 0.05
    # Odometry back: scans wait for it again (and are released by it).
    ego.add_odometry(t, (0.0, 0.0, 0.0), arrival=t)
    assert ego.add_scan(ring_scan(t + 0.05), arrival=t + 0.06) == []
    out = ego.add_odometry(t + 0.1, (0.0, 0.0, 0.0), arrival=t + 0.1)
    assert len(out) == 1 and out[0][2] is not None


def test_odometry_wait_releases_by_odometry_and_by_time():
    wait = OdometryWait(max_wait=1.0)
    wait.add_odometry(0.0, 0.0)
    assert wait.add_scan(0.25, 0.2, 's1') == []
    assert wait.add_odometry(0.5, 0.3) == ['s1']
    assert wait.add_scan(0.6, 0.55, 's2') == []
    assert wait.release(1.5) == []
    assert wait.release(1.7) == ['s2'] and wait.stalls == 1


def test_stamp_pairer_joins_three_streams_in_any_order_and_drops_the_unmatchable():
    got = []
    pairer = StampPairer(('scan', 'pose', 'status'), got.append, depth=4)
    pairer.add('pose', 10, 'p10')
    pairer.add('scan', 10, 's10')
    assert got == []
    pairer.add('status', 10, 'q10')
    assert got == [{'pose': 'p10', 'scan': 's10', 'status': 'q10'}]
    pairer.add('scan', 20, 's20')                          # never completed
    pairer.add('status', 30, 'q30')
    pairer.add('scan', 30, 's30')
    pairer.add('pose', 30, 'p30')
    assert got[-1]['scan'] == 's30' and pairer.dropped == 1 and not pairer.pending
    with pytest.raises(ValueError):
        pairer.add('laser', 40, 'x')


def test_stream_rules_classify():
    rules = StreamRules(max_gap=1.0)
    assert rules.classify(1.0) == 'first'
    rules.accept(1.0)
    assert [rules.classify(t) for t in (1.0, 0.5, 2.5, 1.5, math.nan, -1.0)] == [
        'duplicate', 'backwards', 'gap', 'next', 'invalid', 'invalid']


def test_a_reset_detector_reuses_its_background_and_equals_a_new_one():
    """A reset (time going backwards) clears the static background in place (its memory
    kept) and detects what a new detector detects, to the bit."""
    from laser_tracker.core.stages import warm_up_scene

    def scans(first):
        for k in range(first, first + 8):
            scan, at, _ = warm_up_scene(k)
            yield scan, StampedPose(stamp=scan.stamp, pose=np.array(at), motion=np.zeros(3),
                                    motion_covariance=np.zeros((3, 3)),
                                    pose_covariance=np.zeros((3, 3)), quality=PoseQuality())

    used = Detector()
    for scan, at in scans(10):
        used.update(scan, at)
    background = used.background
    assert (background.count > 0).any()
    fresh = Detector()
    for (scan, at), k in zip(scans(0), range(8)):
        a, b = used.update(scan, at), fresh.update(scan, at)    # the first: time went back
        assert np.array_equal(a.detections.blobs.xy, b.detections.blobs.xy)
        assert np.array_equal(a.detections.people.xy, b.detections.people.xy)
        assert a.changed == b.changed
    assert used.background is background
    for name in ('key', 'count', 'last'):
        assert np.array_equal(getattr(used.background, name), getattr(fresh.background, name))
    assert used.background.previous == fresh.background.previous


def test_switching_the_footprint_rule_on_rebuilds_the_ray_tables():
    """difference.footprint reads each cell's beam span from the ray tables, which hold it
    only when built for it: switching the rule at run time rebuilds them (else the rule
    would silently look at the centre beam alone)."""
    from dataclasses import replace

    from laser_tracker.core.blobs import BlobConfig
    from laser_tracker.core.difference import DifferenceConfig
    from laser_tracker.core.grid import GridConfig

    det = Detector(difference=DifferenceConfig(footprint=False))
    det.update(ring_scan(0.0), pose(0.0))
    table = det.builder.table(ring_scan(0.0))
    assert (table.rays[1] == table.rays[2]).all()          # no spans without the rule
    det.reconfigure(GridConfig(), replace(det.difference_config, footprint=True), BlobConfig())
    assert det.builder.footprints
    det.update(ring_scan(DT), pose(DT))
    table = det.builder.table(ring_scan(DT))
    assert (table.rays[2] > table.rays[1]).any()           # near cells span several beams


def test_scans_whose_stamp_is_never_set_are_named_as_such(caplog):
    """A driver that leaves header.stamp at 0: the scans after the first are duplicates, and
    the warning says what the 0 means."""
    import logging
    stage = EgoMotion()
    with caplog.at_level(logging.WARNING):
        assert stage.update(ring_scan(0.0)) is not None
        assert stage.update(ring_scan(0.0)) is None
    assert stage.skipped == 'duplicate stamp'
    assert 'never sets it' in caplog.text


def test_a_40_hz_scanner_is_thinned_to_ten_scans_a_second_and_still_sees_a_walker(caplog):
    """Detection uses every fourth scan of a 40 Hz scanner (difference.max_scan_rate), says
    so once (not per scan), and the walker shows as blobs on the scans it uses; with the
    rule off every scan is used."""
    import logging
    from dataclasses import replace

    from laser_tracker.core.blobs import BlobConfig
    from laser_tracker.core.grid import GridConfig

    det = Detector()
    used, blobs_seen = [], 0
    with caplog.at_level(logging.INFO, logger='laser_tracker.core.stages'):
        for k in range(80):                       # 2 s; a post walking at 1 m/s
            t = 1.0 + k / 40.0
            out = det.update(ring_scan(t, -2.0 + (t - 1.0)), pose(t))
            if out is None:
                assert det.skipped == 'thinned to difference.max_scan_rate'
                continue
            used.append(k)
            blobs_seen += out.detections.blobs.count > 0
    assert np.diff(used[3:]).tolist() == [4] * (len(used) - 4)
    assert det.events.counts['scans thinned'] == 80 - len(used)
    assert blobs_seen >= len(used) - 6                 # the walker, once there is history
    assert caplog.text.count('scans thinned') <= 3     # the 1st and 10th (and a 100th)
    assert '40.0 Hz' in caplog.text
    det.reconfigure(GridConfig(), replace(det.difference_config, max_scan_rate=0.0),
                    BlobConfig())
    assert all(det.update(ring_scan(3.0 + k / 40.0), pose(3.0 + k / 40.0)) is not None
               for k in range(8))


def test_the_view_marks_the_returns_on_static_background():
    """Returns where the scans have seen something for difference.static_occupied seconds
    are on static background: none at the first scan, the room's wall after 1.2 s, not a
    post that has just appeared (nor the wall behind it, hidden now), and none without a
    background (difference.static_time 0)."""
    from dataclasses import replace
    detector = Detector()
    first = detector.update(ring_scan(0.0), pose(0.0)).detections.view
    assert len(first) == 361 and not first.background.any()
    for k in range(1, 13):
        detector.update(ring_scan(0.1 * k), pose(0.1 * k))
    view = detector.update(ring_scan(1.3, mover_y=0.0), pose(1.3)).detections.view
    post = view.reach < 3.0
    assert 5 < post.sum() < 20
    assert view.background[~post].all() and not view.background[post].any()
    off = Detector(difference=replace(detector.difference_config, static_time=0.0))
    for k in range(14):
        view = off.update(ring_scan(0.1 * k), pose(0.1 * k)).detections.view
    assert len(view) == 361 and not view.background.any()


def test_each_segment_says_how_long_its_place_has_been_seen_occupied():
    """A post seen for 1.3 s has been occupied for 1.2 s before this scan (each scan after
    the first adds the 0.1 s since the one before), decayed with static_time (10 s); the
    same post seen first now, not at all (someone who has just walked there); without a
    background (static_time 0) it is not known."""
    from dataclasses import replace
    def post_occupied(detector, first_post):
        for k in range(14):
            d = detector.update(ring_scan(0.1 * k, mover_y=0.0 if k >= first_post else None),
                                pose(0.1 * k)).detections
        at = np.hypot(*(d.segments.xy - (2.0, 0.0)).T) < 0.2
        assert at.sum() == 1
        return d.segments.occupied[at] if d.segments.occupied.size else None
    decayed = sum(0.1 * math.exp(-(1.3 - 0.1 * k) / 10.0) for k in range(1, 13))
    assert post_occupied(Detector(), 0)[0] == pytest.approx(decayed, abs=0.05)
    assert post_occupied(Detector(), 13)[0] == 0.0
    off = Detector(difference=replace(Detector().difference_config, static_time=0.0))
    assert post_occupied(off, 0) is None
