"""Motion evidence beyond Eq. 1: free space remembered over a short window, and the static
background (how long each place of the odometry frame has been seen occupied)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.core.difference import (DifferenceConfig, StaticBackground,
                                           changed_with_history)
from laser_tracker.core.grid import GridBuilder, GridConfig, GridHistory
from laser_tracker.core.scan import Scan
from laser_tracker.core.stages import Detector, StampedPose
from laser_tracker.core.difference import PoseQuality


def test_a_wall_seen_for_a_second_is_static_a_passer_by_is_not():
    bg = StaticBackground(0.1, DifferenceConfig(static_time=10.0, static_occupied=0.75))
    wall = np.column_stack((np.linspace(0, 3, 31), np.full(31, 2.0)))
    for k in range(6):                      # 5 Hz: 1.2 s of the wall
        t = 0.2 * k
        leg = np.array([[0.5 + 0.2 * k, 0.0]])   # a leg moving 1 m/s, one scan per cell
        bg.add(np.vstack((wall, leg)), t)
    assert bg.static(wall + 0.03, 1.2).all()                 # registration error tolerated
    assert not bg.static(np.array([[1.5, 0.0]]), 1.2).any()  # the leg's path: 0.2 s each
    assert not bg.static(np.array([[1.5, 1.0]]), 1.2).any()  # never seen
    # decays: a minute later the wall is forgotten
    assert not bg.static(wall, 70.0).any()


def test_background_counts_seconds_not_scans():
    """The same place seen for the same time is static at 4 Hz and at 75 Hz alike."""
    cfg = DifferenceConfig(static_time=10.0, static_occupied=0.75)
    for rate in (4.0, 75.0):
        bg = StaticBackground(0.1, cfg)
        point = np.array([[1.0, 1.0]])
        for k in range(int(0.5 * rate)):     # half a second: not yet static
            bg.add(point, k / rate)
        assert not bg.static(point, 0.5)
        for k in range(int(0.5 * rate), int(1.0 * rate) + 1):
            bg.add(point, k / rate)
        assert bg.static(point, 1.0), rate


@pytest.mark.parametrize('later', [1.3, 4.0, 9.0, 40.0])
def test_the_beams_on_static_background_are_those_whose_end_points_are_static(later):
    """``on_returns`` (per beam, from a pose; sharing a cell's answer between beams) and
    ``static`` (per point; both stop at the first static cell) agree with the largest
    decayed occupancy around the beams' end points (``counts``) against static_occupied,
    on part of the scene seen long, part seen once, beams without a return and a
    background decaying with time."""
    bg = StaticBackground(0.1, DifferenceConfig(static_time=10.0, static_occupied=0.75))
    bearing = np.linspace(-2.3, 2.3, 768)
    reach = 3.0 + 2.0 * np.sin(3.0 * bearing)
    reach[::7], reach[3::11], reach[5::13] = np.inf, np.nan, -np.inf
    pose = np.array([0.3, -0.2, 0.4])
    seen = np.isfinite(reach)
    r = np.where(seen, reach, 0.0)
    ends = np.column_stack((pose[0] + r * np.cos(bearing + pose[2]),
                            pose[1] + r * np.sin(bearing + pose[2])))
    for k in range(12):
        bg.add(ends[seen][:300], 0.1 * k)
    bg.add(ends[seen][300:400], 1.2)
    on = bg.on_returns(bearing, reach, pose, later)
    occupied = bg.counts(ends, later) >= 0.75
    assert on.tolist() == (seen & occupied).tolist()
    assert bg.static(ends, later).tolist() == occupied.tolist()
    assert (on.sum() > 250) == (later < 5.0) and not on[~seen].any()


def test_far_away_cells_sharing_a_slot_do_not_alias():
    bg = StaticBackground(0.1, DifferenceConfig(static_time=10.0, static_occupied=0.1),
                          size=64)
    here = np.array([[1.05, 1.05]])
    there = here + 6.4 * 3                  # 3 grid sizes away: the same slots
    for k in range(5):
        bg.add(here, 0.2 * k)
    assert bg.static(here, 1.0) and not bg.static(there, 1.0)


def _room_scan(stamp, pose, post=None):
    """A scanner at ``pose`` in a 10 x 10 m room; optionally a 0.15 m post at ``post``."""
    angles = np.linspace(-math.pi / 2, math.pi / 2, 361)
    x, y, th = pose
    d = np.column_stack((np.cos(th + angles), np.sin(th + angles)))
    with np.errstate(divide='ignore'):
        tx = np.where(d[:, 0] > 0, (5 - x) / d[:, 0], np.where(d[:, 0] < 0, (-5 - x) / d[:, 0],
                                                                np.inf))
        ty = np.where(d[:, 1] > 0, (5 - y) / d[:, 1], np.where(d[:, 1] < 0, (-5 - y) / d[:, 1],
                                                                np.inf))
    r = np.minimum(tx, ty)
    if post is not None:
        c = np.asarray(post) - (x, y)
        b = d @ c
        disc = b * b - (c @ c - 0.15 ** 2)
        r = np.where((disc > 0) & (b > 0), np.minimum(r, b - np.sqrt(np.maximum(disc, 0))), r)
    return Scan(stamp=stamp, ranges=r, angle_min=-math.pi / 2, angle_increment=math.pi / 360,
                range_min=0.05, range_max=8.0)


def _pose(stamp, pose):
    return StampedPose(stamp=stamp, pose=np.asarray(pose, float), motion=np.zeros(3),
                       motion_covariance=np.zeros((3, 3)), pose_covariance=np.zeros((3, 3)),
                       quality=PoseQuality())


def test_structure_seen_before_is_never_a_change_with_the_static_background():
    """A post that stood in view for seconds, hidden for one scan then misregistered by
    0.15 m (an ego-motion slip), is not a moving object with the background; it is without."""
    def run(static_time):
        det = Detector(difference=DifferenceConfig(static_time=static_time, memory=0,
                                                   free_window=0.0))
        blobs = 0
        for k in range(12):
            t = 0.2 * k
            post = (3.0, 1.0) if k < 10 else (3.0, 1.15)     # the slip
            hidden = k == 9                                  # not seen just before it
            out = det.update(_room_scan(t, (0, 0, 0), None if hidden else post),
                             _pose(t, (0, 0, 0)))
            if k >= 10:
                blobs += out.detections.blobs.count
        return blobs
    assert run(0.0) > 0
    assert run(10.0) == 0


def test_free_window_sees_a_walker_entering_the_previous_scans_shadow():
    """The cell a walker steps into was hidden (in its own shadow) in the previous scan but
    seen free just before: a change with a free window, none with Eq. 1 alone."""
    def run(window):
        det = Detector(difference=DifferenceConfig(free_window=window, memory=0,
                                                   static_time=0.0, motion_depth=0.0))
        seen = []
        posts = [None, None, (3.0, 0.0), (3.3, 0.0)]   # appears at 3.0, then steps back to
        for k, post in enumerate(posts):              # 3.3, into its own shadow
            t = 0.1 * k
            seen.append(det.update(_room_scan(t, (0, 0, 0), post), _pose(t, (0, 0, 0))))
        return seen[-1].detections.blobs.count
    assert run(0.0) == 0
    assert run(0.3) > 0


def _one_degree_scan(stamp, ranges):
    """181 beams over 180 deg at 1 deg; beam 90 + k points k deg left; 6 m where not set."""
    r = np.full(181, 6.0)
    for k, v in ranges.items():
        r[90 + k] = v
    return Scan(stamp=stamp, ranges=r, angle_min=-math.pi / 2,
                angle_increment=math.pi / 180, range_min=0.05, range_max=8.0)


def _changed_cell(footprint, pose_now, ranges_now, target, more_beams=0):
    """Whether the cell of the current grid holding world point ``target`` is changed, after
    one earlier scan at the origin whose beam at 2 deg ended 3.12 m away: in the wedge of
    the cell x 3.0-3.1, y 0.1-0.2 (its nearest beam, at 3 deg, passed), short of that cell's
    reach (centre 3.054 m + the 0.1 m margin), in the cell behind it. ``more_beams``: the
    current scan has that many more beams before the first (a driver whose beam count
    changes from scan to scan), so that its beam numbers are not the earlier scan's."""
    import dataclasses
    builder = GridBuilder(GridConfig(free_erosion=0), keep=3, footprints=footprint)
    history = GridHistory(builder, 2)
    history.push(builder.build(_one_degree_scan(0.0, {2: 3.12}), (0.0, 0.0, 0.0)))
    now = _one_degree_scan(0.1, ranges_now)
    now = dataclasses.replace(
        now, ranges=np.concatenate((np.full(more_beams, np.inf), now.ranges)),
        angle_min=now.angle_min - more_beams * now.angle_increment)
    frame = builder.build(now, pose_now)
    config = DifferenceConfig(memory=0, free_window=0.0, static_time=0.0, motion_depth=0.0,
                              footprint=footprint)
    changed = changed_with_history(frame, 0.1, np.asarray(pose_now), history, config)
    x, y = np.asarray(target) - pose_now[:2]
    c, s = math.cos(pose_now[2]), math.sin(pose_now[2])
    cell = np.floor(np.array([c * x + s * y, -s * x + c * y]) / 0.1 + builder.cells / 2)
    return int(cell[0]) * builder.cells + int(cell[1]) in set(changed.tolist())


@pytest.mark.parametrize('more_beams', [0, 3])
def test_a_cell_crossed_by_a_beam_that_ended_short_of_it_is_not_seen_free_after_a_move(
        more_beams):
    """The cell x 3.0-3.1, y 0.1-0.2 was FREE by its nearest beam, but another beam that
    crossed it ended just behind it on something. Seen from 0.1 m back, a return lands in
    the cell (that something's edge, seen from a new place): a change by the nearest beam
    alone, none with the footprint while the earlier end is still seen; a change again when
    it has gone (a leg that swung on), and from a scanner that has not moved. The same when
    the current scan numbers its beams otherwise (the earlier scan's beams are read at
    their own angles)."""
    back = (-0.1, 0.0, 0.0)
    in_cell = math.hypot(3.15, 0.165)               # from (-0.1, 0): (3.05, 0.165) world
    still_there = math.hypot(3.218, 0.109)          # the earlier end (3.118, 0.109), again
    now = {3: in_cell, 2: still_there}
    k = more_beams
    assert _changed_cell(False, np.array(back), now, (3.05, 0.165), k)
    assert not _changed_cell(True, np.array(back), now, (3.05, 0.165), k)
    assert _changed_cell(True, np.array(back), {3: in_cell}, (3.05, 0.165), k)
    here = np.zeros(3)                              # the same place: (3.05, 0.16)
    assert _changed_cell(True, here, {3: math.hypot(3.05, 0.16), 2: 3.12}, (3.05, 0.16), k)


def _with_returns(scan: Scan, returns: dict) -> Scan:
    import dataclasses
    r = scan.ranges.copy()
    for beam, value in returns.items():
        r[beam] = value
    return dataclasses.replace(scan, ranges=r)


def test_a_lone_spurious_return_in_free_space_is_no_change_a_post_is():
    """One beam returning 2 m into the room that every scan saw free (dust, a glitch) is no
    change with difference.ignore_lone_returns; it is one without. A 0.15 m post walking in
    (several beams) is a change either way, and so is a lone return where a leg could be a
    single beam."""
    def blobs(ignore, returns=None, post=None):
        det = Detector(difference=DifferenceConfig(ignore_lone_returns=ignore))
        for k in range(4):
            det.update(_room_scan(0.2 * k, (0, 0, 0)), _pose(0.2 * k, (0, 0, 0)))
        scan = _room_scan(0.8, (0, 0, 0), post)
        if returns:
            scan = _with_returns(scan, returns)
        return det.update(scan, _pose(0.8, (0, 0, 0))).detections.blobs.count
    assert blobs(False, {200: 2.0}) == 1
    assert blobs(True, {200: 2.0}) == 0
    assert blobs(True, {200: 2.0, 201: 2.01}) == 1               # two beams: an object
    assert blobs(True, {200: 2.0, 201: np.nan, 199: np.inf}) == 0  # alone among silent beams
    assert blobs(True, post=(2.0, 0.5)) == blobs(False, post=(2.0, 0.5)) == 1
    # 6.5 m away a leg may be a single beam at 0.5 deg (beyond 0.05 m / 0.5 deg = 5.7 m):
    # there a lone return stays a change
    assert blobs(True, {270: 6.5}) == blobs(False, {270: 6.5}) == 1


def test_lone_returns_are_mapped_to_the_grids_own_cells():
    """without_lone_returns places each return in the cell the grid put it in (the rule
    leaves the changes alone if it could not)."""
    from laser_tracker.core.difference import without_lone_returns
    builder = GridBuilder(GridConfig())
    scan = _with_returns(_room_scan(0.0, (0, 0, 0)), {100: 1.5, 300: 3.0})
    frame = builder.build(scan)
    every_cell = np.unique(frame.flat)
    kept = without_lone_returns(every_cell, frame, scan, 0.13)
    gone = np.setdiff1d(every_cell, kept)
    angles = scan.angle_min + np.array([100, 300]) * scan.angle_increment
    xy = np.column_stack((np.array([1.5, 3.0]) * np.cos(angles),
                          np.array([1.5, 3.0]) * np.sin(angles)))
    cells, res = builder.cells, builder.config.resolution
    expected = (np.floor(xy[:, 0] / res + cells / 2) * cells
                + np.floor(xy[:, 1] / res + cells / 2)).astype(int)
    assert sorted(gone.tolist()) == sorted(expected.tolist())
