"""`laser-tracker simulate` and `laser-tracker summarize`: bags that round-trip, clear errors."""
import dataclasses
import math

import numpy as np
import pytest

from laser_tracker.tools.cli import main
from laser_tracker.tools.bag import (read_ground_truth, read_odometry, read_platform_truth,
                                  read_scans, topics)
from laser_tracker.tools.sim.recorder import record
from laser_tracker.tools.sim.scenarios import SCENARIOS, build
from laser_tracker.tools.simulate import write_recording


def _short(name='exp1_stationary_single_walker', seconds=6.0):
    return record(dataclasses.replace(build(name), duration=seconds))


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_bag_round_trips(tmp_path, storage):
    rec = _short()
    out = write_recording(rec, tmp_path / 'bag', storage=storage)
    scans = list(read_scans(out))
    assert len(scans) == len(rec.scans)
    for got, want in zip(scans, rec.scans):
        assert got.stamp == pytest.approx(want.stamp, abs=1e-9)
        assert np.array_equal(got.ranges, want.ranges.astype(np.float32))
        for f in ('angle_min', 'angle_increment', 'range_max', 'time_increment', 'scan_time'):
            assert getattr(got, f) == pytest.approx(getattr(want, f), rel=1e-6)
        assert got.frame_id == 'laser'
    odom = read_odometry(out)
    assert np.allclose(odom.stamps, rec.odometry.stamps, atol=1e-9)
    assert np.allclose(odom.poses, rec.odometry.poses, atol=1e-9)
    truth = read_ground_truth(out)
    assert len(truth) == len(rec.truth)
    for got, want in zip(truth, rec.truth):
        assert got.frame_id == 'map'
        assert got.stamp == pytest.approx(want.stamp, abs=1e-9)
        assert [(o.id, o.extra) for o in got.objects] == [(o.id, o.extra) for o in want.objects]
        assert np.allclose([(o.x, o.y, o.vx, o.vy) for o in got.objects],
                           [(o.x, o.y, o.vx, o.vy) for o in want.objects])
    platform = read_platform_truth(out)
    assert np.allclose(platform.poses, [(g.platform.x, g.platform.y, g.platform.theta)
                                        for g in rec.truth])
    t = topics(out)
    assert t['/scan'] == ('sensor_msgs/msg/LaserScan', len(rec.scans))
    assert t['/odom'][0] == 'nav_msgs/msg/Odometry'


def test_simulate_writes_the_scenario_and_summarize_describes_it(tmp_path, capsys):
    out = tmp_path / 'exp3'
    assert main(['simulate', 'exp3_rotating_static', str(out), '--seed', '11']) == 0
    assert 'seed 11, 100 scans' in capsys.readouterr().out
    assert main(['summarize', str(out)]) == 0
    text = capsys.readouterr().out
    assert '/scan' in text and '/ground_truth/platform' in text
    assert '361 beams' in text and '5.00 Hz' in text
    assert 'turned' in text and '0 moving object(s)' in text


