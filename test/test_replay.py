"""``laser-tracker replay``: outputs with consistent rows on a bundled recording, the API the
evaluate/demo commands use, and bad recordings that must not stop it."""
from __future__ import annotations

import csv
import logging
import json
import math
from pathlib import Path

import numpy as np
import pytest

from laser_tracker.tools.cli import main
from laser_tracker.conversions import PlanarOdometry, header, odometry_to_msg, scan_to_msg
from laser_tracker.core.scan import Scan
from laser_tracker.errors import InputFileError
from laser_tracker.tools.bag import FACTORY, BagWriter
from laser_tracker.tools.replay import replay_bag
from laser_tracker.tools.data import real_data

REPO = Path(__file__).resolve().parents[1]
DATA = real_data()
BUNDLED = REPO / 'bags' / 'exp1_stationary_single_walker'


def read_csv(path):
    with open(path, newline='') as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def bundled():
    if not (BUNDLED / 'metadata.yaml').exists():
        pytest.skip('bags/exp1_stationary_single_walker not found (`make bags` writes it)')
    return BUNDLED


def test_replay_of_a_bundled_recording_writes_consistent_outputs(tmp_path):
    bag = bundled()
    announced = []
    summary = replay_bag(bag, out_dir=tmp_path, progress=False, figure_scan=40,
                         on_confirmed=lambda *a: announced.append(a))
    head, ego = read_csv(tmp_path / 'ego_motion.csv')
    assert head == ['stamp', 'x', 'y', 'theta']
    head, tracks = read_csv(tmp_path / 'tracks.csv')
    assert head == ['stamp', 'track_id', 'x', 'y', 'vx', 'vy', 'weight', 'confirmed', 'kind',
                    'moving']
    assert len(ego) == summary['scans'] > 100
    ego_stamps = [float(r[0]) for r in ego]
    assert ego_stamps == sorted(ego_stamps) and len(set(ego_stamps)) == len(ego_stamps)
    stamps = {float(r[0]) for r in tracks}
    assert stamps <= set(ego_stamps)
    per_scan = {}
    for r in tracks:
        per_scan.setdefault(r[0], []).append(int(r[1]))
        assert r[7] in ('0', '1') and 0.0 <= float(r[6]) <= 100.0
        assert all(math.isfinite(float(v)) for v in r[2:6])
    assert all(len(ids) == len(set(ids)) for ids in per_scan.values())   # unique per scan
    ids = {int(r[1]) for r in tracks}
    assert summary['hypotheses_created'] >= len(ids) > 0
    confirmed = {int(r[1]) for r in tracks if r[7] == '1'}
    assert summary['confirmed_tracks'] == len(confirmed) >= 1
    # on_confirmed: once per track, at the first scan where tracks.csv has it confirmed.
    assert sorted(a[1] for a in announced) == sorted(confirmed)
    for stamp, tid, x, y, vx, vy in announced:
        first = min(float(r[0]) for r in tracks if int(r[1]) == tid and r[7] == '1')
        assert stamp == pytest.approx(first, abs=1e-6)
    s = json.loads((tmp_path / 'summary.json').read_text())
    assert s['scans'] == summary['scans'] and s['scans_skipped'] == {}
    assert sum(s['ego_motion_sources'].values()) == s['scans']
    assert set(s['timing']['ms_per_scan']) >= {'ego_motion', 'grid', 'tracking'}
    for name in ('tracks.png', 'scan_40.png'):
        assert (tmp_path / name).stat().st_size > 10_000


def scan_msg(stamp, n=181, rng=3.0, angle_max=None):
    scan = Scan(stamp=stamp, ranges=np.full(n, rng), angle_min=-math.pi / 2,
                angle_increment=math.pi / (n - 1), range_min=0.05, range_max=8.0)
    msg = scan_to_msg(FACTORY, scan)
    if angle_max is not None:
        msg = FACTORY.make('sensor_msgs/msg/LaserScan', header=header(FACTORY, stamp, 'laser'),
                           angle_min=msg.angle_min, angle_max=angle_max,
                           angle_increment=msg.angle_increment, time_increment=0.0,
                           scan_time=0.0, range_min=0.05, range_max=8.0, ranges=msg.ranges,
                           intensities=msg.intensities)
    return msg


