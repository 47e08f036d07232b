"""Leg-labelled people put into the scans of a driving robot (``tools.driving_scenes``)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.conversions import header
from laser_tracker.core.scan import Scan
from laser_tracker.tools import driving_scenes as D
from laser_tracker.tools.annotations import HIDDEN_TOPIC, read_annotations
from laser_tracker.tools.bag import FACTORY, BagWriter, read_scans

PERIOD = 1 / 7.5
ANGLES = np.linspace(-0.75 * math.pi, 0.75 * math.pi, 541)
LEG_RADIUS = 0.06


def _circle_ranges(angles, centres, radius=LEG_RADIUS, far=6.0):
    """Ranges of beams along ``angles`` to the nearest of circles at ``centres``, else far."""
    r = np.full(angles.size, far)
    u = np.column_stack((np.cos(angles), np.sin(angles)))
    for c in centres:
        b = u @ c
        disc = b * b - (c @ c - radius * radius)
        hit = disc >= 0
        t = b - np.sqrt(np.where(hit, disc, 0.0))
        r = np.where(hit & (t > 0) & (t < r), t, r)
    return r


def _scan_msg(t, ranges):
    return FACTORY.make(
        'sensor_msgs/msg/LaserScan', header=header(FACTORY, t, 'laser'),
        angle_min=float(ANGLES[0]), angle_max=float(ANGLES[-1]),
        angle_increment=float(ANGLES[1] - ANGLES[0]), time_increment=0.0, scan_time=PERIOD,
        range_min=0.02, range_max=30.0, ranges=FACTORY.float32_array(ranges),
        intensities=FACTORY.float32_array(np.zeros(0)))


def _positive(path, runs=(10, 10), at=(2.0, 0.0)):
    """A standing scanner's labelled recording: one person (legs 0.3 m apart, across the line
    of sight) standing at ``at`` in each run, runs 1 s apart, background 6 m away."""
    t = 100.0
    with BagWriter(path) as bag:
        for n in runs:
            for _ in range(n):
                legs = [(at[0], at[1] - 0.15), (at[0], at[1] + 0.15)]
                poses = [FACTORY.make('geometry_msgs/msg/Pose',
                                      position=FACTORY.make('geometry_msgs/msg/Point', x=x,
                                                            y=y, z=0.0),
                                      orientation=FACTORY.make('geometry_msgs/msg/Quaternion',
                                                               x=0.0, y=0.0, z=0.0, w=1.0))
                         for x, y in legs]
                bag.write('/leg_cluster_positions', FACTORY.make(
                    'geometry_msgs/msg/PoseArray', header=header(FACTORY, t, 'laser'),
                    poses=poses), t)
                centres = [np.array(leg) + (LEG_RADIUS * 0.8, 0.0) for leg in legs]
                bag.write('/training_scan', _scan_msg(t, _circle_ranges(ANGLES, centres)),
                          t + 0.001)
                t += PERIOD
            t += 1.0


def _driving(path, n=60, wall=None):
    """A driving robot's scans: nothing within range (+inf), or a wall ``wall`` m ahead."""
    ranges = np.full(ANGLES.size, np.inf)
    if wall is not None:
        ranges = np.where(np.abs(ANGLES) < 1.0, wall / np.cos(ANGLES), np.inf)
    with BagWriter(path) as bag:
        for k in range(n):
            bag.write('/left_scan', _scan_msg(50.0 + k * PERIOD, ranges), 50.0 + k * PERIOD)


def _poses(n=60, speed=0.0, heading=0.0):
    k = np.arange(n) * PERIOD * speed
    return np.column_stack((k * math.cos(heading), k * math.sin(heading), np.full(n, heading)))


def test_a_beam_meets_an_outline_where_the_geometry_says():
    angles = np.linspace(-0.2, 0.2, 161)
    scan = Scan(stamp=1.0, ranges=np.full(angles.size, np.inf), angle_min=-0.2,
                angle_increment=float(angles[1] - angles[0]), range_min=0.02, range_max=30.0)
    phi = np.linspace(0.5 * math.pi, 1.5 * math.pi, 60)      # the half facing the scanner
    outline = np.column_stack((3.0 + 0.1 * np.cos(phi), 0.1 * np.sin(phi)))
    beams, r = D.outline_ranges(outline, scan)
    truth = _circle_ranges(angles[beams], [np.array([3.0, 0.0])], radius=0.1)
    assert beams.size >= 3 and np.all(np.abs(angles[beams]) < 0.1 / 3.0 + 0.003)
    assert np.abs(r - truth).max() < 0.005
    # nothing behind the scanner, nothing for a point
    assert D.outline_ranges(-outline, scan)[0].size == 0
    assert D.outline_ranges(outline[:1], scan)[0].size == 0


