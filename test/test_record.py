"""``laser-tracker replay BAG --record OUT``: the recording read back with independent readers
(the ``mcap`` / ``mcap-ros2-support`` packages, rosbags) and checked against the replay's own
outputs; outputs that appear whole or not at all."""
from __future__ import annotations

import csv
import errno
import math
import subprocess
import zlib
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from laser_tracker.conversions import (detections_from_marker_array,
                                       objects_from_marker_array, scan_from_msg, scan_to_msg,
                                       stamp_to_ns, yaw_from_quaternion)
from laser_tracker.core.geometry import compose
from laser_tracker.core.self_mask import SelfMaskConfig, mixed_returns
from laser_tracker.tools.bag import FACTORY, TYPESTORE, BagWriter, iter_messages
from laser_tracker.tools.cli import main
from laser_tracker.tools.data import real_recording
from laser_tracker.tools.record import DEFAULT_GRID_EVERY, POSITION_STEP, TOPICS

from test_stages import ring_scan

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / 'bags' / 'hokuyo_corridor_lobby'     # a scanner mounted off the base's origin
GRIDS_EVERY = 7
PER_SCAN = ['/tf', '/ego_motion', '/ego_motion/status', '/blobs', '/hypotheses', '/tracks',
            '/tracks/markers', '/evaluation']


def run(*argv) -> int:
    return main([str(a) for a in argv])