def test_bad_recording_is_survived_and_counted(tmp_path):
    bag = tmp_path / 'bad'
    with BagWriter(bag) as w:
        t = 1.0
        for k in range(6):
            w.write('/scan', scan_msg(t), t)
            t += 0.2
        w.write('/scan', scan_msg(t, n=361), t)                          # beam count changes
        t += 0.2
        nan = scan_msg(t)
        nan.ranges[::2] = np.nan
        w.write('/scan', nan, t)                                          # NaN ranges
        nan_t = t
        t += 0.2
        w.write('/scan', scan_msg(t, angle_max=3.0), t)                   # malformed
        t += 0.2
        w.write('/scan', scan_msg(nan_t), t)                              # duplicate stamp
        w.write('/scan', scan_msg(0.5), t + 0.1)                          # backwards
        for k in range(3):
            w.write('/scan', scan_msg(0.7 + 0.2 * k), t + 0.2 + 0.1 * k)
    summary = replay_bag(bag, out_dir=tmp_path / 'out', progress=False)
    skipped = summary['scans_skipped']
    assert any(k.startswith('malformed scan') for k in skipped)
    assert summary['scan_messages'] == 14
    assert summary['scans'] + sum(skipped.values()) == 14
    assert skipped.get('ego-motion: duplicate stamp') == 1
    assert summary['odom_topic'] is None                                  # scan matching alone
    events = summary['events']
    for stage in ('ego_motion', 'detection', 'tracking'):       # each stage restarts once
        assert events[stage].get('restart') == 1, stage
    _, ego = read_csv(tmp_path / 'out' / 'ego_motion.csv')
    assert len(ego) == summary['scans']


def test_odometry_is_used_when_present(tmp_path):
    bag = tmp_path / 'odo'
    with BagWriter(bag) as w:
        for k in range(8):
            t = 1.0 + 0.2 * k
            for j in range(4):
                s = t - 0.1 + 0.05 * j
                w.write('/odom', odometry_to_msg(FACTORY, PlanarOdometry(s, 0.0, 0.0, 0.0)), s)
            w.write('/scan', scan_msg(t), t + 0.1)
    summary = replay_bag(bag, progress=False)
    assert summary['odom_topic'] == '/odom' and summary['odometry_messages'] == 32
    assert summary['files'] == [] and summary['scans'] == 8


def test_missing_scan_topic_is_a_clear_error(tmp_path):
    bag = tmp_path / 'noscan'
    with BagWriter(bag) as w:
        w.write('/odom', odometry_to_msg(FACTORY, PlanarOdometry(1.0, 0.0, 0.0, 0.0)), 1.0)
    with pytest.raises(InputFileError, match='/scan'):
        replay_bag(bag, progress=False)
    assert main(['replay', str(bag), '--out', str(tmp_path / 'o'), '--no-progress']) == 2


def test_command_line_with_a_config_file(tmp_path, capsys):
    bag = tmp_path / 'small'
    with BagWriter(bag) as w:
        for k in range(5):
            w.write('/scan', scan_msg(1.0 + 0.2 * k), 1.1 + 0.2 * k)
    cfg = tmp_path / 'c.yaml'
    from laser_tracker.tools.config_file import render_defaults
    cfg.write_text(render_defaults().replace('mode: paper', 'mode: cv'))
    out = tmp_path / 'out'
    assert main(['replay', str(bag), '--config', str(cfg), '--out', str(out),
                 '--no-progress']) == 0
    assert '5 scans replayed' in capsys.readouterr().out
    assert json.loads((out / 'summary.json').read_text())['config']['tracking'][
        'kalman.mode'] == 'cv'
    cfg.write_text(cfg.read_text().replace('mode: cv', 'mode: fancy'))
    assert main(['replay', str(bag), '--config', str(cfg), '--out', str(out),
                 '--no-progress']) == 2
    assert 'kalman.mode' in capsys.readouterr().err


def test_real_ros1_recording_without_odometry(tmp_path):
    bag = DATA / 'leg_tracker' / 'demo_stationary_simple_environment.bag'
    if not bag.exists():
        pytest.skip(f'{bag} not found (real data lives beside the repo)')
    summary = replay_bag(bag, out_dir=tmp_path, progress=False)
    assert summary['scans'] >= 1200 and summary['odom_topic'] is None
    assert summary['confirmed_tracks'] > 5                # people walk past
    _, tracks = read_csv(tmp_path / 'tracks.csv')
    assert len(tracks) > 100


