"""False tracks on static structure: a synthetic corrected CARMEN log with known answers."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from laser_tracker.conversions import PlanarOdometry, odometry_to_msg
from laser_tracker.core.geometry import compose, inverse, transform_points
from laser_tracker.tools.bag import FACTORY, BagWriter
from laser_tracker.tools.carmen import read_carmen
from laser_tracker.tools.data import real_recording
from laser_tracker.tools.static_map import (StaticMap, StaticMapConfig, ego_segments,
                                            scan_cells)

from bench_rows import bench_real_row
from test_evaluate import run_cli, write_replay

N_SCANS = 120
DT = 0.25                                  # 4 Hz, as freiburg-079
ROOM = [((-6, -4), (6, -4)), ((6, -4), (6, 4)), ((6, 4), (-6, 4)), ((-6, 4), (-6, -4)),
        ((1.0, 1.0), (1.4, 1.0)), ((1.4, 1.0), (1.4, 1.4)), ((1.4, 1.4), (1.0, 1.4)),
        ((1.0, 1.4), (1.0, 1.0))]          # a room with a 0.4 m pillar
PILLAR = (1.2, 0.9)                        # a point on the pillar's near face
STAND = (-2.0, 2.0)                        # where the person stands at first


def person_at(k):
    """Stands at STAND for 15 scans, then walks away at 1 m/s (out of the room by k = 40)."""
    if k < 15:
        return STAND
    return (STAND[0] + 1.0 * (k - 15) * DT, STAND[1] - 0.3 * (k - 15) * DT)


def reference_pose(k):
    return np.array([-3.0 + 0.04 * k, -1.5 + 0.01 * k, 0.5 + 0.004 * k])


def ray_cast(pose, angles, person):
    """Ranges from ``pose`` to the room's segments and a 0.2 m radius person (or None)."""
    x, y, t = pose
    d = np.stack((np.cos(angles + t), np.sin(angles + t)), axis=1)
    best = np.full(angles.size, 81.91)
    for (ax, ay), (bx, by) in ROOM:
        e = np.array([bx - ax, by - ay])
        w = np.array([ax - x, ay - y])
        den = d[:, 0] * e[1] - d[:, 1] * e[0]
        with np.errstate(divide='ignore', invalid='ignore'):
            s = (w[0] * e[1] - w[1] * e[0]) / den
            u = (w[0] * d[:, 1] - w[1] * d[:, 0]) / den
        ok = (np.abs(den) > 1e-12) & (s > 0) & (u >= 0) & (u <= 1)
        best = np.where(ok & (s < best), s, best)
    if person is not None:
        px, py = person[0] - x, person[1] - y
        b = d[:, 0] * px + d[:, 1] * py
        c = px * px + py * py - 0.2 ** 2
        disc = b * b - c
        s = b - np.sqrt(np.maximum(disc, 0))
        ok = (disc >= 0) & (s > 0)
        best = np.where(ok & (s < best), s, best)
    return best


def write_log(path: Path):
    angles = np.radians(np.arange(-90, 91, 1.0))
    lines = []
    for k in range(N_SCANS):
        p = reference_pose(k)
        r = ray_cast(p, angles, person_at(k))
        t = 100.0 + k * DT
        lines.append('FLASER 181 ' + ' '.join(f'{v:.3f}' for v in r)
                     + f' {p[0]:.4f} {p[1]:.4f} {p[2]:.5f} {p[0]:.4f} {p[1]:.4f} {p[2]:.5f}'
                     f' {t:.3f} host {t:.3f}')
    path.write_text('\n'.join(lines) + '\n')


def write_reference_bag(log: Path, bag: Path):
    """What the extended ``import-carmen`` writes for a corrected log: /scan, a noisy /odom
    and the corrected laser poses on /ground_truth/platform (frame map)."""
    from laser_tracker.conversions import scan_to_msg

    carmen = read_carmen(log)
    with BagWriter(bag) as out:
        for i in range(len(carmen)):
            t = float(carmen.stamps[i])
            out.write('/scan', scan_to_msg(FACTORY, carmen.scan(i)), t)
            x, y, th = carmen.laser_poses[i]
            out.write('/ground_truth/platform', odometry_to_msg(
                FACTORY, PlanarOdometry(t, x, y, th, frame_id='map')), t)
    return carmen


def ego_pose(k):
    """The replay's ego-motion: its own frame, drifting away from the reference."""
    drift = np.array([0.5 + 0.01 * k, -0.3, 0.2 + 0.002 * k])
    return compose(drift, reference_pose(k))


def to_odom(k, xy_map):
    """A map-frame position as the replay would see it: relative to the scanner, in odom."""
    local = transform_points(inverse(reference_pose(k)), np.array([xy_map]))
    return transform_points(ego_pose(k), local)[0]