def read_recording(path: Path) -> dict[str, list]:
    """``{topic: [(log time ns, schema name, decoded message), ...]}`` in log-time order, by
    the mcap packages (not the code that wrote it)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    (mcap_file,) = path.glob('*.mcap')
    out = defaultdict(list)
    with mcap_file.open('rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(
                log_time_order=True):
            out[channel.topic].append((message.log_time, schema.name, decoded))
    return out


def header_ns(msg) -> int:
    if hasattr(msg, 'markers'):
        return stamp_to_ns(msg.markers[0].header.stamp)
    if hasattr(msg, 'transforms'):
        stamps = {stamp_to_ns(t.header.stamp) for t in msg.transforms}
        assert len(stamps) == 1
        return stamps.pop()
    return stamp_to_ns(msg.header.stamp)


def read_csv(path: Path) -> list[dict]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    """hokuyo_corridor_lobby replayed and recorded, with the evaluation and grids every
    GRIDS_EVERY scans."""
    folder = tmp_path_factory.mktemp('record')
    out, rec = folder / 'run', folder / 'rec'
    assert run('replay', BAG, '--out', out, '--record', rec, '--evaluate', '--record-grids',
               GRIDS_EVERY, '--no-progress') == 0
    return out, rec, read_recording(rec)


def test_topics_types_and_one_set_of_messages_per_scan_at_its_stamp(recorded):
    out, _, topics = recorded
    assert set(topics) == set(TOPICS)
    for topic, items in topics.items():
        assert {schema for _, schema, _ in items} == {TOPICS[topic]}, topic
    input_stamps = [stamp_to_ns(m.header.stamp) for _, _, m in iter_messages(BAG, ['/scan'])]
    assert [t for t, _, _ in topics['/scan']] == input_stamps        # every input scan
    assert [header_ns(m) for _, _, m in topics['/scan']] == input_stamps
    replayed = [t for t, _, _ in topics['/ego_motion']]
    ego_csv = read_csv(out / 'ego_motion.csv')
    assert len(replayed) == len(ego_csv) == len(input_stamps) == 300
    assert np.allclose(np.array(replayed) * 1e-9, [float(r['stamp']) for r in ego_csv],
                       atol=2e-6)
    for topic in PER_SCAN:
        items = topics[topic]
        assert [t for t, _, _ in items] == replayed, topic        # one per scan, in order
        assert [header_ns(m) for _, _, m in items] == replayed, topic
    grids = [t for t, _, _ in topics['/grid']]
    assert grids == replayed[::GRIDS_EVERY] == [t for t, _, _ in topics['/grid/difference']]
    assert len(topics['/tf_static']) == 1
    for topic in ('/ground_truth', '/ground_truth/platform'):     # passed through
        assert [header_ns(m) for _, _, m in topics[topic]] == \
            [header_ns(m) for _, _, m in iter_messages(BAG, [topic])]


def frames_used(topics) -> set[str]:
    frames = set()
    for items in topics.values():
        for _, _, m in items:
            for part in getattr(m, 'markers', None) or getattr(m, 'transforms', None) or [m]:
                frames.add(part.header.frame_id)
                frames.add(getattr(part, 'child_frame_id', '') or part.header.frame_id)
    return frames


def tf_edges(topics, stamp: int | None = None) -> dict:
    """``{(parent, child): (x, y, yaw)}`` of /tf_static and of /tf at ``stamp`` (any stamp when
    None)."""
    edges = {}
    for topic in ('/tf_static', '/tf'):
        for _, _, m in topics[topic]:
            for t in m.transforms:
                if topic == '/tf' and stamp is not None and stamp_to_ns(t.header.stamp) != stamp:
                    continue
                tr = t.transform
                edges[(t.header.frame_id, t.child_frame_id)] = (
                    tr.translation.x, tr.translation.y, yaw_from_quaternion(tr.rotation))
    return edges


def planar(pose) -> np.ndarray:
    return np.array([pose.position.x, pose.position.y, yaw_from_quaternion(pose.orientation)])


def test_every_frame_is_connected_to_odom_and_the_chain_is_the_ego_motion(recorded):
    from laser_tracker.tools.mount import find_transform

    _, _, topics = recorded
    edges = tf_edges(topics)
    frames = frames_used(topics) - {''}
    assert frames == {'odom', 'base_link', 'laser', 'map'}
    for frame in frames:
        assert find_transform(edges, 'odom', frame) is not None, frame
    (_, _, static), = topics['/tf_static']
    mount = static.transforms[0].transform.translation
    assert (static.transforms[0].header.frame_id, static.transforms[0].child_frame_id) == \
        ('base_link', 'laser')
    assert (mount.x, mount.y) == pytest.approx((0.85, 0.24))        # the bag's own mount
    truth = {header_ns(m): planar(m.pose.pose) for _, _, m in topics['/ground_truth/platform']}
    for t, _, ego in topics['/ego_motion'][::25]:
        at = tf_edges(topics, t)
        scanner = find_transform(at, 'odom', 'laser')        # each stored to POSITION_STEP
        assert scanner == pytest.approx(planar(ego.pose.pose), abs=POSITION_STEP)
        assert ego.child_frame_id == 'laser' and ego.header.frame_id == 'odom'
        # map -> odom puts the scanner where the truth has it: what evaluate scores against
        true_scanner = compose(truth[t], find_transform(at, 'base_link', 'laser'))
        assert find_transform(at, 'map', 'laser') == pytest.approx(true_scanner,
                                                                   abs=2 * POSITION_STEP)


def test_tracks_and_ego_motion_are_the_replays_own(recorded):
    out, _, topics = recorded
    rows = defaultdict(list)
    for r in read_csv(out / 'tracks.csv'):
        rows[r['stamp']].append(r)
    ego = {r['stamp']: r for r in read_csv(out / 'ego_motion.csv')}
    confirmed_seen = 0
    for (t, _, hyp), (_, _, trk), (_, _, odo), (_, _, vis) in zip(
            topics['/hypotheses'], topics['/tracks'], topics['/ego_motion'],
            topics['/tracks/markers']):
        key = f'{t * 1e-9:.6f}'
        expected = sorted(rows.get(key, []), key=lambda r: int(r['track_id']))
        objects = sorted(objects_from_marker_array(hyp)[2], key=lambda o: o.id)
        assert [o.id for o in objects] == [int(r['track_id']) for r in expected]
        for o, r in zip(objects, expected):      # tracks.csv: 4 decimals
            assert (o.x, o.y, o.vx, o.vy) == pytest.approx(
                tuple(float(r[k]) for k in ('x', 'y', 'vx', 'vy')), abs=POSITION_STEP / 2 + 5e-5)
            assert (o.extra['confirmed'], o.extra['kind']) == (r['confirmed'] == '1', r['kind'])
        confirmed = [o.id for o in objects if o.extra['confirmed']]
        assert sorted(o.id for o in objects_from_marker_array(trk)[2]) == confirmed
        confirmed_seen += len(confirmed)
        labels = {m.id: m.text for m in vis.markers if m.ns == 'track_labels' and m.text}
        assert {i: text.split()[0] for i, text in labels.items()} == \
            {o.id: f'{o.id}' + ('' if o.extra['confirmed'] else '?') for o in objects}
        e = ego[key]
        assert planar(odo.pose.pose) == pytest.approx(
            [float(e['x']), float(e['y']), float(e['theta'])], abs=POSITION_STEP / 2 + 5e-7)
    assert confirmed_seen > 100


def test_blobs_are_the_detection_nodes_message(recorded):
    _, _, topics = recorded
    found = 0
    for _, _, msg in topics['/blobs']:
        detections = detections_from_marker_array(msg)   # the tracking node's own decoder
        assert detections.frame_id == 'odom'
        found += detections.blobs.count + len(detections.people)
    assert found > 100


def test_grids_lie_over_the_scan_in_the_scanner_frame(recorded):
    _, _, topics = recorded
    scans = {t: m for t, _, m in topics['/scan']}
    for (t, _, grid), (_, _, diff) in zip(topics['/grid'], topics['/grid/difference']):
        assert grid.header.frame_id == diff.header.frame_id == 'laser'
        n, res = grid.info.width, grid.info.resolution
        assert (n, grid.info.height) == (160, 160) and res == pytest.approx(0.1)
        assert (grid.info.origin.position.x, grid.info.origin.position.y) == (-8.0, -8.0)
        values = np.asarray(grid.data, np.int8).reshape(n, n)      # [iy, ix]
        assert set(np.unique(values)) <= {-1, 0, 100}
        assert set(np.unique(np.asarray(diff.data, np.int8))) <= {-1, 0, 50, 100}
        scan = scans[t]
        r = np.asarray(scan.ranges, float)
        a = scan.angle_min + scan.angle_increment * np.arange(r.size)
        # the mixed returns beside nearer edges are masked before the grid (self_mask)
        mixed = mixed_returns(scan_from_msg(scan), SelfMaskConfig().beam_width)
        ok = (r > scan.range_min) & (r < scan.range_max) & ~mixed
        xy = np.column_stack((r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])))
        xy = xy[(np.abs(xy) < 7.9).all(axis=1)]
        ix, iy = np.floor(xy * (1 / 0.1) + 80).astype(int).T
        assert (values[iy, ix] == 100).all()            # every end point is an occupied cell
        assert (values == 0).sum() > 1000                # beams freed space


def test_evaluation_markers_are_the_evaluations_verdicts(recorded):
    from laser_tracker.tools.evaluate import evaluate_replay

    out, _, topics = recorded
    mot = evaluate_replay(out, BAG).result['clear_mot']['detectable']
    counts = defaultdict(int)
    for _, _, msg in topics['/evaluation']:
        assert msg.markers[0].action == 3                 # DELETEALL first
        for m in msg.markers[1:]:
            assert m.header.frame_id == 'map'
            counts[m.ns] += len(m.points) // (2 if m.ns == 'matches' else 1)
    assert counts['matches'] == mot['num_matches'] + mot['num_switches'] > 100
    assert counts['misses'] == mot['num_misses']
    assert counts['false_positives'] == mot['num_false_positives']


def test_the_file_is_in_time_order_without_message_index_and_rosbags_reads_it(recorded):
    """What keeps it small and what readers without a message index need (Foxglove reads
    such a file whole, ``ros2 bag play`` in file order): every message in time order in the
    file, the evaluation (computed last) included; a summary with counts and a valid CRC."""
    from mcap.reader import make_reader
    from mcap.records import ChunkIndex, Footer, MessageIndex
    from mcap.stream_reader import StreamReader

    _, rec, topics = recorded
    (path,) = rec.glob('*.mcap')
    with path.open('rb') as fh:
        order = [(m.log_time, c.topic) for _, c, m in make_reader(fh).iter_messages(
            log_time_order=False)]
    assert [t for t, _ in order] == sorted(t for t, _ in order)
    assert {topic for _, topic in order} == set(TOPICS)
    with path.open('rb') as fh:
        records = list(StreamReader(fh, skip_magic=False, emit_chunks=True).records)
    assert not [r for r in records if isinstance(r, (MessageIndex, ChunkIndex))]
    with path.open('rb') as fh:
        summary = make_reader(fh).get_summary()
    counts = {c.topic: summary.statistics.channel_message_counts[i]
              for i, c in summary.channels.items()}
    assert counts == {topic: len(items) for topic, items in topics.items()}
    # the footer's CRC covers the summary and the footer up to it (MCAP specification)
    data, footer = path.read_bytes(), records[-1]
    assert isinstance(footer, Footer)
    assert footer.summary_crc == zlib.crc32(data[footer.summary_start:len(data) - 8 - 4])
    read = [(topic, t) for topic, t, _ in iter_messages(rec, TOPICS)]     # rosbags
    assert sorted(read, key=lambda x: x[1]) == read and len(read) == len(order)


def test_the_compact_file_orders_what_was_written_out_of_order(tmp_path):
    """Equal stamps keep the order they were written in."""
    from mcap.reader import make_reader

    rec = tmp_path / 'rec'
    written = [(3, 'c'), (1, 'a'), (2, 'b1'), (5, 'e'), (2, 'b2'), (4, 'd')]
    with BagWriter(rec, storage='mcap', compact=True) as bag:
        for t, text in written:
            bag.write('/text', FACTORY.make('std_msgs/msg/String', data=text), t)
    with next(rec.glob('*.mcap')).open('rb') as fh:
        got = [(m.log_time, m.data) for _, _, m in make_reader(fh).iter_messages(
            log_time_order=False)]
    assert [t for t, _ in got] == [1, 2, 2, 3, 4, 5]
    assert [TYPESTORE.deserialize_cdr(data, 'std_msgs/msg/String').data for _, data in got] \
        == ['a', 'b1', 'b2', 'c', 'd', 'e']


def test_values_are_stored_to_a_millimetre_and_float32():
    """Positions and vectors on the POSITION_STEP grid, orientations at float32 precision,
    covariances to 3 significant digits; the nodes' factory keeps full precision."""
    from laser_tracker.conversions import PlanarOdometry, odometry_to_msg
    from laser_tracker.tools.record import FACTORY as STORED

    odom = PlanarOdometry(stamp=5.0, x=1.23456789, y=-7.654321, theta=0.3456789, vx=0.1234567)
    cov = np.array([[1.23456e-3, 2e-7, 0.0], [2e-7, 4.5678e-3, 0.0], [0.0, 0.0, 9.87654e-5]])
    full, stored = odometry_to_msg(FACTORY, odom, cov), odometry_to_msg(STORED, odom, cov)
    assert (full.pose.pose.position.x, full.pose.pose.position.y) == (1.23456789, -7.654321)
    p = stored.pose.pose.position
    for value, exact in ((p.x, 1.23456789), (p.y, -7.654321), (stored.twist.twist.linear.x,
                                                                0.1234567)):
        assert (value / POSITION_STEP).is_integer() and abs(value - exact) <= POSITION_STEP / 2
    q, exact_q = stored.pose.pose.orientation, full.pose.pose.orientation
    assert float(np.float32(q.z)) == q.z and q.z == pytest.approx(exact_q.z, rel=1e-7)
    assert yaw_from_quaternion(q) == pytest.approx(0.3456789, abs=1e-6)
    assert np.allclose(stored.pose.covariance, full.pose.covariance, rtol=2 ** -11, atol=0)
    assert np.count_nonzero(stored.pose.covariance) == np.count_nonzero(full.pose.covariance)