def test_topic_options_accept_relative_names_and_refuse_other_types(tmp_path, capsys):
    """--scan-topic scan means /scan; a topic of another type, or absent, is refused with the
    recording's topics of the wanted type (replay, evaluate's scan times, train-detector)."""
    from laser_tracker.tools.bag import read_scan_times, scan_topic_of

    bag = bundled()
    assert main(['replay', str(bag), '--scan-topic', 'scan', '--odom-topic', 'odom',
                 '--out', str(tmp_path / 'rel'), '--no-progress']) == 0
    summary = json.loads((tmp_path / 'rel' / 'summary.json').read_text())
    assert (summary['scan_topic'], summary['odom_topic']) == ('/scan', '/odom')
    with pytest.raises(InputFileError, match='--scan-topic /odom: a nav_msgs/msg/Odometry '
                                             'topic, not sensor_msgs/msg/LaserScan; its '
                                             'LaserScan topics: /scan'):
        read_scan_times(bag, '/odom')
    assert scan_topic_of(bag, None) == '/scan'
    with pytest.raises(InputFileError, match='--scan-topic /front: no such topic'):
        scan_topic_of(bag, '/front')
    without = tmp_path / 'no_odometry'
    with BagWriter(without) as w:
        for k in range(3):
            w.write('/scan', scan_msg(1.0 + 0.2 * k), 1.1 + 0.2 * k)
    capsys.readouterr()
    summary = replay_bag(without, progress=False)        # the default /odom may be absent
    assert summary['odom_topic'] is None
    assert capsys.readouterr().err.count('ego-motion from scan matching alone') == 1
    with pytest.raises(InputFileError, match='--odom-topic /odom: no such topic; its '
                                             'Odometry topics: none'):
        replay_bag(without, odom_topic='/odom', progress=False)   # a given one may not


def test_an_output_folder_that_cannot_be_written_is_named(tmp_path, monkeypatch):
    from laser_tracker.tools.atomic import OutputPathError, check_output

    assert check_output(tmp_path / 'a' / 'b' / 'new') == tmp_path / 'a' / 'b' / 'new'
    with pytest.raises(OutputPathError, match='already exists'):
        check_output(tmp_path)
    assert check_output(tmp_path, overwrite=True) == tmp_path
    monkeypatch.setattr('os.access', lambda path, mode: Path(path) != tmp_path)
    with pytest.raises(OutputPathError, match=f'no permission to write in {tmp_path}'):
        check_output(tmp_path / 'a' / 'new')


def _odometry_as_tf(src, dst):
    """``src`` rewritten as a recording whose odometry is only on /tf (REP 105: odom -> the
    base frame, beside a map -> odom correction and another robot's odometry)."""
    from laser_tracker.conversions import PlanarTransform, odometry_from_msg, transforms_to_msg
    from laser_tracker.tools.bag import iter_messages, topics

    with BagWriter(dst) as w:
        for topic, t_ns, msg in iter_messages(src, list(topics(src))):
            if topic != '/odom':
                w.write(topic, msg, t_ns)
                continue
            o = odometry_from_msg(msg)
            w.write('/tf', transforms_to_msg(FACTORY, [
                PlanarTransform(o.stamp, 'map', 'odom', 5.0, -2.0, 1.0),
                PlanarTransform(o.stamp, 'odom', 'other_robot', -o.x, o.y, 0.0),
                PlanarTransform(o.stamp, 'odom', o.child_frame_id, o.x, o.y, o.theta)]), t_ns)
    return dst


