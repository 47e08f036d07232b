"""CARMEN log reading and ``laser-tracker import-carmen``: real logs reproduced scan for scan,
small synthetic logs for the geometry, the no-return value and every kind of bad input."""
from __future__ import annotations

import gzip
import logging
import math
from pathlib import Path

import numpy as np
import pytest

from laser_tracker.core.geometry import wrap_angle
from laser_tracker.errors import InputFileError
from laser_tracker.tools.bag import read_odometry, read_platform_truth, read_scans, topics
from laser_tracker.tools.carmen import detect_max_reading, flaser_geometry, read_carmen
from laser_tracker.tools.cli import main
from laser_tracker.tools.data import real_data
from laser_tracker.tools.odometry_noise import increments_of

DATA = real_data() / 'carmen'


def _real(name: str) -> Path:
    path = DATA / name
    if not path.exists():
        pytest.skip(f'{DATA / name} not found (the public recordings: $LASER_TRACKER_DATA)')
    return path


def _lines(path: Path):
    opener = gzip.open if path.suffix == '.gz' else open
    with opener(path, 'rt') as fh:
        for line in fh:
            yield line.split()


def _flaser_line(n, ranges, pose=(1.0, 2.0, 0.5), odom=(1.1, 2.1, 0.4), stamp=100.0):
    vals = ' '.join(f'{r:.2f}' for r in ranges)
    return (f'FLASER {n} {vals} {pose[0]} {pose[1]} {pose[2]} {odom[0]} {odom[1]} {odom[2]} '
            f'{stamp:.6f} testhost {stamp + 0.01:.6f}\n')


def _odom_line(x, y, th, stamp, tv=0.3, rv=0.1):
    return f'ODOM {x} {y} {th} {tv} {rv} 0.0 {stamp:.6f} testhost {stamp:.6f}\n'


def _write_log(path: Path, n_scans=5, n_beams=181, odom=True, extra='') -> Path:
    rng = np.random.default_rng(0)
    text = ['# CARMEN Logfile\n', '# message formats defined: PARAM SYNC ODOM FLASER\n',
            'PARAM robot_frontlaser_offset 0.0 nohost 0\n']
    for i in range(n_scans):
        if odom:
            text.append(_odom_line(0.1 * i, 0.0, 0.01 * i, 100.0 + i - 0.05))
        r = np.round(rng.uniform(0.5, 20.0, n_beams), 2)
        r[::17] = 81.91  # no return
        text.append(_flaser_line(n_beams, r, pose=(0.1 * i, 0.0, 0.01 * i),
                                 odom=(0.2 * i, 0.05, 0.02 * i), stamp=100.0 + i))
    text.append(extra)
    path.write_text(''.join(text))
    return path


def _cli(capsys, *argv):
    status = main(['import-carmen', *map(str, argv)])
    return status, capsys.readouterr()


# -------------------------------------------------------------------------- reading


def test_flaser_beam_geometry_conventions():
    assert flaser_geometry(181) == (-math.pi / 2, math.pi / 180)
    assert flaser_geometry(361) == (-math.pi / 2, math.pi / 360)
    # CARMEN's 180-beam convention: 1 degree steps from -90 (last beam at +89 deg)
    assert flaser_geometry(180) == (-math.pi / 2, math.pi / 180)


def test_read_synthetic_log(tmp_path):
    path = _write_log(tmp_path / 'a.log', n_scans=4, n_beams=181)
    log = read_carmen(path)
    assert log.kind == 'FLASER' and len(log) == 4 and log.n_beams == 181
    assert log.range_max == pytest.approx(81.91)
    np.testing.assert_allclose(log.stamps, [100.0, 101.0, 102.0, 103.0])
    np.testing.assert_allclose(log.laser_poses[2], (0.2, 0.0, 0.02))
    np.testing.assert_allclose(log.odom_poses[3], (0.6, 0.05, 0.06))
    assert log.odom_stamps.size == 4 and log.odom_velocities[0, 0] == pytest.approx(0.3)
    assert log.skipped == {'PARAM': 1}
    scan = log.scan(1)
    assert np.isposinf(scan.ranges[::17]).all()          # no return -> +inf (REP 117)
    assert not scan.valid()[::17].any()
    assert np.isfinite(np.delete(scan.ranges, np.arange(0, 181, 17))).all()
    assert scan.angle_min == pytest.approx(-math.pi / 2)
    assert scan.angle_min + 180 * scan.angle_increment == pytest.approx(math.pi / 2)