def test_the_recording_factory_shares_only_the_defaults_nothing_changes():
    """A Marker's unused texture and mesh are one message for all; its header (restamp()
    changes it) and its point list are its own; the nodes' factory shares nothing."""
    from laser_tracker.conversions import restamp_ns
    from laser_tracker.tools.record import FACTORY as STORED

    def two_markers(factory):
        return [factory.make('visualization_msgs/msg/Marker', ns=ns) for ns in 'ab']

    a, b = two_markers(STORED)
    assert a.texture is b.texture and a.mesh_file is b.mesh_file
    assert a.header is not b.header and a.points is not b.points
    restamp_ns(STORED, a, 5_000_000_001)
    assert (b.header.stamp.sec, b.header.stamp.nanosec) == (0, 0)
    c, d = two_markers(FACTORY)
    assert c.texture is not d.texture and c.mesh_file is not d.mesh_file


def test_sqlite3_storage_without_grids_reads_back_with_rosbags(tmp_path):
    from rosbags.highlevel import AnyReader

    rec = tmp_path / 'rec'
    assert run('replay', 'exp3_rotating_static', '--out', tmp_path / 'o', '--record', rec,
               '--record-storage', 'sqlite3', '--record-grids', 'none', '--no-progress') == 0
    assert list(rec.glob('*.db3'))
    with AnyReader([rec], default_typestore=TYPESTORE) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, _, raw in reader.messages([c for c in reader.connections
                                             if c.topic == '/tracks/markers'][:1]):
            reader.deserialize(raw, conn.msgtype)
    assert '/grid' not in counts and counts['/scan'] == counts['/ego_motion'] == 100
    assert counts['/tracks/markers'] == 100 and '/evaluation' not in counts