def test_odometry_on_tf_is_used_when_the_recording_has_no_odometry_topic(tmp_path, capsys):
    """A recording that carries its odometry only as odom -> base transforms on /tf (as ROS 1
    robots record it) replays as the same recording with an Odometry topic does; a frame
    named otherwise is not taken for odometry."""
    src = REPO / 'bags' / 'driving_past_people'
    with_topic = replay_bag(src, out_dir=tmp_path / 'topic', progress=False)
    capsys.readouterr()
    bag = _odometry_as_tf(src, tmp_path / 'tf_only')
    with_tf = replay_bag(bag, out_dir=tmp_path / 'tf', progress=False)
    assert 'odometry from /tf (odom -> base_link)' in capsys.readouterr().err
    assert with_tf['odom_topic'] is None and with_tf['odom_tf'] == '/tf: odom -> base_link'
    assert with_tf['odometry_messages'] == with_topic['odometry_messages'] > 0
    assert with_tf['scanner_mount'] == with_topic['scanner_mount']
    assert with_tf['scanner_mount']['source'] == '/tf_static'
    assert with_tf['ego_motion_sources'] == with_topic['ego_motion_sources']
    assert (tmp_path / 'tf' / 'ego_motion.csv').read_text() == \
        (tmp_path / 'topic' / 'ego_motion.csv').read_text()
    assert (tmp_path / 'tf' / 'tracks.csv').read_text() == \
        (tmp_path / 'topic' / 'tracks.csv').read_text()

    cfg = tmp_path / 'frame.yaml'
    cfg.write_text('ego_motion:\n  ros__parameters:\n    odom_frame: wheels\n')
    alone = replay_bag(bag, config=cfg, progress=False)
    assert alone['odom_tf'] is None and alone['odometry_messages'] == 0
    assert "no odometry on /odom or 'wheels' on /tf: ego-motion from scan matching alone" \
        in capsys.readouterr().err


def test_a_recording_rewritten_with_wheel_odometry_on_tf_keeps_its_other_topics(tmp_path):
    """``bench real``'s odometry rows: the scans as /scan, the annotations kept, the
    recording's own odometry replaced by odom -> base_link on /tf at the odometry rate
    (following the scanner poses a replay finds) and the mount on /tf_static."""
    from laser_tracker.tools import bench_real
    from laser_tracker.tools.bag import read_scans, topics

    src = REPO / 'bags' / 'driving_past_people'
    mount = (0.25, -0.2, -0.5)
    dst = tmp_path / 'with_odometry'
    bench_real.write_with_wheel_odometry(src, '/scan', dst, mount, tmp_path / 'icp', seed=3)
    before, after = topics(src), topics(dst)
    assert set(after) == {'/scan', '/ground_truth', '/tf', '/tf_static'}
    assert after['/scan'][1] == before['/scan'][1]
    assert after['/ground_truth'][1] == before['/ground_truth'][1]
    scans = list(read_scans(dst))
    duration = scans[-1].stamp - scans[0].stamp
    assert after['/tf'][1] == pytest.approx(duration * bench_real.ODOMETRY_RATE, abs=2)
    summary = replay_bag(dst, out_dir=tmp_path / 'out', progress=False)
    assert summary['odom_tf'] == '/tf: odom -> base_link'
    m = summary['scanner_mount']
    assert (m['source'], m['x'], m['y'], m['yaw']) == ('/tf_static', *mount)
    reference = np.loadtxt(tmp_path / 'icp' / 'ego_motion.csv', delimiter=',', skiprows=1)
    replayed = np.loadtxt(tmp_path / 'out' / 'ego_motion.csv', delimiter=',', skiprows=1)
    steps = [np.hypot(*np.diff(poses[:, 1:3], axis=0).T) for poses in (reference, replayed)]
    assert steps[1].sum() == pytest.approx(steps[0].sum(), rel=0.02)      # the same drive


@pytest.mark.parametrize('offset', [-130.0, 130.0])
def test_odometry_stamped_by_another_clock_is_read_on_the_scans_clock(tmp_path, offset, caplog):
    """The odometry of the bundled drive stamped ``offset`` s off the scans' clock (a scanner
    that stamps with its own time): found from the arrivals, said once, and the odometry
    prior is used again after the first scans, as on the recording itself."""
    from laser_tracker.tools.bag import iter_messages, topics

    src = REPO / 'bags' / 'driving_past_people'
    bag = tmp_path / 'shifted'
    with BagWriter(bag) as w:
        for topic, t_ns, msg in iter_messages(src, list(topics(src))):
            if topic == '/odom':
                ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec + int(offset * 1e9)
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
            w.write(topic, msg, t_ns)
    as_recorded = replay_bag(src, progress=False)
    with caplog.at_level(logging.WARNING):
        shifted = replay_bag(bag, progress=False)
    events = shifted['events']['ego_motion']
    assert events['odometry clock'] == 1
    said = [r.message for r in caplog.records if 'odometry clock' in r.message]
    assert len(said) == 1 and f"stamps are {'+' if offset > 0 else '-'}1" in said[0]
    assert events.get('note: no odometry', 0) <= 6                 # the first scans only
    assert shifted['confirmed_tracks'] <= as_recorded['confirmed_tracks'] + 1