def test_max_reading_detection_and_override(tmp_path):
    r = np.array([[1.0, 50.0, 2.0], [50.0, 3.0, 49.9]])
    assert detect_max_reading(r) == 50.0
    assert detect_max_reading(np.array([[1.0, 2.0, 3.0]])) is None  # no repeated maximum
    path = _write_log(tmp_path / 'b.log', n_scans=2)
    log = read_carmen(path, max_reading=15.0)
    assert log.range_max == 15.0
    assert (np.isposinf(log.scan_ranges()) == (log.ranges >= 15.0 - 0.005)).all()


def test_robotlaser1_lines_carry_their_geometry(tmp_path):
    ranges = ' '.join(['2.50'] * 10)
    line = (f'ROBOTLASER1 0 -0.7854 1.5708 0.174533 8.0 0.1 0 10 {ranges} 0 '
            f'1.0 2.0 0.3 0.9 2.0 0.3 0.2 0.0 0.5 0.3 0.0 42.5 host 42.6\n')
    path = tmp_path / 'r.log'
    path.write_text(line + line.replace('42.5 host', '42.7 host'))
    log = read_carmen(path)
    assert log.kind == 'ROBOTLASER1' and len(log) == 2
    assert log.angle_min == pytest.approx(-0.7854)
    assert log.angle_increment == pytest.approx(0.174533)
    assert log.range_max == 8.0
    np.testing.assert_allclose(log.laser_poses[0], (1.0, 2.0, 0.3))
    np.testing.assert_allclose(log.odom_poses[0], (0.9, 2.0, 0.3))
    np.testing.assert_allclose(log.stamps, [42.5, 42.7])


# --------------------------------------------------------------------- real logs


@pytest.mark.parametrize('name', ['intel-corrected.log.gz', 'mit-csail.clf'])
def test_import_reproduces_scan_count_and_ranges(tmp_path, capsys, name):
    path = _real(name)
    flaser = [t for t in _lines(path) if t and t[0] == 'FLASER']
    out = tmp_path / 'bag'
    status, cap = _cli(capsys, path, out)
    assert status == 0, cap.err
    info = topics(out)
    assert info['/scan'][1] == len(flaser)
    assert info['/odom'][1] == len(flaser)   # a corrected log: one noisy sample per scan;
    corrected = 'corrected' in name           # mit-csail: no ODOM lines, the FLASER odometry
    assert ('/ground_truth/platform' in info) == corrected
    assert info['/tf_static'][1] == 1                   # the scanner at the platform origin
    from laser_tracker.tools.mount import recording_mount
    from laser_tracker.core.egomotion import EgoMotionConfig
    mount = recording_mount(out, '/scan', '/odom', EgoMotionConfig())
    assert mount.from_recording and (mount.x, mount.y, mount.yaw) == (0.0, 0.0, 0.0)
    scans = list(read_scans(out))
    assert len(scans) == len(flaser)
    # the bag is in time order; the log may not be: match scans to lines by stamp
    by_stamp = {round(float(t[2 + int(t[1]) + 6]), 6): t for t in flaser}
    logged_max = max(float(v) for t in flaser for v in t[2:2 + int(t[1])])
    checked = 0
    for scan in scans[::25]:
        t = by_stamp[round(scan.stamp, 6)]
        n = int(t[1])
        logged = np.array(t[2:2 + n], dtype=float)
        assert scan.n_beams == n
        no_return = logged >= logged_max - 0.005
        assert np.isposinf(scan.ranges[no_return]).all()
        np.testing.assert_allclose(scan.ranges[~no_return], logged[~no_return], atol=1e-5)
        assert scan.range_max == pytest.approx(logged_max, abs=1e-4)
        checked += 1
    assert checked >= len(flaser) // 25
    assert scans[0].angle_min == pytest.approx(-math.pi / 2, abs=1e-6)
    stamps = [s.stamp for s in scans]
    assert stamps == sorted(stamps)


def test_import_without_odom_lines_uses_flaser_odometry(tmp_path, capsys):
    path = _write_log(tmp_path / 'no_odom.log', n_scans=3, odom=False)
    status, cap = _cli(capsys, path, tmp_path / 'bag')
    assert status == 0, cap.err
    assert 'from FLASER lines' in cap.out
    track = read_odometry(tmp_path / 'bag')
    np.testing.assert_allclose(track.poses[:, :2], [[0.0, 0.05], [0.2, 0.05], [0.4, 0.05]],
                               atol=1e-9)
    np.testing.assert_allclose(track.stamps, [100.0, 101.0, 102.0])