def test_default_grids_are_decimated_and_every_gives_all(tmp_path):
    rec = tmp_path / 'rec'
    assert run('replay', 'exp3_rotating_static', '--out', tmp_path / 'o', '--record', rec,
               '--no-progress') == 0
    topics = read_recording(rec)
    assert len(topics['/grid']) == math.ceil(100 / DEFAULT_GRID_EVERY)
    assert run('replay', 'exp3_rotating_static', '--out', tmp_path / 'o', '--record', rec,
               '--overwrite', '--record-grids', 'every', '--no-progress') == 0
    assert len(read_recording(rec)['/grid']) == 100


# ------------------------------------------------------------------ annotated people


def write_annotated_bag(path: Path, n: int = 30) -> list[int]:
    """A scanner in a ring room, a post walking across; the post's position annotated as a
    leg_tracker Person half a period after each scan (as the annotation tool does)."""
    from test_annotations import person_msg

    stamps = []
    with BagWriter(path) as bag:
        for k in range(n):
            t, y = 100.0 + 0.2 * k, -2.0 + 0.15 * k
            msg = scan_to_msg(FACTORY, ring_scan(t, y))
            bag.write('/scan', msg, t)
            bag.write('/ground_truth_people_tracks', person_msg(2.0, y, 7), t + 0.1)
            stamps.append(stamp_to_ns(msg.header.stamp))
    return stamps


