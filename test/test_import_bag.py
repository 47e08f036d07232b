"""`laser-tracker import-bag`: ROS 1 bags (and rosbag2) to rosbag2, losslessly for what the
pipeline uses; bad input gives a clear error and leaves nothing behind."""
import dataclasses
import logging
import math

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from laser_tracker.tools.cli import main
from laser_tracker.conversions import (PlanarOdometry, bag_factory, odometry_to_msg,
                                       scan_to_msg, stamp_to_sec)
from laser_tracker.core.scan import Scan
from laser_tracker.tools.bag import iter_messages, read_odometry, topics
from laser_tracker.tools.sim.recorder import record
from laser_tracker.tools.sim.scenarios import build
from laser_tracker.tools.import_bag import import_bag
from laser_tracker.tools.simulate import write_recording
from laser_tracker.tools.data import real_data

DATA = real_data()
LEG_BAG = DATA / 'leg_tracker' / 'demo_stationary_simple_environment.bag'
ROS1 = get_typestore(Stores.ROS1_NOETIC)
ROS1.register(get_types_from_msg('geometry_msgs/TransformStamped[] transforms',
                                 'tf2_msgs/msg/TFMessage'))


def _leg_bag():
    if not LEG_BAG.is_file():
        pytest.skip(f'{LEG_BAG} not found (the public recordings: $LASER_TRACKER_DATA)')
    return LEG_BAG


def _messages(path, topic):
    return [(t, msg) for _, t, msg in iter_messages(path, [topic])]


def _ros1_bag(path, n=20, bad_scan_at=None):
    """A small ROS 1 bag: /scan (181 beams) at 5 Hz, /base/odom at 25 Hz, /chatter."""
    f = bag_factory(ROS1)
    rng = np.random.default_rng(0)
    with Ros1Writer(path) as w:
        scan_c = w.add_connection('/scan', 'sensor_msgs/msg/LaserScan', typestore=ROS1)
        odom_c = w.add_connection('/base/odom', 'nav_msgs/msg/Odometry', typestore=ROS1)
        text_c = w.add_connection('/chatter', 'std_msgs/msg/String', typestore=ROS1)
        t0 = 1_300_000_000.0
        for k in range(n):
            stamp = t0 + 0.2 * k
            scan = Scan(stamp, rng.uniform(0.5, 7.9, 181).astype(np.float32), -math.pi / 2,
                        math.pi / 180, 0.0, 8.0, 1e-5, 0.0133, 'laser')
            msg = scan_to_msg(f, scan, intensities=np.arange(181.0))
            if k == bad_scan_at:
                msg = dataclasses.replace(msg, ranges=msg.ranges[:100])
            w.write(scan_c, int(round((stamp + 0.05) * 1e9)),
                    ROS1.serialize_ros1(msg, msg.__msgtype__))
            for j in range(5):
                ts = stamp + 0.04 * j
                odo = odometry_to_msg(f, PlanarOdometry(ts, 0.1 * k, 0.01 * j, 0.02 * k, 0.5),
                                      pose_variance=[0.01] * 6)
                w.write(odom_c, int(round(ts * 1e9)), ROS1.serialize_ros1(odo, odo.__msgtype__))
            s = f.make('std_msgs/msg/String', data='hi')
            w.write(text_c, int(round(stamp * 1e9)), ROS1.serialize_ros1(s, s.__msgtype__))
    return path


def test_ros1_bag_converts_scans_and_odometry_keeping_times(tmp_path, capsys):
    src = _ros1_bag(tmp_path / 'in.bag')
    assert main(['import-bag', str(src), str(tmp_path / 'out')]) == 0
    assert '/scan: 20' in capsys.readouterr().out
    out = tmp_path / 'out'
    assert topics(out) == {'/scan': ('sensor_msgs/msg/LaserScan', 20),
                           '/base/odom': ('nav_msgs/msg/Odometry', 100)}
    for topic in ('/scan', '/base/odom'):
        before, after = _messages(src, topic), _messages(out, topic)
        assert [t for t, _ in after] == pytest.approx([t for t, _ in before], abs=1000)  # 1 us
        for (_, a), (_, b) in zip(before, after):
            assert stamp_to_sec(b.header.stamp) == pytest.approx(stamp_to_sec(a.header.stamp),
                                                                 abs=1e-6)
            assert b.header.frame_id == a.header.frame_id
            if topic == '/scan':
                assert np.array_equal(b.ranges, a.ranges)
                assert np.array_equal(b.intensities, a.intensities)
                for f in ('angle_min', 'angle_increment', 'time_increment', 'scan_time',
                          'range_min', 'range_max'):
                    assert getattr(b, f) == getattr(a, f)
                assert b.angle_max == pytest.approx(a.angle_max, abs=1e-6)   # recomputed
            else:
                assert b.child_frame_id == a.child_frame_id
                assert np.allclose(b.pose.covariance, a.pose.covariance)
    assert np.allclose(read_odometry(out, '/base/odom').poses,
                       read_odometry(src, '/base/odom').poses)