def test_corrected_log_gets_ground_truth_and_a_noisy_odometry(tmp_path, capsys):
    path = _real('freiburg-079-part1-corrected.log.gz')
    log = read_carmen(path)
    out = tmp_path / 'bag'
    status, cap = _cli(capsys, path, out, '--odometry-noise', 'poor', '--seed', '3')
    assert status == 0, cap.err
    assert 'corrected poses on /ground_truth/platform' in cap.out
    truth = read_platform_truth(out)
    np.testing.assert_allclose(truth.stamps, log.stamps)
    np.testing.assert_allclose(truth.poses[:, :2], log.laser_poses[:, :2], atol=1e-6)
    np.testing.assert_allclose(wrap_angle(truth.poses[:, 2] - log.laser_poses[:, 2]), 0.0,
                               atol=1e-6)
    odom = read_odometry(out)
    np.testing.assert_allclose(odom.stamps, log.stamps)
    err = increments_of(odom.poses) - increments_of(truth.poses)
    assert np.std(err[:, 0]) == pytest.approx(0.05, rel=0.1)       # the poor model
    assert np.degrees(np.std(err[:, 2])) == pytest.approx(2.0, rel=0.1)
    # the same seed gives the same odometry; none gives the reference itself
    status, _ = _cli(capsys, path, tmp_path / 'again', '--odometry-noise', 'poor',
                     '--seed', '3')
    np.testing.assert_allclose(read_odometry(tmp_path / 'again').poses, odom.poses)
    status, _ = _cli(capsys, path, tmp_path / 'exact', '--odometry-noise', 'none')
    exact = read_odometry(tmp_path / 'exact').poses
    np.testing.assert_allclose(exact[:, :2], truth.poses[:, :2], atol=1e-6)
    np.testing.assert_allclose(wrap_angle(exact[:, 2] - truth.poses[:, 2]), 0.0, atol=1e-6)


def test_noisy_odometry_is_refused_for_a_raw_log(tmp_path, capsys):
    path = _write_log(tmp_path / 'raw.log', n_scans=3)
    out = tmp_path / 'bag'
    status, cap = _cli(capsys, path, out, '--odometry-noise', 'realistic')
    assert status == 2 and 'for corrected logs' in cap.err and not out.exists()



def test_scan_period_stamps_the_scans_apart_in_the_logs_order(tmp_path, capsys):
    """A subsampled log whose stamps go back once: the scans keep the log's order (the
    drive's), stamped S apart, each scan's header with its receive time and its odometry."""
    stamps = [100.0, 103.0, 102.5, 109.0]
    text = ['# CARMEN Logfile\n']
    for i, t in enumerate(stamps):
        r = np.full(181, 1.0 + i)
        r[-1] = 81.91                       # the log's no-return reading
        text.append(_flaser_line(181, r, pose=(0.1 * i, 0.0, 0.0), odom=(0.2 * i, 0.0, 0.0),
                                 stamp=t))
    path = tmp_path / 'sub.log'
    path.write_text(''.join(text))
    status, cap = _cli(capsys, path, tmp_path / 'bag', '--scan-period', '0.5')
    assert status == 0, cap.err
    scans = list(read_scans(tmp_path / 'bag'))
    assert [s.stamp for s in scans] == pytest.approx([100.0, 100.5, 101.0, 101.5])
    assert [float(s.ranges[0]) for s in scans] == [1.0, 2.0, 3.0, 4.0]     # the log's order
    odom = read_odometry(tmp_path / 'bag')
    np.testing.assert_allclose(odom.stamps, [100.0, 100.5, 101.0, 101.5])
    np.testing.assert_allclose(odom.poses[:, 0], [0.0, 0.2, 0.4, 0.6], atol=1e-9)
    # without it, the stamps are sorted (the third line goes before the second)
    status, cap = _cli(capsys, path, tmp_path / 'sorted')
    assert [float(s.ranges[0]) for s in read_scans(tmp_path / 'sorted')] == [1.0, 3.0, 2.0, 4.0]


def test_scan_period_is_refused_when_it_cannot_hold(tmp_path, capsys):
    path = _write_log(tmp_path / 'raw.log', n_scans=3)      # ODOM lines of their own stamps
    status, cap = _cli(capsys, path, tmp_path / 'bag', '--scan-period', '1')
    assert status == 2 and 'ODOM lines' in cap.err and not (tmp_path / 'bag').exists()
    for bad in ('0', '-1', 'nan'):
        status, cap = _cli(capsys, path, tmp_path / 'bag', '--scan-period', bad)
        assert status == 2 and '--scan-period must be a positive' in cap.err