def track_rows(tid, scans, where):
    rows = []
    for k in scans:
        x, y = to_odom(k, where(k))
        rows.append((100.0 + k * DT, tid, x, y, 0.5, 0.0, 80.0, True))
    return rows


@pytest.fixture(scope='module')
def corrected(tmp_path_factory):
    folder = tmp_path_factory.mktemp('carmen')
    log = folder / 'room.log'
    write_log(log)
    bag = folder / 'room_bag'
    write_reference_bag(log, bag)
    replay = folder / 'replay'
    rows = (track_rows(1, range(50, 56), lambda k: PILLAR)            # on the pillar: false
            + track_rows(2, range(20, 30), person_at)                 # on the walking person
            + track_rows(3, range(5, 12), lambda k: STAND)            # the person standing
            + track_rows(4, range(60, 66), lambda k: (0.0, -2.0))     # free space, no returns
            + [(100.0 + k * DT, 5, 0.0, 0.0, 0.0, 0.0, 10.0, False) for k in range(80, 90)])
    write_replay(replay, [(100.0 + k * DT, *ego_pose(k)) for k in range(N_SCANS)], rows)
    return bag, replay


def verdicts(result):
    return {t['track']: t['kind'] for t in result['static_structure']['tracks']}


def test_tracks_on_static_structure_are_false_with_reference_poses(corrected, capsys):
    bag, replay = corrected
    assert run_cli('evaluate', replay, bag) == 0          # reference poses: the default
    r = json.loads((replay / 'evaluation.json').read_text())
    assert r['mode'] == 'static'
    st = r['static_structure']
    assert verdicts(r) == {1: 'static', 2: 'moving', 3: 'moving', 4: 'unsupported'}
    assert st['false_tracks'] == 1 and st['unsupported_tracks'] == 1
    assert st['duration_s'] == pytest.approx(N_SCANS * DT)
    assert st['false_per_minute'] == pytest.approx(1 / (N_SCANS * DT / 60))
    false = st['false_list'][0]
    assert false['track'] == 1 and false['time_s'] == pytest.approx(50 * DT)
    assert false['x'] == pytest.approx(PILLAR[0], abs=1e-3)
    assert false['y'] == pytest.approx(PILLAR[1], abs=1e-3)
    out = capsys.readouterr().out
    assert 'false (on static structure) 1' in out and '#1 ' in out
    assert (replay / 'evaluation_static.png').is_file()


def test_ego_pose_variant_agrees_on_the_synthetic_log(corrected):
    bag, replay = corrected
    out = replay / 'ego.json'
    assert run_cli('evaluate', replay, bag, '--static-map', 'ego', '--no-figures',
                   '--json', out) == 0
    r = json.loads(out.read_text())
    assert r['static_structure']['mode'] == 'ego'
    assert verdicts(r) == {1: 'static', 2: 'moving', 3: 'moving', 4: 'unsupported'}


def test_static_cells_need_most_observations_to_hit():
    cfg = StaticMapConfig(resolution=0.1, max_range=10.0)
    angles = np.array([0.0])

    class Beam:
        def __init__(self, stamp, r):
            self.stamp, self.angles, self.ranges = stamp, angles, np.array([r])
            self.range_max = 20.0

    # a beam along +x: a wall at 3 m in 4 scans of 10, nothing (free to 10 m) in the others
    scans = [Beam(k, 3.05 if k < 4 else np.inf) for k in range(10)]
    sm = StaticMap.build(scans, np.zeros((10, 3)), config=cfg)
    hits, observed = sm.counts(np.array([_key(3.05, 0.0, cfg)]))
    assert (hits[0], observed[0]) == (4, 10)
    assert sm.on_structure(np.array([[3.05, 0.0]]))[0]       # 40 % >= 30 %
    strict = StaticMap.build(scans, np.zeros((10, 3)),
                             config=StaticMapConfig(resolution=0.1, max_range=10.0,
                                                    static_share=0.5))
    assert not strict.on_structure(np.array([[3.05, 0.0]]))[0]
    # within `near` (0.15 m) of a static cell counts, farther does not
    assert sm.on_structure(np.array([[3.05, 0.14]]))[0]
    assert not sm.on_structure(np.array([[3.05, 0.35]]))[0]
    # free space along the beam is observed, not hit
    h, o = sm.counts(np.array([_key(1.0, 0.0, cfg)]))
    assert (h[0], o[0]) == (0, 10)


def _key(x, y, cfg):
    from laser_tracker.tools.static_map import _keys
    return _keys(np.array([math.floor(x / cfg.resolution)]),
                 np.array([math.floor(y / cfg.resolution)]))[0]