def test_a_benchmark_parameter_file_is_the_custom_mode_alone(tmp_path):
    """``bench real`` / ``bench sims --config FILE``: the file makes the ``custom`` column;
    ``paper``, ``motion`` and ``defaults`` stay what they are (motion: the defaults without
    the person detector)."""
    from laser_tracker.tools.bench_real import mode_parameters
    config = tmp_path / 'x.yaml'
    config.write_text('/**:\n  ros__parameters:\n    hypotheses:\n      gate: 0.3\n'
                      '    person_detector:\n      enabled: true\n')
    gate = {mode: mode_parameters(mode, [config])['tracking'].sections['hypotheses'].gate
            for mode in ('paper', 'motion', 'defaults', 'custom')}
    assert gate == {'paper': 0.7, 'motion': 0.7, 'defaults': 0.7, 'custom': 0.3}
    detector = mode_parameters('motion', [config])['detection'].sections['person_detector']
    assert detector.enabled is False


def _upside_down_copy(src: Path, dst: Path, turn_mount: bool = True) -> None:
    """``src`` as the same scanner hung upside down would have recorded it: each scan's
    beams in the other order about the mirrored angles, and /tf_static's mount rolled 180 deg
    about the scanner's x axis (same place, same heading of its x axis; not with
    ``turn_mount`` false)."""
    import dataclasses

    from laser_tracker.conversions import scan_from_msg
    from laser_tracker.tools.bag import LATCHED_QOS, iter_messages, topics

    with BagWriter(dst) as bag:
        for topic, t_ns, msg in iter_messages(src, list(topics(src))):
            if msg.__msgtype__ == 'sensor_msgs/msg/LaserScan':
                scan = scan_from_msg(msg)
                last = scan.angle_min + (scan.n_beams - 1) * scan.angle_increment
                msg = scan_to_msg(FACTORY, dataclasses.replace(
                    scan, ranges=scan.ranges[::-1].copy(), angle_min=-last))
            elif topic == '/tf_static' and turn_mount:
                for t in msg.transforms:
                    q = t.transform.rotation
                    half = math.atan2(q.z, q.w)          # half the mount's yaw
                    q.x, q.y, q.z, q.w = math.cos(half), math.sin(half), 0.0, 0.0
            bag.write(topic, msg, int(t_ns), LATCHED_QOS if topic == '/tf_static' else ())


def test_a_scanner_hung_upside_down_is_replayed_as_the_level_one(tmp_path, capsys):
    """A robot whose scanner hangs upside down (off-centre and turned, with odometry): its
    scans are turned over to the level frame, so ego-motion agrees with the odometry and
    the tracks are those of the same robot with the scanner right side up. Taken as level,
    the mirrored scans turn against the odometry and the scene fills with false tracks."""
    level = REPO / 'bags' / 'driving_past_people'
    if not (level / 'metadata.yaml').exists():
        pytest.skip('bags/driving_past_people not found (`make bags` writes it)')
    flipped = tmp_path / 'upside_down'
    _upside_down_copy(level, flipped)
    runs = {}
    for name, bag in (('level', level), ('flipped', flipped)):
        summary = replay_bag(bag, out_dir=tmp_path / name, progress=False)
        runs[name] = (summary, read_csv(tmp_path / name / 'tracks.csv')[1],
                      np.array(read_csv(tmp_path / name / 'ego_motion.csv')[1], float))
    assert not runs['level'][0]['scanner_mount']['mirrored']
    assert runs['flipped'][0]['scanner_mount']['mirrored']
    assert 'upside down' in capsys.readouterr().err
    assert runs['flipped'][0]['confirmed_tracks'] == runs['level'][0]['confirmed_tracks'] > 0
    np.testing.assert_allclose(runs['flipped'][2], runs['level'][2], atol=1e-4)
    got, want = (np.array([[float(v) for v in row[:4]] + [row[7] == '1']
                           for row in runs[name][1]]) for name in ('flipped', 'level'))
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, atol=1e-3)   # stamp, id, x, y, confirmed
    # recorded to look at: the scans turned over, in the level mount the recording states
    from laser_tracker.conversions import scan_from_msg
    from laser_tracker.tools.bag import iter_messages
    assert main(['replay', str(flipped), '--out', str(tmp_path / 'r'), '--record',
                 str(tmp_path / 'rec'), '--no-progress']) == 0
    first = {}
    for name, bag in (('level', level), ('recorded', tmp_path / 'rec')):
        for _, _, msg in iter_messages(bag, ['/scan']):
            first[name] = scan_from_msg(msg)
            break
    assert first['recorded'].angle_min == pytest.approx(first['level'].angle_min)
    np.testing.assert_allclose(first['recorded'].ranges, first['level'].ranges, atol=1e-3)
    # the same scans with a /tf_static that says the scanner is level: taken as they are
    _upside_down_copy(level, tmp_path / 'said_level', turn_mount=False)
    said = replay_bag(tmp_path / 'said_level', out_dir=tmp_path / 'x', progress=False)
    ego = np.array(read_csv(tmp_path / 'x' / 'ego_motion.csv')[1], float)
    assert not said['scanner_mount']['mirrored']
    assert np.abs(ego[:, 1:3] - runs['level'][2][:, 1:3]).max() > 0.5
    assert said['confirmed_tracks'] > runs['level'][0]['confirmed_tracks']


