"""A detected person who walked out: the place where they were detected moments ago is empty
now (``difference.walked_out_*``), motion evidence beside "walked in" (space seen free
before), which someone walking away from the scanner never gives (they walk into their own
shadow)."""
from __future__ import annotations

import numpy as np
import pytest

from laser_tracker.core.difference import DifferenceConfig, people_in_odometry
from laser_tracker.core.grid import GridBuilder, GridConfig, GridHistory
from laser_tracker.core.person_detector import PersonDetections

from leg_scenes import scene

CFG = GridConfig(resolution=0.1, size=12.0, no_return_free=5.0)
WALL = [(5.0, -4.0, 5.0, 4.0)]
ON = (1.0, 0.3, 3.0)                        # window (s), radius (m), speed (m/s)


def person(x, y=0.0):
    """Two legs 0.2 m apart across the line of sight, at (x, y)."""
    return [(x, y - 0.1, 0.06), (x, y + 0.1, 0.06)]


def evidence(earlier, now, circles_now, walls=WALL, walked_out=ON, ranges=None, stamp=0.5):
    """``walked`` of a person detected at ``now`` (odometry = scanner frame, a standing
    scanner), with one earlier detection at ``earlier`` (0.5 s before) and the current scan
    of ``circles_now``; ``ranges`` rewrites the scan's ranges first."""
    builder = GridBuilder(CFG, keep=3)
    history = GridHistory(builder, 2)
    scan = scene(circles_now, walls, n_beams=721, fov=np.radians(180), range_max=10.0)
    scan.stamp = stamp
    if ranges is not None:
        scan.ranges = ranges(scan)
    history.push(builder.build(scan, np.zeros(3)))
    people = PersonDetections.empty(stamp)
    people.xy = np.array([now], float)
    people.leg_xy = np.array([now], float)
    people.legs = np.array([[0, -1]])
    recent = np.array([[*earlier, 0.0, 0.0, 0.0, 0.0]])
    return bool(people_in_odometry(people, np.zeros(3), stamp, history, None, 0.5, recent,
                                   walked_out, scan.silent())[1][0])


def test_a_person_walking_away_left_empty_space():
    assert evidence((1.2, 0.0), (2.0, 0.0), person(2.0))


def test_off_without_a_window():
    assert not evidence((1.2, 0.0), (2.0, 0.0), person(2.0), walked_out=(0.0, 0.3, 3.0))


def test_a_track_hopping_between_two_posts_finds_the_first_one_still_there():
    posts = [(1.5, 0.4, 0.03), (1.5, -0.4, 0.03)]
    assert not evidence((1.5, 0.4), (1.5, -0.4), posts)


def test_a_place_behind_something_nearer_is_not_seen_empty():
    # the earlier place, 2.5 m out, hidden now behind a box at 1.5 m
    box = [(1.4, -0.5, 1.4, 0.5)]
    assert not evidence((2.5, 0.0), (2.5, 1.6), person(2.5, 1.6), walls=WALL + box)


@pytest.mark.parametrize('earlier, now', [((1.9, 0.0), (2.2, 0.0)),     # nearer than 2 radii
                                          ((0.5, 0.0), (3.5, 0.0))])    # beyond reach
def test_too_near_or_beyond_reach_is_no_evidence(earlier, now):
    assert not evidence(earlier, now, person(now[0]))


def test_beams_without_a_return_are_no_evidence_against_nor_alone_for():
    def silent_beyond_one(scan):
        r = scan.ranges.copy()
        r[np.abs(scan.angles) < 0.3] = np.nan             # no return through the place...
        r[np.abs(scan.angles) < 0.005] = 5.0              # ...but one beam hits the wall
        return r

    def all_silent(scan):
        r = scan.ranges.copy()
        r[np.abs(scan.angles) < 0.3] = np.nan
        return r

    assert evidence((1.2, 0.0), (2.0, 1.0), person(2.0, 1.0), ranges=silent_beyond_one)
    assert not evidence((1.2, 0.0), (2.0, 1.0), person(2.0, 1.0), ranges=all_silent)


def test_defaults_are_on_and_the_paper_mode_is_off():
    from laser_tracker.parameters import PAPER_REFERENCE

    assert DifferenceConfig().walked_out_window > 0
    assert PAPER_REFERENCE['detection']['difference.walked_out_window'] == 0.0
