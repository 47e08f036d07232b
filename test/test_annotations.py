"""Hand-annotated recordings (leg_tracker benchmark style): placement, counting, oracles."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from laser_tracker.conversions import header
from laser_tracker.tools.annotations import (ANNOTATION_TOPIC, HIDDEN_TOPIC, PERSON_MSGTYPE,
                                             Frames,
                                             annotation_velocities, read_annotations,
                                             register_person_type, score_clear_mot,
                                             score_following, to_frame)
from laser_tracker.tools.bag import FACTORY, TYPESTORE, BagWriter
from laser_tracker.tools.data import real_recording

from test_evaluate import run_cli, write_replay

DT = 0.1
T0 = 1000.0          # first scan's receive time
OFFSET = 130.0       # header stamps run this far ahead of receive times, as in the real bag


def person_msg(x, y, oid):
    register_person_type(TYPESTORE)
    f = FACTORY
    pose = f.make('geometry_msgs/msg/Pose',
                  position=f.make('geometry_msgs/msg/Point', x=float(x), y=float(y), z=0.0),
                  orientation=f.make('geometry_msgs/msg/Quaternion', x=0.0, y=0.0, z=0.0,
                                     w=1.0))
    return TYPESTORE.types[PERSON_MSGTYPE](pose=pose, id=oid)


def scan_msg(stamp):
    return FACTORY.make(
        'sensor_msgs/msg/LaserScan', header=header(FACTORY, stamp, 'base_laser_link'),
        angle_min=-0.5, angle_max=0.5, angle_increment=0.5, time_increment=0.0,
        scan_time=0.1, range_min=0.0, range_max=5.0,
        ranges=FACTORY.float32_array(np.array([2.0, 2.0, 2.0])),
        intensities=FACTORY.float32_array(np.zeros(0)))


def write_annotated_bag(path: Path, people, n=40, extra=(), offset=OFFSET, hidden=None):
    """Scans at receive ``T0 + k DT`` (header stamp ``+ offset``); ``people(k)`` gives the
    ``(id, x, y)`` annotated at scan k (scan frame), written half a period after it, like the
    annotation tool; ``extra``: ``(receive time, id, x, y)`` more annotations; ``hidden(k)``:
    the people out of sight at scan k, on ``HIDDEN_TOPIC``."""
    events = [(T0 + k * DT, 0, k) for k in range(n)]
    events += [(T0 + (k + 0.5) * DT, 1, (oid, x, y)) for k in range(n) for oid, x, y in people(k)]
    events += [(t, 1, (oid, x, y)) for t, oid, x, y in extra]
    if hidden is not None:
        events += [(T0 + (k + 0.5) * DT, 2, (oid, x, y)) for k in range(n)
                   for oid, x, y in hidden(k)]
    events.sort(key=lambda e: (e[0], e[1]))
    with BagWriter(path) as bag:
        for t, kind, what in events:
            if kind == 0:
                bag.write('/scan_base2', scan_msg(t + offset), t)
            else:
                bag.write(ANNOTATION_TOPIC if kind == 1 else HIDDEN_TOPIC,
                          person_msg(what[1], what[2], what[0]), t)
    return [T0 + k * DT + offset for k in range(n)]


def scanner_poses(n):
    """A scanner driving a curve in the odometry frame."""
    k = np.arange(n)
    return np.column_stack((1.0 * k * DT, 0.1 * np.sin(k * DT), 0.2 * k * DT))


def feed_back(stamps, poses, people, n, track_of=lambda k, oid: 100 + oid, skip=()):
    """Track rows that are the annotations, brought into the odometry frame with ``poses``."""
    rows = []
    for k in range(n):
        for oid, x, y in people(k):
            if (k, oid) in skip:
                continue
            ox, oy = to_frame(poses[[k]], np.array([x]), np.array([y]))
            rows.append((stamps[k], track_of(k, oid), float(ox[0]), float(oy[0]), 0.0, 0.0,
                         80.0, True))
    return rows


def follower(k):
    """The followed person, 1.5 m ahead, moving a little in the scanner frame."""
    return [(2, 1.5 + 0.1 * math.sin(k / 5), 0.2 * math.cos(k / 7))]


# --------------------------------------------------------------------------- placement


def test_annotations_are_placed_at_the_scan_received_before_them(tmp_path, caplog):
    bag = tmp_path / 'bag'
    stamps = write_annotated_bag(bag, follower, n=20, extra=[
        (T0 - 0.05, 2, 1.0, 0.0),                  # before the first scan
        (T0 + 19 * DT + 0.12, 3, 1.0, 1.0),        # just after the last scan: attached
        (T0 + 19 * DT + 5.0, 3, 1.0, 1.0),         # long after the last scan: dropped
        (T0 + 3 * DT + 0.07, 2, 9.0, 9.0),         # a second annotation of id 2 at scan 3
        (T0 + 4 * DT + 0.07, 4, float('nan'), 1.0)])
    ann = read_annotations(bag)
    assert ann.scans.topic == '/scan_base2'
    assert np.allclose(ann.scans.stamps, stamps)
    assert ann.header_offset == pytest.approx(OFFSET, abs=1e-6)
    # attached after the last scan: the follower's own annotation of scan 19 and id 3's
    assert ann.counts == {'messages': 25, 'before_first_scan': 1, 'after_last_scan_attached': 2,
                          'after_last_scan_dropped': 1, 'non_finite': 1, 'duplicates': 1}
    assert len(ann) == 21 and ann.ids() == [2, 3]
    assert list(ann.scan[ann.obj_id == 2]) == list(range(20))
    assert list(ann.scan[ann.obj_id == 3]) == [19]
    at3 = (ann.scan == 3) & (ann.obj_id == 2)
    assert ann.x[at3] == pytest.approx([9.0])      # the later one of the duplicate pair
    assert 'before the first scan' in caplog.text and 'non-finite' in caplog.text


def test_empty_annotation_topic_and_wrong_type_are_clear_errors(tmp_path):
    from laser_tracker.errors import InputFileError

    empty = tmp_path / 'empty'
    write_annotated_bag(empty, lambda k: [], n=5)
    with pytest.raises(InputFileError, match='no annotations'):
        read_annotations(empty)
    wrong = tmp_path / 'wrong'
    with BagWriter(wrong) as bag:
        bag.write('/scan_base2', scan_msg(T0), T0)
        bag.write(ANNOTATION_TOPIC, scan_msg(T0), T0 + 0.05)
    with pytest.raises(InputFileError, match='not a leg_tracker Person'):
        read_annotations(wrong)


# ----------------------------------------------------------------------------- counting


def frames_of(rows):
    return Frames.of(*zip(*rows)) if rows else Frames.of([], [], [], [])


def test_following_counts_follow_the_benchmark_rules():
    people = frames_of([(f, 2, 1.0, 0.0) for f in range(10)])
    # perfect: one track throughout
    perfect = frames_of([(f, 7, 1.1, 0.0) for f in range(10)])
    c = score_following(10, people, perfect)
    assert (c.tracked, c.id_switches, c.misses, c.false_positives) == (10, 0, 0, 0)
    assert c.as_dict()['motp'] == pytest.approx(0.1)
    # a gap of 3 frames: 3 misses, the same track afterwards is no switch
    gap = frames_of([(f, 7, 1.1, 0.0) for f in range(10) if f not in (4, 5, 6)])
    c = score_following(10, people, gap)
    assert (c.tracked, c.id_switches, c.misses) == (7, 0, 3)
    # the track id changes at frame 5: one switch (person side: a new track on a person
    # last matched to another track)
    change = frames_of([(f, 7 if f < 5 else 8, 1.1, 0.0) for f in range(10)])
    c = score_following(10, people, change)
    assert (c.tracked, c.id_switches, c.misses) == (9, 1, 0)
    # ... also after a gap: the remembered pair outlives the frames without a match
    late = frames_of([(f, 7 if f < 5 else 8, 1.1, 0.0) for f in range(10) if f not in (5, 6)])
    c = score_following(10, people, late)
    assert (c.tracked, c.id_switches, c.misses) == (7, 1, 2)
    # a far-away track is a false positive, which following ignores
    far = frames_of([(f, 7, 1.1, 0.0) for f in range(10)] + [(f, 9, 6.0, 0.0)
                                                            for f in range(10)])
    c = score_following(10, people, far)
    assert (c.tracked, c.id_switches, c.misses, c.false_positives) == (10, 0, 0, 10)
    # 0.75 m is a miss (strictly closer than the threshold matches)
    edge = frames_of([(f, 7, 1.75, 0.0) for f in range(10)])
    assert score_following(10, people, edge).misses == 10


def test_following_keeps_a_continuing_pair_before_a_closer_newcomer():
    people = frames_of([(f, 2, 1.0, 0.0) for f in range(4)])
    tracks = frames_of([(f, 7, 1.5, 0.0) for f in range(4)] + [(f, 8, 1.0, 0.0)
                                                               for f in (2, 3)])
    c = score_following(4, people, tracks)
    assert (c.tracked, c.id_switches, c.false_positives) == (4, 0, 2)
    # the track side of a switch: track 7 moves from person 2 to person 3
    people = frames_of([(0, 2, 1.0, 0.0), (1, 2, 1.0, 0.0), (1, 3, 3.0, 0.0),
                        (2, 3, 3.0, 0.0)])
    tracks = frames_of([(0, 7, 1.0, 0.0), (1, 7, 3.0, 0.0), (2, 7, 3.0, 0.0)])
    c = score_following(3, people, tracks)
    assert (c.tracked, c.id_switches, c.misses) == (2, 1, 1)


def test_following_pairs_by_plain_distance_sum_as_the_benchmark():
    # track 7 is 0.7 m from person 2 and 3.2 m from person 3; track 8 is 0.2 m from person 2
    # and 2.3 m from person 3. The plain-distance assignment (7-2, 8-3: 3.0 m) beats
    # 7-3, 8-2 (3.4 m), so track 7 matches person 2; a threshold-capped cost would match 8-2.
    people = frames_of([(0, 2, 0.0, 0.0), (0, 3, 2.5, 0.0)])
    tracks = frames_of([(0, 7, -0.7, 0.0), (0, 8, 0.2, 0.0)])
    c = score_following(1, people, tracks)
    assert (c.tracked, c.misses, c.false_positives) == (1, 1, 1)
    assert c.distance_sum == pytest.approx(0.7)


def test_clear_mot_walking_ignores_standing_people():
    people = frames_of([(f, 2, 1.0, 0.0) for f in range(10)])
    care = np.arange(10) >= 4          # standing for the first 4 frames
    tracks = frames_of([(f, 7, 1.1, 0.0) for f in range(2, 10)])
    mot, err_all, err_walk, verdicts = score_clear_mot(10, people, care, tracks)
    assert mot['all']['num_misses'] == 2 and mot['all']['num_matches'] == 8
    assert mot['walking']['num_misses'] == 0 and mot['walking']['num_matches'] == 6
    assert mot['walking']['num_false_positives'] == 0   # tracks on the standing person
    assert mot['walking']['num_objects'] == 6 and err_walk.size == 6
    assert np.allclose(err_all, 0.1)
    # the per-frame verdicts (over all people) say which frame missed and which matched
    miss = verdicts.kind == 'MISS'
    assert verdicts.frame[miss].tolist() == [0, 1] and set(verdicts.obj_id[miss]) == {2}
    assert np.isnan(verdicts.track_xy[miss]).all() and np.allclose(verdicts.obj_xy[miss], (1, 0))
    match = verdicts.kind == 'MATCH'
    assert verdicts.frame[match].tolist() == list(range(2, 10))
    assert set(verdicts.track_id[match]) == {7} and np.allclose(verdicts.track_xy[match], (1.1, 0))


def test_speed_is_judged_in_the_odometry_frame():
    n = 30
    stamps = np.arange(n) * DT
    poses = scanner_poses(n)
    # a followed person: static in the scanner frame while the scanner drives at 1 m/s
    ox, oy = to_frame(poses, np.full(n, 1.5), np.zeros(n))
    v = annotation_velocities(stamps, np.full(n, 2), ox, oy)
    assert np.nanmedian(np.hypot(v[:, 0], v[:, 1])) > 0.3
    # a person standing in the odometry frame, seen from the moving scanner
    still = annotation_velocities(stamps, np.full(n, 2), np.full(n, 4.0), np.full(n, 1.0))
    assert np.allclose(still[~np.isnan(still[:, 0])], 0.0, atol=1e-9)
    # two ego-motion runs (different frames) are not fitted across
    seg = (np.arange(n) >= 15).astype(int)
    jumpy = annotation_velocities(stamps, np.full(n, 2), np.where(seg, 10.0, 0.0),
                                  np.zeros(n), segment=seg)
    assert np.allclose(jumpy[~np.isnan(jumpy[:, 0])], 0.0, atol=1e-9)


# ------------------------------------------------------------------- oracle, end to end


def run_eval(tmp_path, people, rows_of, n=40, ego_keep=None, ego_nan=(), extra_args=(),
             summary=None, hidden=None):
    bag = tmp_path / 'bag'
    stamps = write_annotated_bag(bag, people, n, hidden=hidden)
    poses = scanner_poses(n)
    keep = np.ones(n, bool) if ego_keep is None else ego_keep
    ego = [(stamps[k], *(poses[k] if k not in ego_nan else [np.nan] * 3))
           for k in range(n) if keep[k]]
    replay = tmp_path / 'replay'
    write_replay(replay, ego, rows_of(stamps, poses), summary)
    assert run_cli('evaluate', replay, bag, '--no-figures', *extra_args) == 0
    return json.loads((replay / 'evaluation.json').read_text())


def test_annotations_fed_back_as_tracks_score_perfectly(tmp_path, capsys):
    r = run_eval(tmp_path, follower, lambda s, p: feed_back(s, p, follower, 40))
    f = r['following']
    assert (f['tracked'], f['id_switches'], f['misses'], f['false_positives']) == (40, 0, 0, 0)
    assert r['following_all_annotations'] == {'objects': 40, 'tracked': 40, 'id_switches': 0,
                                              'misses': 0}
    assert r['clear_mot']['all']['mota'] == pytest.approx(1.0)
    assert r['clear_mot']['all']['motp'] == pytest.approx(0.0, abs=1e-5)
    assert r['clear_mot']['walking']['num_false_positives'] == 0
    assert r['annotations']['walking'] + r['annotations']['speed_unknown'] == 40
    assert r['header_minus_receive_s'] == pytest.approx(OFFSET, abs=1e-6)
    out = capsys.readouterr()
    assert '40 of 40 positions tracked (100.0 %), 0 ID switches, 0 misses' in out.out
    assert (out.out + out.err).count('run 130.0 s ahead of receive times') == 1


def test_perturbed_tracks_give_the_exact_counts(tmp_path):
    def rows(stamps, poses):
        return (feed_back(stamps, poses, follower, 40, skip={(k, 2) for k in (10, 11, 12)},
                          track_of=lambda k, oid: 100 if k < 20 else 101)
                + [(stamps[k], 555, 20.0, 20.0, 0.0, 0.0, 80.0, True) for k in range(40)])
    r = run_eval(tmp_path, follower, rows, extra_args=('--mode', 'following'))
    f = r['following']
    assert (f['tracked'], f['id_switches'], f['misses'], f['false_positives']) == (36, 1, 3, 40)
    mot = r['clear_mot']['all']
    assert (mot['num_switches'], mot['num_misses'], mot['num_false_positives']) == (1, 3, 40)


def test_false_positives_on_people_out_of_sight_are_counted_apart(tmp_path, capsys):
    """The followed person is in view for 20 scans, then out of sight (on the hidden topic)
    for 20, and a track follows them throughout; another track stands where nobody is. Both
    are false positives while the person is out of sight, and only the first is on them."""
    def seen(k):
        return follower(k) if k < 20 else []

    def hidden(k):
        return follower(k) if k >= 20 else []

    def rows(stamps, poses):
        return feed_back(stamps, poses, follower, 40) + [
            (stamps[k], 555, 20.0, 20.0, 0.0, 0.0, 80.0, True) for k in range(40)]
    r = run_eval(tmp_path, seen, rows, hidden=hidden)
    mot = r['clear_mot']['all']
    assert (mot['num_objects'], mot['num_matches'], mot['num_false_positives']) == (20, 20, 60)
    assert r['false_positives_on_hidden'] == 20
    assert r['annotations']['hidden'] == 20
    assert 'within the threshold of a person out of sight (20 such positions): 20' \
        in capsys.readouterr().out
    # without the hidden topic the count is not made (no such knowledge)
    plain = run_eval(tmp_path / 'plain', seen, rows)
    assert plain['clear_mot']['all']['num_false_positives'] == 60
    assert plain['false_positives_on_hidden'] is None and plain['annotations']['hidden'] is None


def test_a_sector_scores_only_the_annotations_and_tracks_within_its_bearings(tmp_path,
                                                                             capsys):
    """leg_tracker's benchmarks score their moving-robot recordings within -80 to 12 deg of
    the scanner: a person annotated and tracked at 45 deg, and a track at -120 deg, are then
    not scored; the followed person ahead is."""
    def people(k):
        return follower(k) + [(7, 2.0, 2.0)]                     # 45 deg to the left

    def rows(stamps, poses):
        far = [(stamps[k], 900, *to_frame(poses[[k]], np.array([-1.0]), np.array([-1.7])),
                0.0, 0.0, 80.0, True) for k in range(40)]        # -120 deg, nobody there
        return feed_back(stamps, poses, people, 40) + [
            (s, i, float(x[0]), float(y[0]), vx, vy, w, c) for s, i, x, y, vx, vy, w, c in far]
    whole = run_eval(tmp_path / 'whole', people, rows)
    assert whole['clear_mot']['all']['num_objects'] == 80
    assert whole['clear_mot']['all']['num_false_positives'] == 40
    sector = run_eval(tmp_path / 'sector', people, rows, extra_args=('--sector', '-80', '12'))
    mot = sector['clear_mot']['all']
    assert (mot['num_objects'], mot['num_false_positives'], mot['num_misses']) == (40, 0, 0)
    assert sector['annotations']['outside_sector'] == 40
    assert sector['following_all_annotations']['objects'] == 40
    assert sector['sector_deg'] == [-80.0, 12.0]
    capsys.readouterr()
    assert run_cli('evaluate', tmp_path / 'sector' / 'replay', tmp_path / 'sector' / 'bag',
                   '--no-figures', '--sector', '12', '-80') == 2
    assert '--sector 12 -80: the least and the largest bearing' in capsys.readouterr().err


def test_an_upside_down_scanners_replay_is_scored_in_the_frame_turned_right_side_up(
        tmp_path):
    """The replay of a scanner hung upside down works in the frame turned right side up
    (its scans mirrored): the annotations, in the scanner's own frame, are mirrored too, and
    the person annotated 2 m ahead and 2 m to its left is tracked 2 m to the right there; so
    is a sector (45 deg left is 45 deg right). Scored as a level scanner's, the same tracks
    miss that person (the one ahead, near the axis of the mirror, is matched either way)."""
    def people(k):
        return follower(k) + [(7, 2.0, 2.0)]

    def mirrored_people(k):
        return [(oid, x, -y) for oid, x, y in people(k)]

    def rows(stamps, poses):
        return feed_back(stamps, poses, mirrored_people, 40)
    mount = {'x': 0.0, 'y': 0.0, 'yaw': 0.0, 'source': '/tf_static', 'mirrored': True}
    r = run_eval(tmp_path / 'flipped', people, rows, summary={'scanner_mount': mount})
    mot = r['clear_mot']['all']
    assert (mot['num_objects'], mot['num_misses'], mot['num_false_positives']) == (80, 0, 0)
    r = run_eval(tmp_path / 'sector', people, rows, summary={'scanner_mount': mount},
                 extra_args=('--sector', '30', '60'))
    mot = r['clear_mot']['all']
    assert (mot['num_objects'], mot['num_misses'], mot['num_false_positives']) == (40, 0, 0)
    level = dict(mount, mirrored=False)
    r = run_eval(tmp_path / 'level', people, rows, summary={'scanner_mount': level})
    mot = r['clear_mot']['all']
    assert (mot['num_misses'], mot['num_false_positives']) == (40, 40)


def test_scans_without_ego_pose_are_not_scored_but_counted(tmp_path, caplog):
    keep = np.ones(40, bool)
    keep[[5, 6]] = False                       # skipped by the replay: no row
    r = run_eval(tmp_path, follower,           # scan 30: a row without a pose (NaN)
                 lambda s, p: [row for row in feed_back(s, p, follower, 40)
                               if not np.isclose(row[0], [s[5], s[6], s[30]]).any()],
                 ego_keep=keep, ego_nan=(30,))
    assert '1 of 38 scan(s) without an ego-motion pose' in caplog.text
    assert r['frames_scored'] == 37 and r['annotations']['not_scored_no_pose'] == 3
    assert r['following']['tracked'] == 37 and r['following']['misses'] == 0
    assert r['following_all_annotations'] == {'objects': 40, 'tracked': 37, 'id_switches': 0,
                                              'misses': 3}


def test_annotations_all_before_the_scans_score_nothing_without_crashing(tmp_path, capsys):
    bag = tmp_path / 'bag'
    write_annotated_bag(bag, lambda k: [], n=10, extra=[(T0 - 1.0, 2, 1.0, 0.0)])
    replay = tmp_path / 'replay'
    write_replay(replay, [(T0 + OFFSET + k * DT, 0, 0, 0) for k in range(10)], [])
    assert run_cli('evaluate', replay, bag, '--no-figures') == 0
    r = json.loads((replay / 'evaluation.json').read_text())
    assert r['annotations']['before_first_scan'] == 1 and r['annotations']['placed'] == 0
    assert r['following']['objects'] == 0 and r['following']['tracked_share'] is None


def test_bad_annotated_inputs_give_one_line_errors(tmp_path, capsys):
    bag = tmp_path / 'bag'
    write_annotated_bag(bag, follower, 10)
    other = tmp_path / 'other'
    write_replay(other, [(5.0 + k * DT, 0, 0, 0) for k in range(10)], [])
    assert run_cli('evaluate', other, bag) == 2
    assert 'was it replayed from that recording' in capsys.readouterr().err
    replay = tmp_path / 'replay'
    write_replay(replay, [(T0 + OFFSET + k * DT, 0, 0, 0) for k in range(10)], [])
    assert run_cli('evaluate', replay, bag, '--person', '9') == 2
    err = capsys.readouterr().err
    assert 'no annotated person with id 9 (ids: 2)' in err and 'Traceback' not in err


# ------------------------------------------------------------------------- real recording


REAL = real_recording('leg_tracker/person_following_outdoor_1.bag')


@pytest.mark.skipif(not REAL.exists(), reason=f'{REAL} not available')
def test_real_annotations_are_placed_and_score_perfectly_when_fed_back():
    from laser_tracker.tools.evaluate import Replay
    from laser_tracker.tools.annotations import evaluate_annotated
    from laser_tracker.tools.scoring import EvaluationConfig, TrackTable

    ann = read_annotations(REAL)
    assert ann.scans.topic == '/scan_base2' and len(ann.scans) == 7170
    assert ann.counts['messages'] == 6179 and len(ann) == 6179
    assert ann.counts['before_first_scan'] == 0 and ann.counts['after_last_scan_attached'] == 1
    assert np.unique(ann.scan).size == 6179            # one annotation per annotated scan
    assert 130.2 < ann.header_offset < 130.3
    # oracle: the annotations as tracks in an odometry frame of a made-up scanner path
    n = len(ann.scans)
    k = np.arange(n)
    poses = np.column_stack((0.05 * k, 0.5 * np.sin(k / 50), 0.01 * k))
    ox, oy = to_frame(poses[ann.scan], ann.x, ann.y)
    stamps = ann.scans.stamps
    tracks = TrackTable.from_rows(
        (stamps[s], 40, x, y, 0.0, 0.0, 80.0, True) for s, x, y in zip(ann.scan, ox, oy))
    replay = Replay(Path('oracle'), stamps.copy(), poses, tracks, {})
    r = evaluate_annotated(replay, REAL, EvaluationConfig()).result
    assert r['following']['tracked'] == 6179 and r['following']['id_switches'] == 0
    assert r['following']['misses'] == 0 and r['following']['false_positives'] == 0
    assert r['clear_mot']['all']['mota'] == pytest.approx(1.0)


@pytest.mark.skipif(not REAL.exists(), reason=f'{REAL} not available')
def test_real_people_in_the_scanners_reach_return_some_beam():
    """What hypotheses.silent_is_empty rests on: a person within the scan's reach returns
    some beam. Of the annotated positions of the followed person, all but a handful have a
    return within 0.25 m; at most 3 have none while the same scan returns from farther."""
    from laser_tracker.tools.bag import read_scans

    ann = read_annotations(REAL)
    scans = list(read_scans(REAL, ann.scans.topic))
    radius, returned, silent = 0.25, 0, 0
    for k, x, y in zip(ann.scan, ann.x, ann.y):
        scan = scans[k]
        rho = math.hypot(x, y)
        off = np.abs((scan.angles - math.atan2(y, x) + np.pi) % (2 * np.pi) - np.pi)
        reach = np.where(scan.valid(), scan.ranges, np.inf)
        disc = reach[off <= math.asin(min(1.0, radius / rho))]
        if (np.abs(disc - rho) <= radius).any():
            returned += 1
        elif not np.isfinite(disc).any() and reach[np.isfinite(reach)].max() > rho + radius:
            silent += 1
    assert returned >= 6170 and silent <= 3


def test_a_recording_at_half_the_rate_keeps_each_annotation_with_its_scan(tmp_path):
    """bench real's other scanners: every second scan of an annotated recording, with the
    annotations of the scans kept (and none of those left out), each at its own scan; every
    second beam leaves the annotations as they are."""
    from laser_tracker.tools.bench_real import rewrite_scans
    src = tmp_path / 'src'
    stamps = write_annotated_bag(src, lambda k: [(1, 1.0 + 0.01 * k, 0.0)], n=20)
    half = tmp_path / 'half'
    rewrite_scans(src, half, ['/scan_base2'], scan_step=2, as_inf=False,
                  attached=(ANNOTATION_TOPIC,))
    ann = read_annotations(half, scan_topic='/scan_base2')
    np.testing.assert_allclose(ann.scans.stamps, stamps[::2])
    assert len(ann) == 10 and not ann.counts.get('repeated')
    np.testing.assert_allclose(ann.x, 1.0 + 0.01 * np.arange(0, 20, 2))   # their own scan's
    beams = tmp_path / 'beams'
    rewrite_scans(src, beams, ['/scan_base2'], beam_step=2, as_inf=False,
                  attached=(ANNOTATION_TOPIC,))
    ann = read_annotations(beams, scan_topic='/scan_base2')
    assert len(ann) == 20
    np.testing.assert_allclose(ann.x, 1.0 + 0.01 * np.arange(20))