# ---------------------------------------------------------------- messy time stamps


def _messy(tmp_path, lines: str, n_scans=6, **kw) -> Path:
    return _write_log(tmp_path / 'messy.log', n_scans=n_scans, extra=lines, **kw)


def _issue(log, text: str) -> int:
    found = [n for message, n in log.issues.items() if text in message]
    assert len(found) == 1, (text, log.issues)
    return found[0]


def test_negative_odom_stamp_is_skipped_or_refused_with_strict(tmp_path, capsys, caplog):
    path = _messy(tmp_path, _odom_line(9.0, 9.0, 0.0, -3.0))
    with caplog.at_level(logging.WARNING, logger='laser_tracker.tools.carmen'):
        log = read_carmen(path)
    assert _issue(log, 'ODOM lines stamped negative') == 1
    assert log.odom_stamps.size == 6 and np.all(log.odom_stamps > 0)
    assert sum('stamped negative' in r.message for r in caplog.records) == 1
    with pytest.raises(InputFileError, match='time stamp must be finite and >= 0') as info:
        read_carmen(path, strict=True)
    assert info.value.location == f'line {len(path.read_text().splitlines())}'
    out = tmp_path / 'out'
    status, cap = _cli(capsys, path, out, '--strict')
    _assert_failed(status, cap, out, path, len(path.read_text().splitlines()))
    status, cap = _cli(capsys, path, out)
    assert status == 0 and read_odometry(out).stamps.size == 6