def test_annotated_people_become_ground_truth_markers_at_their_scan(tmp_path):
    bag, rec = tmp_path / 'annotated', tmp_path / 'rec'
    stamps = write_annotated_bag(bag)
    assert run('replay', bag, '--out', tmp_path / 'o', '--record', rec, '--evaluate',
               '--no-progress') == 0
    topics = read_recording(rec)
    truth = topics['/ground_truth']
    assert [t for t, _, _ in truth] == stamps
    for k, (_, _, msg) in enumerate(truth):
        (person,) = objects_from_marker_array(msg)[2]
        assert msg.markers[1].header.frame_id == 'laser'
        assert (person.id, person.x, person.y) == pytest.approx((7, 2.0, -2.0 + 0.15 * k),
                                                                abs=POSITION_STEP / 2)
    verdicts = defaultdict(int)
    for _, _, msg in topics['/evaluation']:
        assert all(m.header.frame_id == 'laser' for m in msg.markers[1:])
        for m in msg.markers[1:]:
            verdicts[m.ns] += 1
    assert verdicts['matches'] > 5 and verdicts['misses'] > 0     # found after a few scans


# ------------------------------------------------------------------ bad outputs


def test_existing_output_is_refused_before_the_replay(tmp_path, capsys):
    rec = tmp_path / 'rec'
    rec.mkdir()
    (rec / 'keep').write_text('mine')
    assert run('replay', 'exp3_rotating_static', '--out', tmp_path / 'o', '--record', rec,
               '--no-progress') == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'already exists' in err and '--overwrite' in err
    assert (rec / 'keep').read_text() == 'mine' and not (tmp_path / 'o').exists()