def _stamped_at_receive(src: Path, dst: Path, clear_stamps: bool) -> None:
    """``src`` with every scan and odometry message received at its header stamp; with
    ``clear_stamps`` those header stamps are then left unset (0), as some drivers and
    simulators record them."""
    from laser_tracker.tools.bag import LATCHED_QOS, iter_messages, topics

    with BagWriter(dst) as bag:
        for topic, t_ns, msg in iter_messages(src, list(topics(src))):
            if topic in ('/scan', '/odom'):
                t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                if clear_stamps:
                    msg.header.stamp.sec = msg.header.stamp.nanosec = 0
            bag.write(topic, msg, int(t_ns), LATCHED_QOS if topic == '/tf_static' else ())


def test_scans_and_odometry_without_header_stamps_are_stamped_with_their_receive_times(
        tmp_path, caplog):
    """A recording whose scans and odometry carry no header stamp (0): each message is
    stamped with its receive time, once said per topic, and the replay is that of the same
    recording stamped at those times (before, every scan after the first was a duplicate
    stamp and skipped)."""
    from laser_tracker.tools.bag import read_scan_times, read_scans
    src = REPO / 'bags' / 'driving_past_people'
    if not (src / 'metadata.yaml').exists():
        pytest.skip('bags/driving_past_people not found (`make bags` writes it)')
    _stamped_at_receive(src, tmp_path / 'stamped', clear_stamps=False)
    _stamped_at_receive(src, tmp_path / 'unstamped', clear_stamps=True)
    with caplog.at_level(logging.WARNING):
        unstamped = replay_bag(tmp_path / 'unstamped', out_dir=tmp_path / 'u', progress=False)
    stamped = replay_bag(tmp_path / 'stamped', out_dir=tmp_path / 's', progress=False)
    scans = stamped['scans']
    assert unstamped['scans'] == scans > 100 and not unstamped['scans_skipped']
    assert unstamped['stamped_with_receive_time']['/scan'] == scans
    assert unstamped['stamped_with_receive_time']['/odom'] > scans
    assert not stamped['stamped_with_receive_time']
    assert sum('carries no header stamp' in r.getMessage() for r in caplog.records) == 2
    assert unstamped['confirmed_tracks'] == stamped['confirmed_tracks'] > 0
    for name in ('tracks.csv', 'ego_motion.csv'):
        assert read_csv(tmp_path / 'u' / name) == read_csv(tmp_path / 's' / name)
    times = read_scan_times(tmp_path / 'unstamped', '/scan')
    np.testing.assert_allclose(times.stamps, times.receive_ns * 1e-9, rtol=0, atol=1e-9)
    first = next(read_scans(tmp_path / 'unstamped', '/scan'))
    assert first.stamp == pytest.approx(times.stamps[0]) and first.stamp > 0
