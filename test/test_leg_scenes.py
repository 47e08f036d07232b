"""Leg-labelled training recordings as annotated tracking scenes (``tools.leg_scenes``), the
labelled area in the annotated scoring, and the pooled rows of ``bench real``."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.conversions import header
from laser_tracker.tools import leg_scenes
from laser_tracker.tools.annotations import read_annotations
from laser_tracker.tools.bag import FACTORY, BagWriter
from laser_tracker.tools.bench_real import headline, pooled, rewrite_scans
from laser_tracker.tools.bag import read_scans
from laser_tracker.tools.data import real_recording
from laser_tracker.tools.evaluate import evaluate_recording

from bench_rows import bench_real_row
from test_evaluate import write_replay

PERIOD = 1 / 7.5


def test_legs_pair_into_people_nearest_first():
    legs = [np.array([[1.0, 0.0], [1.0, 0.3], [3.0, 0.0]]),     # a pair and a lone leg
            np.array([[1.0, 0.0], [1.0, 0.5], [1.0, 1.0]]),     # 0.5 apart twice: one pair
            np.zeros((0, 2))]
    people = leg_scenes.people_of_legs(legs, pair_distance=0.6)
    assert np.allclose(people[0], [[1.0, 0.15], [3.0, 0.0]])
    assert people[1].shape == (2, 2) and np.allclose(people[1][0], [1.0, 0.25])
    assert people[2].shape == (0, 2)


def test_people_keep_their_id_until_a_gap_or_a_jump():
    stamps = np.array([0.0, 0.13, 0.27, 5.0, 5.13])
    people = [np.array([[1.0, 0.0], [3.0, 0.0]]), np.array([[3.1, 0.0], [1.1, 0.0]]),
              np.array([[1.2, 0.0], [4.0, 0.0]]),          # the second one jumped 0.9 m
              np.array([[1.2, 0.0]]),                       # after a gap: someone new
              np.array([[1.3, 0.0]])]
    p = leg_scenes.link_people(stamps, people, link_distance=0.5, max_gap=0.3)
    ids = [p.person[p.scan == k].tolist() for k in range(5)]
    assert ids == [[0, 1], [1, 0], [0, 2], [3], [3]]


def _positive_bag(path, n=12, zeros=False):
    """A labelled recording as leg_tracker extracted them: labels, then their scan."""
    angles = np.linspace(-math.pi / 2, math.pi / 2, 181)
    with BagWriter(path) as bag:
        for k in range(n):
            t = 100.0 + k * PERIOD
            x = 1.0 + 0.1 * k                        # one person walking away, legs 0.2 apart
            legs = [(x, -0.1), (x, 0.1)]
            poses = [FACTORY.make('geometry_msgs/msg/Pose',
                                  position=FACTORY.make('geometry_msgs/msg/Point', x=lx, y=ly,
                                                        z=0.0),
                                  orientation=FACTORY.make('geometry_msgs/msg/Quaternion',
                                                           x=0.0, y=0.0, z=0.0, w=1.0))
                     for lx, ly in legs]
            bag.write('/leg_cluster_positions', FACTORY.make(
                'geometry_msgs/msg/PoseArray', header=header(FACTORY, t, 'laser'), poses=poses),
                t)
            r = np.full(angles.size, 0.0 if zeros else 6.0)
            r[np.abs(angles) < 0.15] = x
            bag.write('/training_scan', FACTORY.make(
                'sensor_msgs/msg/LaserScan', header=header(FACTORY, t, 'laser'),
                angle_min=float(angles[0]), angle_max=float(angles[-1]),
                angle_increment=float(angles[1] - angles[0]), time_increment=0.0,
                scan_time=PERIOD, range_min=0.02, range_max=10.0,
                ranges=FACTORY.float32_array(r), intensities=FACTORY.float32_array(np.zeros(0))),
                t + 0.001)


def test_a_positive_recording_becomes_an_annotated_scene(tmp_path):
    src = tmp_path / 'positive'
    _positive_bag(src, zeros=True)
    info = leg_scenes.write_scene(src, tmp_path / 'scene', no_return_as_inf=True)
    assert info['scans'] == 12 and info['people'] == 1 and info['legs'] == 24
    assert info['area'] == pytest.approx([1.0, 2.1, -0.1, 0.1])
    ann = read_annotations(tmp_path / 'scene', scan_topic='/scan')
    assert len(ann) == 12 and ann.ids() == [0]
    assert np.allclose(ann.x, 1.0 + 0.1 * np.arange(12)) and np.allclose(ann.y, 0.0)
    assert np.allclose(ann.scans.stamps, ann.scans.receive_ns * 1e-9)   # header stamps
    scan = next(iter(read_scans(tmp_path / 'scene', '/scan')))
    assert np.isinf(scan.ranges).sum() == scan.ranges.size - (np.abs(scan.angles) < 0.15).sum()


def test_a_scene_as_a_scanner_with_half_the_beams_or_half_the_rate(tmp_path):
    src = tmp_path / 'positive'
    _positive_bag(src)
    full = list(read_scans(src, '/training_scan'))
    info = leg_scenes.write_scene(src, tmp_path / 'beams', beam_step=2)
    assert info['scans'] == 12 and info['legs'] == 24
    sparse = list(read_scans(tmp_path / 'beams', '/scan'))
    assert sparse[0].n_beams == 91
    assert np.allclose(sparse[0].angles, full[0].angles[::2])
    assert np.array_equal(sparse[3].ranges, full[3].ranges[::2].astype(np.float32))
    info = leg_scenes.write_scene(src, tmp_path / 'rate', scan_step=2)
    assert info['scans'] == 6 and info['annotations'] == 6 and info['legs'] == 12
    ann = read_annotations(tmp_path / 'rate', scan_topic='/scan')
    # the kept scans, and their people with the ids of the whole recording
    assert np.allclose(ann.scans.stamps, 100.0 + 2 * PERIOD * np.arange(6), atol=1e-6)
    assert ann.ids() == [0] and np.allclose(ann.x, 1.0 + 0.2 * np.arange(6))


def test_a_recording_rewritten_as_another_scanner_keeps_its_topics_apart(tmp_path):
    src = tmp_path / 'two'
    angles = np.linspace(-2.0, 2.0, 9)
    with BagWriter(src) as bag:
        for k in range(6):
            for topic, r0 in (('/a', 1.0), ('/b', 2.0)):
                t = 10.0 + k * 0.1 + (0.01 if topic == '/b' else 0.0)
                r = np.full(angles.size, r0 + k)
                r[0] = 0.0                           # a no-return code
                bag.write(topic, FACTORY.make(
                    'sensor_msgs/msg/LaserScan', header=header(FACTORY, t, 'laser'),
                    angle_min=-2.0, angle_max=2.0, angle_increment=0.5, time_increment=0.001,
                    scan_time=0.1, range_min=0.05, range_max=30.0,
                    ranges=FACTORY.float32_array(r), intensities=FACTORY.float32_array(
                        np.zeros(0))), t)
    rewrite_scans(src, tmp_path / 'out', ['/a', '/b'], beam_step=2, scan_step=3)
    for topic, r0 in (('/a', 1.0), ('/b', 2.0)):
        scans = list(read_scans(tmp_path / 'out', topic))
        assert [s.ranges[1] for s in scans] == [r0, r0 + 3]          # scans 0 and 3
        assert all(s.n_beams == 5 and s.angle_increment == 1.0 for s in scans)
        assert all(np.isposinf(s.ranges[0]) for s in scans)         # REP 117
        assert scans[0].time_increment == pytest.approx(0.002)


def test_a_recording_rewritten_as_a_faster_drive_keeps_the_scan_rate(tmp_path):
    src = tmp_path / 'two'
    with BagWriter(src) as bag:
        for k in range(6):
            for topic in ('/a', '/b'):
                t = 10.0 + k * 0.1 + (0.01 if topic == '/b' else 0.0)
                bag.write(topic, FACTORY.make(
                    'sensor_msgs/msg/LaserScan', header=header(FACTORY, t, 'laser'),
                    angle_min=-1.0, angle_max=1.0, angle_increment=0.5, time_increment=0.0,
                    scan_time=0.1, range_min=0.05, range_max=30.0,
                    ranges=FACTORY.float32_array(np.full(5, 1.0 + k)),
                    intensities=FACTORY.float32_array(np.zeros(0))), t)
    rewrite_scans(src, tmp_path / 'fast', ['/a', '/b'], scan_step=2, faster=True)
    for topic, offset in (('/a', 0.0), ('/b', 0.005)):
        scans = list(read_scans(tmp_path / 'fast', topic))
        # scans 0, 2 and 4 (the robot twice as far each scan), 0.1 s apart as recorded
        assert [s.ranges[0] for s in scans] == [1.0, 3.0, 5.0]
        assert np.allclose([s.stamp for s in scans], 10.0 + offset + 0.1 * np.arange(3))


def test_tracks_outside_the_labelled_area_count_only_on_a_labelled_person(tmp_path):
    src = tmp_path / 'positive'
    _positive_bag(src)
    info = leg_scenes.write_scene(src, tmp_path / 'scene')
    stamps = 100.0 + PERIOD * np.arange(12)
    ego = [(s, 0.0, 0.0, 0.0) for s in stamps]
    rows = [(s, 1, 1.0 + 0.1 * k, 0.0, 0.7, 0.0, 80.0, True) for k, s in enumerate(stamps)]
    rows += [(s, 2, 4.0, 3.0, 0.0, 0.0, 80.0, True) for s in stamps]       # someone else
    rows += [(s, 3, 1.0 + 0.1 * k, 0.6, 0.7, 0.0, 80.0, True)               # a duplicate
             for k, s in enumerate(stamps)]                                 # just outside
    write_replay(tmp_path / 'replay', ego, rows)
    whole = evaluate_recording(tmp_path / 'replay', tmp_path / 'scene', scan_topic='/scan',
                               force=True).result
    inside = evaluate_recording(tmp_path / 'replay', tmp_path / 'scene', scan_topic='/scan',
                                force=True, area=info['area']).result
    assert whole['clear_mot']['all']['num_false_positives'] == 24
    # the duplicate beside the person still counts, the one elsewhere does not
    assert inside['clear_mot']['all']['num_false_positives'] == 12
    assert inside['tracks_outside_area'] == 1
    assert inside['clear_mot']['all']['num_misses'] == 0


def test_pooled_rows_add_the_counts_before_the_ratios():
    parts = [dict(objects=100, misses=10, fp=5, switches=1, walking_objects=50,
                  walking_misses=5, walking_fp=5, walking_switches=0, confirmed=3, scans=90,
                  outside_area=1, replay_s=1.0),
             dict(objects=10, misses=10, fp=0, switches=0, walking_objects=0, walking_misses=0,
                  walking_fp=0, walking_switches=0, confirmed=0, scans=10, outside_area=0,
                  replay_s=0.5)]
    row = pooled(parts)
    assert row['objects'] == 110 and row['scenes'] == 2
    assert row['mota'] == pytest.approx(1 - 26 / 110)
    assert row['recall'] == pytest.approx(1 - 20 / 110)
    assert row['walking_recall'] == pytest.approx(0.9)


def test_pooled_scenes_say_how_many_false_positives_lie_on_people_out_of_sight():
    part = dict(objects=100, misses=10, fp=5, switches=1, walking_objects=50,
                walking_misses=5, walking_fp=5, walking_switches=0, confirmed=3, scans=90,
                outside_area=1, replay_s=1.0)
    row = pooled([dict(part, fp_hidden=3), dict(part, fp_hidden=1)])
    assert row['fp_hidden'] == 4
    assert headline(row) == ('MOTA 0.840, recall 0.900 (walking 0.900), 10 false positives '
                             '(4 on people out of sight), 2 switches')
    # a scene without that knowledge (no hidden topic) leaves the pooled count out
    mixed = pooled([dict(part, fp_hidden=3), part])
    assert 'fp_hidden' not in mixed and '(' not in headline(mixed).split('positives')[1]


def test_pooled_scanners_with_nobody_in_view_add_their_false_tracks():
    parts = [dict(scans=435, confirmed=c, false=c, minutes=0.97, replay_s=1.0)
             for c in (1, 0, 3)]
    row = pooled(parts)
    assert row['false'] == 4 and row['false_by_part'] == [1, 0, 3]
    assert row['false_per_minute'] == pytest.approx(4 / 2.91)
    assert headline(row) == '4 false (1.37/min; 1 / 0 / 3)'


@pytest.mark.skipif(not leg_scenes.positive_recordings(),
                    reason='the leg_tracker training recordings are not under '
                           '$LASER_TRACKER_DATA (README.md, "Data")')
def test_a_real_positive_recording_becomes_a_scene_of_its_labelled_legs(tmp_path):
    src = real_recording('leg_tracker/training/positive_2_extracted.bag')
    info = leg_scenes.write_scene(src, tmp_path / 'scene')
    scans, legs = leg_scenes.read_labelled(src)
    assert info['scans'] == len(scans) and info['legs'] == sum(map(len, legs))
    ann = read_annotations(tmp_path / 'scene', scan_topic='/scan')
    for k, xy in enumerate(legs):             # each person is at a leg or between two
        spots = np.vstack([xy, (xy[:, None, :] + xy[None, :, :]).reshape(-1, 2) / 2])
        at = ann.scan == k
        assert at.any()
        for x, y in zip(ann.x[at], ann.y[at]):
            assert np.hypot(*(spots - (x, y)).T).min() < 1e-6
    x0, x1, y0, y1 = info['area']
    assert x0 <= ann.x.min() and ann.x.max() <= x1 and y0 <= ann.y.min() and ann.y.max() <= y1


@pytest.mark.skipif(not real_recording('leg_tracker/training/negative_2.bag').exists(),
                    reason='negative_2.bag is not under $LASER_TRACKER_DATA (README.md, "Data")')
def test_bench_real_replays_negative_2_as_a_scanner_at_half_the_rate(tmp_path):
    row = bench_real_row(tmp_path, 'negative_2_inf_half_rate')
    assert len(row['false_by_part']) == 3 and row['false'] == sum(row['false_by_part'])
    # every second scan of each of the three scanners, as +inf where nothing returned
    recorded = sum(1 for _ in read_scans(real_recording('leg_tracker/training/negative_2.bag'),
                                         '/left_scan'))
    half = list(read_scans(tmp_path / 'work' / 'negative_2_inf_half_rate', '/left_scan'))
    assert len(half) == (recorded + 1) // 2
    assert row['scans'] == sum(
        sum(1 for _ in read_scans(tmp_path / 'work' / 'negative_2_inf_half_rate', t))
        for t in ('/left_scan', '/right_scan', '/rear_scan'))
    assert not any((s.ranges == 0).any() for s in half)


@pytest.mark.skipif(not real_recording('leg_tracker/training/negative_2.bag').exists(),
                    reason='negative_2.bag is not under $LASER_TRACKER_DATA (README.md, "Data")')
def test_the_robot_of_negative_2_driving_twice_as_fast_confirms_nothing(tmp_path):
    row = bench_real_row(tmp_path, 'negative_2_inf_fast', mode='defaults')
    assert row['false_by_part'] == [0, 0, 0]
    recorded = [s.stamp for s in read_scans(
        real_recording('leg_tracker/training/negative_2.bag'), '/left_scan')]
    fast = [s.stamp for s in read_scans(tmp_path / 'work' / 'negative_2_inf_fast',
                                        '/left_scan')]
    # every second scan, at the recorded rate: the robot goes twice as far between scans
    assert len(fast) == (len(recorded) + 1) // 2
    assert np.median(np.diff(fast)) == pytest.approx(np.median(np.diff(recorded)), rel=0.05)