@pytest.mark.parametrize('where', ['under_a_file', 'dev_full'])
def test_unwritable_output_is_one_line_before_the_replay(tmp_path, capsys, where):
    if where == 'under_a_file':
        (tmp_path / 'file').write_text('x')
        rec = tmp_path / 'file' / 'rec'
    else:
        rec = Path('/dev/full/rec')
    assert run('replay', 'exp3_rotating_static', '--out', tmp_path / 'o', '--record', rec,
               '--no-progress') == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(rec) in err and 'cannot be written' in err
    assert not (tmp_path / 'o').exists()


def one_error_line(err: str) -> str:
    """The command's error: one line, the last one (progress notes may come before it)."""
    errors = [line for line in err.strip().splitlines() if ': error: ' in line]
    assert len(errors) == 1 and err.strip().splitlines()[-1] == errors[0], err
    return errors[0]


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith('.rec'))


def _assert_full_disk_leaves_nothing(tmp_path: Path, capsys) -> None:
    """A replay recording into ``tmp_path / 'rec'`` on a disk that fills up: one error line
    naming the recording and the cause, exit 2, nothing left."""
    rec = tmp_path / 'rec'
    assert run('replay', 'exp3_rotating_static', '--out', tmp_path / 'o', '--record', rec,
               '--no-progress') == 2
    err = one_error_line(capsys.readouterr().err)
    assert 'No space left on device' in err and str(rec) in err
    assert not rec.exists() and leftovers(tmp_path) == []


def test_full_disk_mid_write_leaves_nothing(tmp_path, capsys, monkeypatch):
    written = {'n': 0}
    original = BagWriter.write

    def fill_up(self, *args, **kwargs):
        written['n'] += 1
        if written['n'] > 500:
            raise OSError(errno.ENOSPC, 'No space left on device')
        return original(self, *args, **kwargs)

    monkeypatch.setattr(BagWriter, 'write', fill_up)
    _assert_full_disk_leaves_nothing(tmp_path, capsys)


@pytest.mark.parametrize('step', ['closing', 'compacting'])
def test_full_disk_while_closing_leaves_nothing(tmp_path, capsys, monkeypatch, step):
    """The disk fills as rosbags closes the file, or while it is rewritten compact (after a
    part of the compact copy is written)."""
    from rosbags.rosbag2 import Writer
    from laser_tracker.tools import compact_mcap

    def full(*args):
        if step == 'compacting':
            args[2].file.write(b'\x89MCAP0\r\n' + bytes(1000))    # _rewrite's output
        raise OSError(errno.ENOSPC, 'No space left on device')

    if step == 'closing':
        monkeypatch.setattr(Writer, 'close', full)
    else:
        monkeypatch.setattr(compact_mcap, '_rewrite', full)
    _assert_full_disk_leaves_nothing(tmp_path, capsys)


