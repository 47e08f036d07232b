"""A recording played backwards (tools.reverse)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.conversions import (PlanarOdometry, PlanarTransform, odometry_from_msg,
                                       odometry_to_msg, scan_from_msg, scan_to_msg,
                                       transforms_from_msg, transforms_to_msg)
from laser_tracker.core.scan import Scan
from laser_tracker.errors import InputFileError
from laser_tracker.tools.annotations import ANNOTATION_TOPIC, register_person_type
from laser_tracker.tools.bag import (FACTORY, LATCHED_QOS, TYPESTORE, BagWriter, iter_messages,
                                     read_scans, topics)
from laser_tracker.tools.data import real_recording
from laser_tracker.tools.leg_scenes import person_msg
from laser_tracker.tools.reverse import write_reversed

S = 1_000_000_000


def _recording(path, n=4):
    """n scans 0.1 s apart (receive times 0.02 s after their stamps), odometry between them,
    /tf, /tf_static, an annotation 1 us after each scan, and a topic of another type."""
    register_person_type(TYPESTORE)
    with BagWriter(path) as bag:
        bag.write('/tf_static', transforms_to_msg(
            FACTORY, [PlanarTransform(0.0, 'base_link', 'laser', 0.1, 0.0, 0.0)]), 5 * S,
            qos=LATCHED_QOS)
        for k in range(n):
            t = 10.0 + 0.1 * k
            scan = Scan(stamp=t, ranges=np.full(5, 1.0 + k), angle_min=-0.2,
                        angle_increment=0.1, range_min=0.05, range_max=10.0)
            t_ns = round((t + 0.02) * S)
            bag.write('/scan', scan_to_msg(FACTORY, scan), t_ns)
            bag.write(ANNOTATION_TOPIC, person_msg(FACTORY, TYPESTORE, (float(k), 0.0), k),
                      t_ns + 1000)
            odom = PlanarOdometry(stamp=t + 0.05, x=0.1 * k, y=0.0, theta=0.0, vx=1.0,
                                  omega=0.5)
            bag.write('/odom', odometry_to_msg(FACTORY, odom), t_ns + 50_000_000)
            bag.write('/tf', transforms_to_msg(
                FACTORY, [PlanarTransform(t + 0.05, 'odom', 'base_link', 0.1 * k, 0.0, 0.0)]),
                t_ns + 50_000_000)
            bag.write('/status', FACTORY.make('std_msgs/msg/String', data=str(k)), t_ns)
    return path


def test_a_recording_played_backwards(tmp_path):
    src = _recording(tmp_path / 'ahead')
    counts = write_reversed(src, tmp_path / 'back', attached=(ANNOTATION_TOPIC,))
    assert counts['left_out'] == {'/status': 4} and counts['bad_scans'] == 0
    assert set(topics(tmp_path / 'back')) == {'/scan', '/odom', '/tf', '/tf_static',
                                             ANNOTATION_TOPIC}
    back = list(iter_messages(tmp_path / 'back', ['/scan', ANNOTATION_TOPIC, '/odom', '/tf',
                                                  '/tf_static']))
    times = [t for _, t, _ in back]
    assert times == sorted(times)
    # mirrored about the middle of the recording (stamps 10.0 to 10.35 s, receive times
    # 10.02 to 10.37 s): the latest scan comes first; each annotation right after its scan;
    # the static transform at the start
    assert back[0][0] == '/tf_static'
    scans = [(t, scan_from_msg(m)) for topic, t, m in back if topic == '/scan']
    assert [s.ranges[0] for _, s in scans] == [4.0, 3.0, 2.0, 1.0]
    assert [round(s.stamp, 6) for _, s in scans] == [10.05, 10.15, 10.25, 10.35]
    assert scans[0][0] == round(10.07 * S)
    for k, (topic, t, msg) in enumerate(back):
        if topic == ANNOTATION_TOPIC:
            assert back[k - 1][0] == '/scan' and t - back[k - 1][1] == 1000
            assert msg.pose.position.x == scan_from_msg(back[k - 1][2]).ranges[0] - 1.0
    # odometry: the poses in reverse order, stamped between the scans, moving the other way
    odom = [odometry_from_msg(m) for topic, _, m in back if topic == '/odom']
    assert [round(o.x, 6) for o in odom] == [0.3, 0.2, 0.1, 0.0]
    assert [round(o.stamp, 6) for o in odom] == [10.0, 10.1, 10.2, 10.3]
    assert all(o.vx == -1.0 and o.omega == -0.5 for o in odom)
    tf = [transforms_from_msg(m)[0] for topic, _, m in back if topic == '/tf']
    assert [round(x.stamp, 6) for x in tf] == [10.0, 10.1, 10.2, 10.3]
    # played backwards twice: the recording as it was
    write_reversed(tmp_path / 'back', tmp_path / 'again', attached=(ANNOTATION_TOPIC,))
    again = [(t, s.stamp, s.ranges[0]) for t, s in (
        (t, scan_from_msg(m)) for _, t, m in iter_messages(tmp_path / 'again', ['/scan']))]
    ahead = [(t, s.stamp, s.ranges[0]) for t, s in (
        (t, scan_from_msg(m)) for _, t, m in iter_messages(src, ['/scan']))]
    assert [a[0] for a in again] == [a[0] for a in ahead]
    assert np.allclose([a[1:] for a in again], [a[1:] for a in ahead])


def test_what_cannot_be_played_backwards_is_refused(tmp_path):
    src = _recording(tmp_path / 'ahead', n=2)
    with pytest.raises(InputFileError, match='/people'):
        write_reversed(src, tmp_path / 'out', attached=('/people',))
    with BagWriter(tmp_path / 'odometry_only') as bag:
        bag.write('/odom', odometry_to_msg(FACTORY, PlanarOdometry(1.0, 0.0, 0.0, 0.0)), S)
    with pytest.raises(InputFileError, match='no LaserScan'):
        write_reversed(tmp_path / 'odometry_only', tmp_path / 'out')
    assert not (tmp_path / 'out').exists()


@pytest.mark.skipif(not real_recording('leg_tracker/training/negative_2.bag').exists(),
                    reason='negative_2.bag is not under $LASER_TRACKER_DATA (README.md, "Data")')
def test_bench_real_replays_negative_2_backwards(tmp_path):
    from bench_rows import bench_real_row

    row = bench_real_row(tmp_path, 'negative_2_inf_reversed')
    assert len(row['false_by_part']) == 3 and row['false'] == sum(row['false_by_part'])
    forward = list(read_scans(tmp_path / 'work' / 'negative_2_inf', '/left_scan'))
    backward = list(read_scans(tmp_path / 'work' / 'negative_2_inf_reversed', '/left_scan'))
    assert len(backward) == len(forward)
    assert np.array_equal(backward[0].ranges, forward[-1].ranges)
    assert math.isclose(backward[0].stamp, forward[0].stamp, abs_tol=1e-6)
    assert row['scans'] == sum(
        sum(1 for _ in read_scans(tmp_path / 'work' / 'negative_2_inf_reversed', t))
        for t in ('/left_scan', '/right_scan', '/rear_scan'))