def test_scan_cells_are_unique_and_include_the_returns():
    cfg = StaticMapConfig(resolution=0.1, max_range=5.0)
    angles = np.radians(np.arange(-90, 91, 1.0))
    ranges = np.full(angles.size, 2.0)
    hits, observed = scan_cells((1.0, 1.0, 0.0), angles, ranges, 10.0, cfg)
    assert np.unique(hits).size == hits.size and np.isin(hits, observed).all()
    assert 50 < hits.size < 200


def test_ego_segments_cut_at_restarts():
    stamps = np.arange(8) * 0.1
    poses = np.array([[0, 0, 0], [0.05, 0, 0], [0.1, 0, 0], [0, 0, 0], [0.05, 0, 0],
                      [3.0, 0, 0], [3.05, 0, 0], [3.1, 0, 0]], float)
    assert list(ego_segments(stamps, poses)) == [0, 0, 0, 1, 1, 2, 2, 2]
    gap = stamps.copy()
    gap[6:] += 5.0
    assert list(ego_segments(gap, poses[[0, 1, 2, 2, 2, 2, 2, 2]])) == [0, 0, 0, 0, 0, 0, 1, 1]


def test_no_labels_and_no_static_map_is_a_clear_error(tmp_path, capsys):
    from test_evaluate import write_bag

    bag = tmp_path / 'plain'
    write_bag(bag, ground_truth=False)
    replay = tmp_path / 'replay'
    write_replay(replay, [(1.0, 0, 0, 0)], [])
    assert run_cli('evaluate', replay, bag) == 2
    err = capsys.readouterr().err
    assert '--static-map ego' in err and '--no-ground-truth' in err


REAL = real_recording('carmen/freiburg-079-part1-corrected.log.gz')


@pytest.mark.skipif(not REAL.exists(), reason=f'{REAL} not available')
def test_real_corrected_poses_make_a_map_the_returns_fall_on():
    """The corrected laser poses are the reference: a scan's returns lie on the map built
    from all scans (a wrong pose reading, e.g. robot instead of laser pose, would not)."""
    carmen = read_carmen(REAL)
    idx = np.arange(0, len(carmen), 4)                 # every 4th scan, to keep it quick
    scans = [carmen.scan(int(i)) for i in idx]
    poses = carmen.laser_poses[idx]
    sm = StaticMap.build(scans, poses)
    shares = []
    for j in range(10, len(idx), 53):
        pts = transform_points(poses[j], scans[j].points(max_range=20.0))
        shares.append(sm.on_structure(pts).mean())
    assert np.median(shares) > 0.9


@pytest.mark.skipif(not REAL.exists(), reason=f'{REAL} not available')
def test_bench_real_replays_freiburg_with_other_draws_of_the_odometry_noise(tmp_path):
    """freiburg_other_noise: each noise model drawn with three other seeds, six replays
    pooled in one row, each with odometry of its own."""
    from laser_tracker.tools import bench_real
    from laser_tracker.tools.bag import read_odometry
    row = bench_real_row(tmp_path, 'freiburg_other_noise', jobs=2)
    assert len(row['false_by_part']) == 6 and row['false'] == sum(row['false_by_part'])
    odometry = [read_odometry(tmp_path / 'work' / f'freiburg_realistic_seed{s}').poses
                for s in bench_real.OTHER_NOISE_SEEDS]
    assert all(len(o) == len(odometry[0]) for o in odometry)
    assert not np.allclose(odometry[0], odometry[1]) and not np.allclose(odometry[1],
                                                                         odometry[2])


@pytest.mark.skipif(not real_recording('carmen/aces-corrected.log.gz').exists(),
                    reason='aces-corrected.log.gz not available')
def test_bench_real_replays_a_subsampled_log_at_one_scan_a_second(tmp_path):
    """aces (a scan every metre of the drive, stamps 3 s apart that go back once) is replayed
    in the log's order at 1 Hz, scored on the corrected poses' static structure; motion
    alone confirms nothing on the building."""
    from laser_tracker.tools import bench_real
    from laser_tracker.tools.bag import read_scans
    row = bench_real_row(tmp_path, 'aces')
    stamps = np.array([s.stamp for s in read_scans(tmp_path / 'work' / 'aces')])
    np.testing.assert_allclose(np.diff(stamps), bench_real.SUBSAMPLED_PERIOD)
    assert row['scans'] == stamps.size == 440
    assert row['minutes'] == pytest.approx(stamps.size * bench_real.SUBSAMPLED_PERIOD / 60,
                                           abs=0.05)
    assert row['false'] == 0