def test_a_really_full_tmpfs_leaves_nothing(tmp_path, capsys):
    mnt = tmp_path / 'tiny'
    mnt.mkdir()
    if subprocess.run(['mount', '-t', 'tmpfs', '-o', 'size=64k', 'tmpfs', str(mnt)],
                      capture_output=True).returncode != 0:
        pytest.skip('cannot mount a tmpfs here (needs root in a namespace that allows it)')
    try:
        rec = mnt / 'rec'
        assert run('replay', 'exp3_rotating_static', '--out', tmp_path / 'o', '--record', rec,
                   '--no-progress') == 2
        err = one_error_line(capsys.readouterr().err)
        assert 'No space left on device' in err
        assert list(mnt.iterdir()) == []
    finally:
        subprocess.run(['umount', str(mnt)], capture_output=True)


def _recording_replay(tmp_path: Path, stderr=subprocess.DEVNULL):
    """A replay of ``crossing_walkers`` recording every grid to ``tmp_path / 'rec'``, in a
    session of its own, once its recording has started: (process, recording path)."""
    import sys
    import time

    rec = tmp_path / 'rec'
    proc = subprocess.Popen([sys.executable, '-m', 'laser_tracker.tools.cli', 'replay',
                             'crossing_walkers', '--out', str(tmp_path / 'o'),
                             '--record', str(rec), '--record-grids', 'every', '--no-progress'],
                            stderr=stderr, text=True, start_new_session=True)
    deadline = time.monotonic() + 60.0
    while not any(tmp_path.glob('.rec*')) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, proc.stderr.read() if proc.stderr else proc.returncode
    time.sleep(0.5)
    return proc, rec


def test_ctrl_c_during_a_recorded_replay_leaves_nothing(tmp_path):
    """The recording is written by a second process: Ctrl-C (SIGINT to the whole process
    group, as a terminal sends it) stops both, and neither the recording nor a temporary file
    is left."""
    import os
    import signal

    proc, rec = _recording_replay(tmp_path, stderr=subprocess.PIPE)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode != 0 and 'Traceback' not in err, err
    assert not rec.exists() and leftovers(tmp_path) == []


@pytest.mark.parametrize('signum', ['SIGTERM', 'SIGKILL'])
def test_a_killed_replay_leaves_no_recording_and_no_recording_process(tmp_path, signum):
    """The replay killed (SIGTERM, or SIGKILL: no cleanup of its own): the recording process
    sees the pipe end, removes the partial recording and exits."""
    import os
    import signal
    import time

    proc, rec = _recording_replay(tmp_path)
    os.kill(proc.pid, getattr(signal, signum))        # the replay alone, not its group
    proc.wait(timeout=30)

    def recording_processes():
        found = []
        for entry in Path('/proc').iterdir():
            try:
                if entry.name.isdigit() and str(rec).encode() in \
                        (entry / 'cmdline').read_bytes():
                    found.append(entry.name)
            except OSError:
                pass
        return found

    deadline = time.monotonic() + 10.0
    while (recording_processes() or leftovers(tmp_path) or rec.exists()) and \
            time.monotonic() < deadline:
        time.sleep(0.1)
    assert recording_processes() == []
    assert not rec.exists() and leftovers(tmp_path) == []


def test_a_failure_in_the_recording_process_is_an_error_not_a_recording(tmp_path,
                                                                       monkeypatch):
    """A bug while building a message (in the recording process) fails the replay with the
    child's traceback; nothing that looks complete is left."""
    from laser_tracker.tools import record
    from laser_tracker.tools.replay import replay_bag

    def broken(*args, **kwargs):
        raise ValueError('a bug in a conversion')

    monkeypatch.setattr(record, 'ego_motion_to_msgs', broken)
    rec = tmp_path / 'rec'
    with pytest.raises(RuntimeError, match='a bug in a conversion'):
        replay_bag('exp3_rotating_static', out_dir=tmp_path / 'o', progress=False,
                   record=record.RecordOptions(rec))
    assert not rec.exists() and leftovers(tmp_path) == []