def test_stamps_with_too_few_digits_are_spread(tmp_path):
    # the same stamp printed for three ODOM lines and for two laser lines
    rng = np.random.default_rng(1)
    text = []
    for i in range(4):
        stamp = 1000.0 + (i // 2)                        # 1000, 1000, 1001, 1001
        for j in range(3):
            text.append(_odom_line(0.1 * i + 0.01 * j, 0.0, 0.0, stamp + 0.5 * (i % 2)))
        text.append(_flaser_line(181, np.round(rng.uniform(1, 9, 181), 2), stamp=stamp))
    path = tmp_path / 'digits.log'
    path.write_text(''.join(text))
    log = read_carmen(path)
    assert _issue(log, 'FLASER lines share their time stamp') == 2
    np.testing.assert_allclose(log.stamps, [1000.0, 1000.5, 1001.0, 1001.5])
    assert _issue(log, 'ODOM lines share their time stamp') == 8
    assert np.all(np.diff(log.odom_stamps) > 0)
    np.testing.assert_allclose(log.odom_stamps[:3], [1000.0, 1000.5 / 3 + 2000 / 3,
                                                     1000.0 + 1.0 / 3])
    with pytest.raises(InputFileError, match='repeats the previous'):
        read_carmen(path, strict=True)


def test_out_of_order_odometry_sorted_or_dropped_and_reported_once(tmp_path, capsys, caplog):
    # two lines a little late (sorted in), two stamped seconds early (dropped), and the
    # corrected logs' habit: ODOM lines stamped 0 between the real ones (dropped)
    extra = (_odom_line(9.0, 9.0, 0.0, 104.8) + _odom_line(8.0, 8.0, 0.0, 104.6)
             + _odom_line(7.0, 7.0, 0.0, 101.5) + _odom_line(7.0, 7.0, 0.0, 101.2)
             + ''.join(_odom_line(0.5, 0.5, 0.0, 0.0) for _ in range(5)))
    path = _messy(tmp_path, extra, n_scans=6)
    with caplog.at_level(logging.WARNING, logger='laser_tracker.tools.carmen'):
        log = read_carmen(path)
    assert _issue(log, 'out of time order: sorted') == 2     # after the log's 104.95
    assert _issue(log, 'more than 1 s before') == 2
    assert _issue(log, 'stamped 0 after later ones') == 5
    assert np.all(np.diff(log.odom_stamps) > 0)
    assert log.odom_stamps.size == 6 + 2
    assert 8.0 in log.odom_stream[:, 0] and 7.0 not in log.odom_stream[:, 0]
    # one warning per kind, whatever the count
    messages = [r.message for r in caplog.records]
    assert len(messages) == len(log.issues) and len(set(messages)) == len(messages)
    with pytest.raises(InputFileError, match='before an earlier ODOM line'):
        read_carmen(path, strict=True)
    out = tmp_path / 'bag'
    status, cap = _cli(capsys, path, out)
    assert status == 0, cap.err
    track = read_odometry(out)
    assert list(track.stamps) == sorted(track.stamps) and len(track) == 8


def test_unstamped_odom_lines_are_dropped(tmp_path):
    extra = ''.join(_odom_line(0.5, 0.5, 0.0, 0.0) for _ in range(5))
    log = read_carmen(_messy(tmp_path, extra))
    assert _issue(log, 'stamped 0 after later ones') == 5
    assert log.odom_stamps.size == 6 and log.odom_stamps.min() > 99.0


def test_odom_lines_disagreeing_with_the_laser_odometry_are_reported(tmp_path):
    log = read_carmen(_messy(tmp_path, ''))  # FLASER odometry (0.2 i, 0.05) vs ODOM (0.1 i, 0)
    n = _issue(log, 'odometry fields disagree with the ODOM lines')
    assert 4 <= n <= 6
    assert log.odometry()[3] == 'ODOM'


# ------------------------------------------------------------------------ bad input


def _assert_failed(status, cap, out: Path, path: Path, line: int):
    assert status != 0
    assert str(path) in cap.err and f'line {line}' in cap.err
    assert not out.exists()
    assert not any(p.name.startswith(f'.{out.name}.') for p in out.parent.iterdir())


def test_malformed_number_names_file_and_line(tmp_path, capsys):
    path = _write_log(tmp_path / 'bad.log', n_scans=3)
    lines = path.read_text().splitlines(keepends=True)
    target = next(i for i, ln in enumerate(lines) if ln.startswith('FLASER') and i > 5)
    lines[target] = lines[target].replace(' 81.91 ', ' 8x.91 ', 1)
    path.write_text(''.join(lines))
    out = tmp_path / 'out'
    status, cap = _cli(capsys, path, out)
    _assert_failed(status, cap, out, path, target + 1)
    assert "'8x.91' is not a number" in cap.err


def test_line_cut_short_names_file_and_line(tmp_path, capsys):
    path = _write_log(tmp_path / 'cut.log', n_scans=3)
    text = path.read_text()
    path.write_text(text + 'FLASER 181 1.0 2.0 3.0\n')
    n_lines = len(path.read_text().splitlines())
    out = tmp_path / 'out'
    status, cap = _cli(capsys, path, out)
    _assert_failed(status, cap, out, path, n_lines)
    assert 'needs 190 or 192 fields' in cap.err


def test_bad_odom_line_names_file_and_line(tmp_path, capsys):
    path = _write_log(tmp_path / 'odom.log', n_scans=2, extra='ODOM 1 2\n')
    n_lines = len(path.read_text().splitlines())
    out = tmp_path / 'out'
    status, cap = _cli(capsys, path, out)
    _assert_failed(status, cap, out, path, n_lines)


def test_truncated_gzip_names_file_and_line(tmp_path, capsys):
    plain = _write_log(tmp_path / 'full.log', n_scans=40)
    data = gzip.compress(plain.read_bytes())
    path = tmp_path / 'trunc.log.gz'
    path.write_bytes(data[: len(data) * 2 // 3])
    out = tmp_path / 'out'
    status, cap = _cli(capsys, path, out)
    assert status != 0
    assert str(path) in cap.err and 'line ' in cap.err
    assert 'truncated' in cap.err or 'needs' in cap.err
    assert not out.exists()
    with pytest.raises(InputFileError) as info:
        read_carmen(path)
    assert info.value.location.startswith('line ')


def test_changing_beam_count_and_no_laser_lines_are_errors(tmp_path):
    path = _write_log(tmp_path / 'mixed.log', n_scans=2, n_beams=181)
    path.write_text(path.read_text() + _flaser_line(361, [1.0] * 361, stamp=200.0))
    with pytest.raises(InputFileError, match='361 beams after 181-beam scans'):
        read_carmen(path)
    empty = tmp_path / 'empty.log'
    empty.write_text('# nothing\nODOM 0 0 0 0 0 0 1.0 h 1.0\n')
    with pytest.raises(InputFileError, match='no FLASER or ROBOTLASER1 lines'):
        read_carmen(empty)
    with pytest.raises(InputFileError, match='no such file'):
        read_carmen(tmp_path / 'missing.log')


def test_existing_output_is_left_alone(tmp_path, capsys):
    path = _write_log(tmp_path / 'ok.log', n_scans=2)
    out = tmp_path / 'out'
    out.mkdir()
    (out / 'keep.txt').write_text('mine')
    status, cap = _cli(capsys, path, out)
    assert status != 0 and 'already exists' in cap.err
    assert (out / 'keep.txt').read_text() == 'mine'
    status, cap = _cli(capsys, path, out, '--overwrite')
    assert status == 0 and topics(out)['/scan'][1] == 2