def test_topics_option_chooses_and_rejects(tmp_path, capsys):
    src = _ros1_bag(tmp_path / 'in.bag', n=3)
    assert main(['import-bag', str(src), str(tmp_path / 'a'), '--topics', '/base/odom']) == 0
    assert set(topics(tmp_path / 'a')) == {'/base/odom'}
    assert main(['import-bag', str(src), str(tmp_path / 'b'), '--topics', '/chatter']) == 2
    assert 'only LaserScan, Odometry and TFMessage' in capsys.readouterr().err
    assert main(['import-bag', str(src), str(tmp_path / 'c'), '--topics', '/nope']) == 2
    assert "no topic '/nope'" in capsys.readouterr().err
    assert not (tmp_path / 'b').exists() and not (tmp_path / 'c').exists()


def test_a_malformed_scan_is_skipped_with_a_warning(tmp_path, caplog):
    src = _ros1_bag(tmp_path / 'in.bag', n=5, bad_scan_at=2)
    with caplog.at_level(logging.WARNING, logger='laser_tracker.tools.import_bag'):
        counts = import_bag(src, tmp_path / 'out')
    assert counts['/scan'] == 4 and counts['skipped'] == 1
    assert 'skipped scan' in caplog.text and 'in.bag' in caplog.text


def test_rosbag2_input_is_accepted(tmp_path):
    rec = record(dataclasses.replace(build('exp1_stationary_single_walker'), duration=3.0))
    src = write_recording(rec, tmp_path / 'sim')
    counts = import_bag(src, tmp_path / 'out', storage='mcap')
    assert counts == {'/odom': len(rec.odometry.stamps), '/ground_truth/platform': len(rec.truth),
                      '/scan': len(rec.scans), '/tf_static': 1, 'skipped': 0}
    for topic in ('/scan', '/odom'):
        a, b = _messages(src, topic), _messages(tmp_path / 'out', topic)
        assert [t for t, _ in a] == [t for t, _ in b]


def test_real_leg_tracker_bag_keeps_every_scan(tmp_path):
    src = _leg_bag()
    counts = import_bag(src, tmp_path / 'out')
    assert counts['/scan'] == 1265
    before, after = _messages(src, '/scan'), _messages(tmp_path / 'out', '/scan')
    assert len(after) == 1265
    assert all(np.array_equal(a.ranges, b.ranges, equal_nan=True) and b.ranges.size == 512
               for (_, a), (_, b) in zip(before, after))
    assert all(abs(ta - tb) <= 1000 for (ta, _), (tb, _) in zip(before, after))