def test_a_carried_outline_shows_the_new_scanner_the_side_the_old_one_saw():
    phi = np.linspace(0.5 * math.pi, 1.5 * math.pi, 30)
    outline = np.column_stack((2.0 + 0.06 * np.cos(phi), 0.06 * np.sin(phi)))
    # the driving scanner 2 m beside the leg, looking along x: the leg is on its left
    moved = D.carried(outline, np.zeros(3), np.array([2.0, -2.0, 0.0]))
    # its centre where the world puts it; the point the old scanner saw nearest is the
    # new one's nearest too (the bulge turned towards it)
    assert np.allclose(moved.mean(axis=0), outline.mean(axis=0) + (-2.0, 2.0))
    assert np.argmin(np.hypot(*moved.T)) == np.argmin(np.hypot(*outline.T))
    assert np.argmin(moved[:, 1]) == np.argmin(outline[:, 0])
    assert np.allclose(np.hypot(*np.diff(moved, axis=0).T),
                       np.hypot(*np.diff(outline, axis=0).T))   # the same shape


def test_runs_split_where_the_scans_are_apart():
    stamps = np.r_[np.arange(5) * PERIOD, 10 + np.arange(3) * PERIOD]
    assert [r.tolist() for r in D.runs_of(stamps)] == [[0, 1, 2, 3, 4], [5, 6, 7]]
    assert D.runs_of(np.zeros(0)) == []


def test_people_stand_in_the_driving_scans_where_the_standing_robot_saw_them(tmp_path):
    _positive(tmp_path / 'positive')
    _driving(tmp_path / 'driving')
    info = D.write_driving_scene(tmp_path / 'positive', tmp_path / 'driving', '/left_scan',
                                 tmp_path / 'scene', poses=_poses())
    # runs of 10 after START scans; the GAP scans after a run left out; ends with the last
    assert info['runs'] == 2 and info['scans'] == D.START + 20
    assert info['annotations'] == 20 and info['people'] == 2 and info['hidden'] == 0
    scans = list(read_scans(tmp_path / 'scene', '/scan'))
    assert len(scans) == D.START + 20
    assert all(np.isinf(s.ranges).all() for s in scans[:D.START])
    legs = scans[D.START].ranges < 10
    assert 6 <= legs.sum() <= 30
    assert np.all(np.abs(scans[D.START].ranges[legs] - 2.0) < 0.1)
    ann = read_annotations(tmp_path / 'scene', scan_topic='/scan')
    assert np.allclose(ann.x, 2.0) and np.allclose(ann.y, 0.0, atol=1e-9)
    assert sorted(set(ann.ids())) == [0, 1]
    gap = scans[D.START + 10].stamp - scans[D.START + 9].stamp
    assert gap == pytest.approx((D.GAP + 1) * PERIOD, abs=1e-3)   # more than max_gap (2 s)


def test_the_people_stay_where_they_stood_while_the_robot_drives_away(tmp_path):
    _positive(tmp_path / 'positive', runs=(10,))
    _driving(tmp_path / 'driving')
    info = D.write_driving_scene(tmp_path / 'positive', tmp_path / 'driving', '/left_scan',
                                 tmp_path / 'scene', poses=_poses(speed=-1.0))
    assert info['annotations'] == 10
    ann = read_annotations(tmp_path / 'scene', scan_topic='/scan')
    assert np.allclose(np.diff(ann.x), PERIOD)               # 1 m/s farther each scan
    scans = list(read_scans(tmp_path / 'scene', '/scan'))
    last = scans[-1].ranges
    assert np.abs(last[last < 10] - ann.x[-1]).max() < 0.1


def test_a_run_ends_where_the_robot_would_run_into_its_people(tmp_path):
    _positive(tmp_path / 'positive', runs=(30,))
    _driving(tmp_path / 'driving')
    info = D.write_driving_scene(tmp_path / 'positive', tmp_path / 'driving', '/left_scan',
                                 tmp_path / 'scene', poses=_poses(speed=1.0))
    ann = read_annotations(tmp_path / 'scene', scan_topic='/scan')
    # 2 m away at 1 m/s: the run stops before the person is within CLEARANCE
    assert info['scans'] - D.START == ann.x.size < 30
    assert ann.x.min() >= D.CLEARANCE and ann.x.min() < D.CLEARANCE + 2 * PERIOD


def test_a_person_behind_the_buildings_wall_is_not_annotated(tmp_path):
    _positive(tmp_path / 'positive', runs=(10,))
    _driving(tmp_path / 'driving', wall=1.5)
    info = D.write_driving_scene(tmp_path / 'positive', tmp_path / 'driving', '/left_scan',
                                 tmp_path / 'scene', poses=_poses())
    assert info['runs'] == 1 and info['annotations'] == 0 and info['hidden'] == 10
    out_of_sight = read_annotations(tmp_path / 'scene', HIDDEN_TOPIC, scan_topic='/scan')
    assert out_of_sight.x.size == 10                        # where it stands, behind the wall
    assert np.allclose(out_of_sight.x, 2.0) and np.allclose(out_of_sight.y, 0.0, atol=1e-9)
    scans = list(read_scans(tmp_path / 'scene', '/scan'))
    ahead = np.abs(scans[-1].angles) < 1.0                  # the wall, as the robot saw it
    assert np.allclose(scans[-1].ranges[ahead], 1.5 / np.cos(scans[-1].angles[ahead]),
                       rtol=1e-6)