def test_misused_record_options_are_one_line_errors(tmp_path, capsys):
    out = tmp_path / 'o'
    cases = [
        (['--record-grids', '3'], '--record-grids only with --record OUT'),
        (['--evaluate'], '--evaluate only with --record OUT'),
        (['--record', tmp_path / 'r', '--record-grids', 'often'], "--record-grids 'often'"),
    ]
    for extra, message in cases:
        assert run('replay', 'exp3_rotating_static', '--out', out, '--no-progress',
                   *extra) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
    # --evaluate on a recording with nothing to score per frame: refused before the replay
    bag = tmp_path / 'plain'
    with BagWriter(bag) as w:
        for k in range(5):
            w.write('/scan', scan_to_msg(FACTORY, ring_scan(1.0 + 0.2 * k)), 1.0 + 0.2 * k)
    assert run('replay', bag, '--out', out, '--record', tmp_path / 'r', '--evaluate',
               '--no-progress') == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and '--evaluate needs' in err
    assert not out.exists() and not (tmp_path / 'r').exists()



# ------------------------------------------------------------------ a real run's size


FOLLOWING = real_recording('leg_tracker/person_following_outdoor_1.bag')


@pytest.mark.skipif(not FOLLOWING.exists(), reason=f'{FOLLOWING} not available')
def test_a_real_run_is_recorded_in_at_most_three_times_its_input(tmp_path):
    """leg_tracker's person_following (7,170 scans, 12 minutes) at default settings."""
    from mcap.reader import make_reader

    rec = tmp_path / 'rec'
    assert run('replay', FOLLOWING, '--scan-topic', '/scan_base2', '--out', tmp_path / 'o',
               '--record', rec, '--no-progress') == 0
    size = sum(p.stat().st_size for p in rec.iterdir())
    assert size <= 3 * FOLLOWING.stat().st_size
    with next(rec.glob('*.mcap')).open('rb') as fh:
        summary = make_reader(fh).get_summary()
    counts = {c.topic: summary.statistics.channel_message_counts[i]
              for i, c in summary.channels.items()}
    assert counts['/scan'] == counts['/ego_motion'] == counts['/tracks/markers'] == 7170
    assert counts['/grid'] == math.ceil(7170 / DEFAULT_GRID_EVERY)


@pytest.mark.parametrize('delay', [0.3, 0.6, 0.9, 1.2, 1.5])
def test_ctrl_c_while_a_replay_starts_stops_it_with_one_line(tmp_path, delay):
    """Ctrl-C at any moment of the start (imports, numba loading, the compiled kernels
    loading, where LLVM calls back into Python and a KeyboardInterrupt would be dropped)
    stops the replay with one line and no traceback."""
    import os
    import signal
    import sys
    import time

    proc = subprocess.Popen([sys.executable, '-m', 'laser_tracker.tools.cli', 'replay',
                             'crossing_walkers', '--out', str(tmp_path / 'o'), '--no-progress'],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    time.sleep(delay)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert 'Traceback' not in err and 'Exception ignored' not in err, err
    if proc.returncode == 0:       # a loaded machine: the replay was done before the signal
        assert (tmp_path / 'o' / 'summary.json').exists()
    else:
        assert proc.returncode == 130 and 'interrupted' in err, (proc.returncode, err)


def test_ctrl_c_after_the_work_is_done_is_not_a_death_by_signal(tmp_path):
    """Ctrl-C just after a replay has written its outputs, while Python shuts down (a few
    tenths of a second): the replay ends with its own status, or says it was interrupted;
    it is not killed by the signal."""
    import os
    import signal
    import sys
    import time

    proc = subprocess.Popen([sys.executable, '-m', 'laser_tracker.tools.cli', 'replay',
                             'crossing_walkers', '--out', str(tmp_path / 'o'), '--no-progress'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env={**os.environ, 'PYTHONUNBUFFERED': '1'})
    for line in proc.stdout:
        if line.startswith('outputs in'):      # its last line: then Python shuts down
            time.sleep(0.15)
            os.killpg(proc.pid, signal.SIGINT)
            break
    _, err = proc.communicate(timeout=60)
    assert proc.returncode in (0, 130), (proc.returncode, err)
    assert 'Traceback' not in err and 'Exception ignored' not in err, err