def test_truncated_ros1_bag_names_the_offset_and_writes_nothing(tmp_path, capsys):
    src = _leg_bag() if LEG_BAG.is_file() else _ros1_bag(tmp_path / 'in.bag')
    data = src.read_bytes()
    cut = tmp_path / 'cut.bag'
    cut.write_bytes(data[:len(data) // 2])
    assert main(['import-bag', str(cut), str(tmp_path / 'out')]) == 2
    err = capsys.readouterr().err
    assert str(cut) in err and f'byte offset {len(data) // 2}' in err and 'truncated' in err
    assert not (tmp_path / 'out').exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith('.out')] == []
    # Cut inside the index at the end: the index's offset is named.
    tail = tmp_path / 'tail.bag'
    tail.write_bytes(data[:-40])
    assert main(['import-bag', str(tail), str(tmp_path / 'out')]) == 2
    err = capsys.readouterr().err
    assert str(tail) in err and 'index at byte offset' in err
    assert not (tmp_path / 'out').exists()


def test_garbage_and_truncated_rosbag2_are_clear_errors(tmp_path, capsys):
    junk = tmp_path / 'junk.bag'
    junk.write_bytes(b'#ROSBAG V2.0\n' + b'\x07' * 64)
    assert main(['import-bag', str(junk), str(tmp_path / 'out')]) == 2
    assert 'junk.bag: byte offset 13' in capsys.readouterr().err
    rec = record(dataclasses.replace(build('exp3_rotating_static'), duration=4.0))
    src = write_recording(rec, tmp_path / 'sim')
    db = next(src.glob('*.db3'))
    db.write_bytes(db.read_bytes()[:db.stat().st_size // 2])
    assert main(['import-bag', str(src), str(tmp_path / 'out')]) == 2
    assert str(src) in capsys.readouterr().err
    assert not (tmp_path / 'out').exists()
    assert main(['import-bag', str(tmp_path / 'missing.bag'), str(tmp_path / 'out')]) == 2
    assert 'no such file' in capsys.readouterr().err


def test_existing_output_needs_overwrite(tmp_path, capsys):
    src = _ros1_bag(tmp_path / 'in.bag', n=2)
    (tmp_path / 'out').mkdir()
    assert main(['import-bag', str(src), str(tmp_path / 'out')]) == 2
    assert 'already exists' in capsys.readouterr().err
    assert main(['import-bag', str(src), str(tmp_path / 'out'), '--overwrite']) == 0
    assert topics(tmp_path / 'out')['/scan'][1] == 2


def _ros1_bag_with_mount(path, mount=(0.3, -0.1, 0.5)):
    """_ros1_bag plus /tf_static: base_link -> laser at ``mount`` (and an unrelated frame)."""
    from laser_tracker.conversions import PlanarTransform, transforms_to_msg
    _ros1_bag(path)
    f = bag_factory(ROS1)
    tf = transforms_to_msg(f, [PlanarTransform(0.0, 'base_link', 'laser', *mount),
                               PlanarTransform(0.0, 'base_link', 'camera', 0.1, 0.0, 0.0)])
    with Ros1Writer(path.with_name('tf.bag')) as w:
        c = w.add_connection('/tf_static', 'tf2_msgs/msg/TFMessage', typestore=ROS1,
                             latching=1)
        w.write(c, 1_299_999_999_000_000_000, ROS1.serialize_ros1(tf, tf.__msgtype__))
    return path, path.with_name('tf.bag')


def test_transforms_are_kept_and_replay_takes_the_scanner_mount_from_them(tmp_path, capsys):
    from laser_tracker.conversions import transforms_from_msg
    from laser_tracker.tools.replay import replay_bag

    src, tf_bag = _ros1_bag_with_mount(tmp_path / 'in.bag')
    out = tmp_path / 'out'
    # Two ROS 1 bags of one recording: import the transforms, then scans and odometry.
    assert main(['import-bag', str(tf_bag), str(tmp_path / 'tf')]) == 0
    (_, _, tf), = iter_messages(tmp_path / 'tf', ['/tf_static'])
    frames = {(t.parent, t.child): (t.x, t.y, t.yaw) for t in transforms_from_msg(tf)}
    assert frames[('base_link', 'laser')] == pytest.approx((0.3, -0.1, 0.5))
    # One recording holding all three (what a robot's rosbag has).
    from laser_tracker.tools.bag import BagWriter
    with BagWriter(out) as bag:
        for topic, t_ns, msg in sorted(
                list(iter_messages(tmp_path / 'tf', ['/tf_static']))
                + [m for m in iter_messages(_import(src, tmp_path / 'so'),
                                            ['/scan', '/base/odom'])], key=lambda m: m[1]):
            bag.write(topic, msg, t_ns)
    summary = replay_bag(out, odom_topic='/base/odom', progress=False)
    mount = summary['scanner_mount']
    assert mount['source'] == '/tf_static'
    assert (mount['x'], mount['y'], mount['yaw']) == pytest.approx((0.3, -0.1, 0.5))
    assert 'scanner mount from the recording' in capsys.readouterr().err
    # Without the transforms: a clear warning, not a silent zero.
    plain = replay_bag(tmp_path / 'so', odom_topic='/base/odom', progress=False)
    assert plain['scanner_mount']['source'] == 'unknown'
    assert "no transform between them" in capsys.readouterr().err


def _import(src, dst):
    assert import_bag(src, dst)['/scan'] == 20
    return dst


def test_a_ros1_recording_with_its_odometry_and_mount_only_on_tf_replays_with_both(tmp_path,
                                                                                    capsys):
    """A ROS 1 robot's recording as leg_tracker's benchmarks hold them: no Odometry topic,
    the odometry and the mount as old-style tf/tfMessage transforms on /tf, frame names with
    a leading slash, the scanner two transforms below the odometry's child."""
    from laser_tracker.conversions import PlanarTransform, transforms_to_msg
    from laser_tracker.tools.replay import replay_bag

    ros1 = get_typestore(Stores.ROS1_NOETIC)
    for name in ('tf/msg/tfMessage', 'tf2_msgs/msg/TFMessage'):
        ros1.register(get_types_from_msg('geometry_msgs/TransformStamped[] transforms', name))
    f = bag_factory(ros1)
    path = tmp_path / 'robot.bag'
    rng = np.random.default_rng(1)
    with Ros1Writer(path) as w:
        scan_c = w.add_connection('/scan', 'sensor_msgs/msg/LaserScan', typestore=ros1)
        tf_c = w.add_connection('/tf', 'tf/msg/tfMessage', typestore=ros1)
        t0 = 1_400_000_000.0
        for k in range(30):
            stamp = t0 + 0.2 * k
            for j in range(4):
                ts = stamp + 0.05 * j
                tf = transforms_to_msg(f, [
                    PlanarTransform(ts, '/odom', '/base_footprint', 0.1 * (k + j / 4), 0.0, 0.0),
                    PlanarTransform(ts, '/base_footprint', '/base_link', 0.0, 0.0, 0.0),
                    PlanarTransform(ts, '/base_link', '/laser', 0.2, 0.1, 0.3)])
                msg = f.make('tf/msg/tfMessage', transforms=tf.transforms)
                w.write(tf_c, int(round((ts + 0.005) * 1e9)),
                        ros1.serialize_ros1(msg, msg.__msgtype__))
            scan = Scan(stamp, rng.uniform(1.0, 6.0, 181).astype(np.float32), -math.pi / 2,
                        math.pi / 180, 0.0, 8.0, 1e-5, 0.1, 'laser')
            msg = scan_to_msg(f, scan)
            w.write(scan_c, int(round((stamp + 0.02) * 1e9)),
                    ros1.serialize_ros1(msg, msg.__msgtype__))
    summary = replay_bag(path, progress=False)
    assert summary['odom_tf'] == '/tf: odom -> base_footprint'
    assert summary['odometry_messages'] == 120
    mount = summary['scanner_mount']
    assert mount['source'] == '/tf'
    assert (mount['x'], mount['y'], mount['yaw']) == pytest.approx((0.2, 0.1, 0.3))
    assert 'odometry from /tf (odom -> base_footprint)' in capsys.readouterr().err


def test_a_scanner_mounted_upside_down_is_found_mirrored_and_a_tilted_one_is_said(tmp_path,
                                                                                 capsys):
    """The recording's /tf_static hangs the scanner upside down under the base (rolled
    180 deg, turned 0.5 rad): its scans are mirrored (the replay turns them over), and the
    mount says so; a scanner pitched 10 deg down towards the floor passes without a word, one
    pitched 60 deg is taken as level with a warning."""
    import math

    from laser_tracker.conversions import PlanarTransform, transforms_from_msg, \
        transforms_to_msg
    from laser_tracker.tools.bag import FACTORY, LATCHED_QOS, BagWriter
    from laser_tracker.tools.mount import recording_mount
    from laser_tracker.core.egomotion import EgoMotionConfig

    def recording(name, rotation):
        out = tmp_path / name
        with BagWriter(out) as bag:
            tf = transforms_to_msg(FACTORY, [PlanarTransform(0.0, 'base_link', 'laser', 0.3,
                                                             -0.1, 0.5)])
            for key, value in rotation.items():
                setattr(tf.transforms[0].transform.rotation, key, value)
            bag.write('/tf_static', tf, 1.0, qos=LATCHED_QOS)
            for topic, t_ns, msg in iter_messages(_import(_ros1_bag(tmp_path / f'{name}.bag'),
                                                          tmp_path / f'{name}_so'),
                                                  ['/scan', '/base/odom']):
                bag.write(topic, msg, t_ns)
        return out, transforms_from_msg(tf)[0]

    upside_down, tr = recording('upside_down', dict(x=math.cos(0.25), y=math.sin(0.25), z=0.0,
                                                    w=0.0))
    assert tr.yaw == pytest.approx(0.5) and tr.tilt == pytest.approx(math.pi)
    mount = recording_mount(upside_down, '/scan', '/base/odom', EgoMotionConfig())
    assert (mount.x, mount.y, mount.yaw) == pytest.approx((0.3, -0.1, 0.5))
    assert mount.mirrored and 'upside down' in mount.message
    assert 'warning' not in mount.message
    steep, tr = recording('steep', dict(x=0.0, y=math.sin(math.radians(30)), z=0.0,
                                        w=math.cos(math.radians(30))))
    mount = recording_mount(steep, '/scan', '/base/odom', EgoMotionConfig())
    assert not mount.mirrored and 'warning: the scanner is tilted 60 deg' in mount.message
    pitched, tr = recording('pitched', dict(x=0.0, y=math.sin(math.radians(5)), z=0.0,
                                            w=math.cos(math.radians(5))))
    assert tr.tilt == pytest.approx(math.radians(10))
    mount = recording_mount(pitched, '/scan', '/base/odom', EgoMotionConfig())
    assert not mount.mirrored and 'warning' not in mount.message


def _level_pose(rotation, translation):
    """(x, y, yaw of the x axis, mirrored) of a 3D transform whose z axis is near vertical."""
    m = rotation.as_matrix()
    return (translation[0], translation[1], math.atan2(m[1, 0], m[0, 0]), m[2, 2] < 0)


@pytest.mark.parametrize('rolls', [(math.pi, 0.0), (0.0, math.pi), (math.pi, math.pi),
                                   (math.pi, 0.0, math.pi), (0.0, 0.0)])
def test_a_chain_of_mounts_with_links_upside_down_is_the_3d_chain_on_the_floor(rolls):
    """Each link of base -> ... -> laser is a turn, an offset and a roll of 0 or 180 deg
    (a mast hung under a plate, a scanner under the mast); the planar chain with mirrored
    links puts the scanner where the 3D chain does, in either direction of the tree."""
    from scipy.spatial.transform import Rotation

    from laser_tracker.tools.mount import mount_between

    rng = np.random.default_rng(len(rolls) + int(10 * sum(rolls)))
    frames = ['base'] + [f'f{k}' for k in range(len(rolls) - 1)] + ['laser']
    edges, flips = {}, {}
    chain_r, chain_t = Rotation.identity(), np.zeros(3)
    for k, roll in enumerate(rolls):
        yaw, offset = rng.uniform(-math.pi, math.pi), rng.uniform(-0.5, 0.5, 3)
        r = Rotation.from_euler('ZX', [yaw, roll])
        edges[(frames[k], frames[k + 1])] = (offset[0], offset[1], yaw)
        flips[(frames[k], frames[k + 1])] = abs(roll) > math.pi / 2
        chain_t = chain_t + chain_r.apply(offset)
        chain_r = chain_r * r
    x, y, yaw, mirrored = _level_pose(chain_r, chain_t)
    pose, flipped = mount_between(edges, 'base', 'laser', flips)
    assert flipped == mirrored == (sum(f for f in flips.values()) % 2 == 1)
    assert pose[:2] == pytest.approx((x, y))
    assert math.remainder(pose[2] - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    back, flipped_back = mount_between(edges, 'laser', 'base', flips)
    x, y, yaw, _ = _level_pose(chain_r.inv(), -chain_r.inv().apply(chain_t))
    assert flipped_back == mirrored and back[:2] == pytest.approx((x, y))
    assert math.remainder(back[2] - yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_a_mirrored_scan_is_the_same_returns_seen_from_the_other_side():
    """Turned right side up, an upside-down scanner's return at (x, y) of its own frame lies
    at (x, -y); turned over twice, the scan is itself again, whichever way its beams run."""
    from laser_tracker.core.scan import Scan

    rng = np.random.default_rng(3)
    for increment in (math.radians(0.5), -math.radians(0.5)):
        scan = Scan(1.0, rng.uniform(0.5, 8.0, 361), 0.3, increment, 0.1, 10.0, frame_id='l')
        scan.ranges[::7] = np.inf
        mirror = scan.mirrored()
        a, b = scan.points(), mirror.points()
        assert b[::-1] == pytest.approx(a * (1.0, -1.0))
        twice = mirror.mirrored()
        assert twice.angle_min == pytest.approx(scan.angle_min)
        assert np.array_equal(twice.ranges, scan.ranges)