def test_summarize_lists_ground_truth_objects(tmp_path, capsys):
    out = write_recording(_short('exp4_corridor_passers', 20.0), tmp_path / 'c')
    assert main(['summarize', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'id   1 person' in text and 'visible in' in text


def test_list_names_every_scenario(capsys):
    assert main(['simulate', '--list']) == 0
    text = capsys.readouterr().out
    assert all(name in text for name in SCENARIOS)


def test_unknown_scenario_is_a_clear_error(tmp_path, capsys):
    assert main(['simulate', 'exp9_moonwalk', str(tmp_path / 'x')]) == 2
    err = capsys.readouterr().err
    assert 'unknown scenario' in err and 'exp1_stationary_single_walker' in err
    assert not (tmp_path / 'x').exists()


def test_missing_arguments_are_a_clear_error(capsys):
    assert main(['simulate', 'exp1_stationary_single_walker']) == 2
    assert 'give SCENARIO and OUT' in capsys.readouterr().err


def test_existing_output_needs_overwrite(tmp_path, capsys):
    out = tmp_path / 'bags'
    (out / 'exp3_rotating_static').mkdir(parents=True)
    (out / 'exp3_rotating_static' / 'keep.txt').write_text('mine')
    assert main(['simulate', 'all', str(out)]) == 2
    assert 'already exists' in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ['exp3_rotating_static']   # nothing written
    assert (out / 'exp3_rotating_static' / 'keep.txt').read_text() == 'mine'
    assert main(['simulate', 'exp3_rotating_static', str(out / 'exp3_rotating_static'),
                 '--overwrite']) == 0
    assert not (out / 'exp3_rotating_static' / 'keep.txt').exists()
    assert topics(out / 'exp3_rotating_static')['/scan'][1] == 100


def test_summarize_of_a_missing_bag_is_a_clear_error(tmp_path, capsys):
    assert main(['summarize', str(tmp_path / 'nothing')]) == 2
    assert 'no such recording' in capsys.readouterr().err


def test_tf_static_carries_the_scanner_mount(tmp_path):
    """Every recording carries its scanner mount once, first, on /tf_static (base_link ->
    laser, latched: reliable, transient local, depth 1), as a robot's static transform
    publisher does: off-centre and turned here, at the platform's origin in the others."""
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.rosbag2 import Reader

    from laser_tracker.conversions import transforms_from_msg
    from laser_tracker.tools.bag import iter_messages
    from laser_tracker.tools.sim.scenarios import REAL_ROBOT_MOUNT

    sc = dataclasses.replace(build('hokuyo_corridor_lobby'), duration=2.0)
    out = write_recording(record(sc), tmp_path / 'bag')
    tf = list(iter_messages(out, ['/tf_static']))
    assert len(tf) == 1
    _, t_ns, msg = tf[0]
    assert t_ns == 0 and msg.__msgtype__ == 'tf2_msgs/msg/TFMessage'
    (mount,) = transforms_from_msg(msg)
    assert (mount.parent, mount.child) == ('base_link', 'laser')
    assert (mount.x, mount.y, mount.yaw) == pytest.approx(REAL_ROBOT_MOUNT)
    assert (mount.x, mount.y, math.degrees(mount.yaw)) == pytest.approx((0.85, 0.24, 42.0))
    t = msg.transforms[0]
    assert t.transform.translation.z == 0.0
    assert t.transform.rotation.x == 0.0 and t.transform.rotation.y == 0.0
    assert all(s.frame_id == 'laser' for s in read_scans(out))
    assert topics(out)['/tf_static'] == ('tf2_msgs/msg/TFMessage', 1)
    with Reader(out) as reader:
        (conn,) = [c for c in reader.connections if c.topic == '/tf_static']
        (qos,) = conn.ext.offered_qos_profiles
        assert qos.durability == QosDurability.TRANSIENT_LOCAL
        assert qos.reliability == QosReliability.RELIABLE and qos.depth == 1
        assert next(reader.messages())[0].topic == '/tf_static'
    odom = list(iter_messages(out, ['/odom']))
    assert odom and all(m.child_frame_id == 'base_link' for _, _, m in odom)
    plain = write_recording(_short('exp3_rotating_static', 2.0), tmp_path / 'plain')
    (_, _, msg), = iter_messages(plain, ['/tf_static'])
    (origin,) = transforms_from_msg(msg)
    assert (origin.parent, origin.child) == ('base_link', 'laser')
    assert (origin.x, origin.y, origin.yaw) == (0.0, 0.0, 0.0)


def test_bundled_recording_names_work_for_summarize_and_replay(tmp_path, capsys):
    assert main(['summarize', 'exp3_rotating_static']) == 0
    assert 'exp3_rotating_static' in capsys.readouterr().out
    assert main(['replay', 'exp3_rotating_static', '--out', str(tmp_path / 'r'),
                 '--no-progress']) == 0
    assert (tmp_path / 'r' / 'tracks.csv').is_file()
