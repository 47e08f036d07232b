"""Scoring against ground truth on synthetic data whose answer is known by construction."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from laser_tracker.conversions import MovingObject
from laser_tracker.core.geometry import compose, inverse, transform_points
from laser_tracker.tools.bag import GroundTruthFrame
from laser_tracker.tools.scoring import (EvaluationConfig, TrackTable, TruthTable, score,
                                         score_unlabelled, segment_paths, tracks_to_map)

DT = 0.2  # 5 Hz, as the paper's scanner


def walker(n=50, start=(0.0, 1.0), vel=(1.0, 0.0), dt=DT, oid=1, visible=None):
    """A ground-truth object walking at constant velocity: list of (stamp, MovingObject)."""
    out = []
    for k in range(n):
        extra = {'kind': 'person'}
        if visible is not None:
            extra['visible'] = bool(visible(k))
        out.append((k * dt, MovingObject(oid, start[0] + vel[0] * k * dt,
                                         start[1] + vel[1] * k * dt, vel[0], vel[1], extra)))
    return out


def frames_of(n, *objects_lists, dt=DT):
    by_stamp = {k: [] for k in range(n)}
    for objs in objects_lists:
        for stamp, o in objs:
            by_stamp[int(round(stamp / dt))].append(o)
    return [GroundTruthFrame(k * dt, 'map', by_stamp[k]) for k in range(n)]


def perfect_rows(objs, track_id=100, offset=(0.0, 0.0), confirmed=True):
    return [(s, track_id, o.x + offset[0], o.y + offset[1], o.vx, o.vy, 80.0, confirmed)
            for s, o in objs]


def test_perfect_tracker_scores_mota_one_and_no_false_positive():
    objs = walker()
    truth = TruthTable.from_frames(frames_of(50, objs))
    s = score(truth, TrackTable.from_rows(perfect_rows(objs)))
    mot = s.clear_mot['detectable']
    assert mot['mota'] == pytest.approx(1.0)
    assert mot['num_false_positives'] == 0 and mot['num_misses'] == 0
    assert mot['num_switches'] == 0 and mot['num_matches'] == 50
    assert mot['motp'] == pytest.approx(0.0, abs=1e-9)
    assert s.false_detections == [] and s.incorrect_tracks == []
    assert s.as_dict()['paths_taken'] == 1 and s.as_dict()['paths_detected'] == 1


def test_offset_of_half_a_metre_matches_at_075_and_misses_at_04():
    objs = walker()
    truth = TruthTable.from_frames(frames_of(50, objs))
    tracks = TrackTable.from_rows(perfect_rows(objs, offset=(0.3, 0.4)))  # 0.5 m away
    loose = score(truth, tracks, EvaluationConfig(threshold=0.75))
    assert loose.clear_mot['detectable']['num_matches'] == 50
    assert loose.clear_mot['detectable']['motp'] == pytest.approx(0.5)  # metres, not m^2
    assert np.allclose(loose.errors, 0.5) and loose.error_stats()['median'] == pytest.approx(0.5)
    tight = score(truth, tracks, EvaluationConfig(threshold=0.4))
    mot = tight.clear_mot['detectable']
    assert mot['num_matches'] == 0 and mot['num_misses'] == 50
    assert mot['num_false_positives'] == 50
    assert len(tight.false_detections) == 1 and tight.false_detections[0].frames == 50


def test_id_switch_is_counted():
    objs = walker()
    rows = perfect_rows(objs[:25], track_id=1) + perfect_rows(objs[25:], track_id=2)
    s = score(TruthTable.from_frames(frames_of(50, objs)), TrackTable.from_rows(rows))
    assert s.clear_mot['detectable']['num_switches'] == 1
    assert s.clear_mot['detectable']['mota'] == pytest.approx(1 - 1 / 50)


def test_false_track_of_three_frames_is_one_false_detection_of_length_three():
    objs = walker()
    ghost = [(k * DT, 7, 5.0, -3.0, 0.5, 0.5, 90.0, True) for k in (10, 11, 12)]
    s = score(TruthTable.from_frames(frames_of(50, objs)),
              TrackTable.from_rows(perfect_rows(objs) + ghost))
    assert [(f.track_id, f.frames) for f in s.false_detections] == [(7, 3)]
    assert not s.false_detections[0].after_match
    assert s.false_detections[0].start == pytest.approx(10 * DT)
    assert s.clear_mot['detectable']['num_false_positives'] == 3
    # two separate runs of one track are two false detections
    ghost2 = [(k * DT, 7, 5.0, -3.0, 0.5, 0.5, 90.0, True) for k in (10, 11, 20)]
    s2 = score(TruthTable.from_frames(frames_of(50, objs)),
               TrackTable.from_rows(perfect_rows(objs) + ghost2))
    assert sorted(f.frames for f in s2.false_detections) == [1, 2]


def test_a_track_overshooting_after_its_object_stopped_is_flagged():
    objs = walker(20)
    stand = [((20 + k) * DT, MovingObject(1, objs[-1][1].x, 1.0, 0.0, 0.0, {}))
             for k in range(5)]
    # the track coasts on at 1 m/s for 5 scans after the object stopped: 0.2 .. 1.0 m away
    coast = [((20 + k) * DT, 100, objs[-1][1].x + 0.2 * (k + 1), 1.0, 1.0, 0.0, 60.0, True)
             for k in range(5)]
    s = score(TruthTable.from_frames(frames_of(25, objs + stand)),
              TrackTable.from_rows(perfect_rows(objs) + coast))
    assert [(f.frames, f.after_match) for f in s.false_detections] == [(2, True)]
    assert s.as_dict()['false_detections_after_match'] == 1


def test_unconfirmed_hypotheses_are_not_scored_unless_asked():
    objs = walker()
    ghost = [(k * DT, 7, 5.0, -3.0, 0.5, 0.5, 10.0, False) for k in range(5)]
    truth = TruthTable.from_frames(frames_of(50, objs))
    tracks = TrackTable.from_rows(perfect_rows(objs) + ghost)
    assert score(truth, tracks).false_detections == []
    every = score(truth, tracks, EvaluationConfig(confirmed_only=False))
    assert [f.frames for f in every.false_detections] == [5]


def test_paths_taken_and_detected():
    # east for 3 s, then north for 3 s (a 90 deg turn), then stands for 2 s
    east = walker(15, start=(0.0, 0.0), vel=(1.0, 0.0))
    north = [(s + 15 * DT, MovingObject(1, 3.0, o.y - 0.0, 0.0, 1.0, {}))
             for s, o in walker(15, start=(3.0, 0.0), vel=(0.0, 1.0))]
    north = [(s, MovingObject(1, 3.0, 0.2 * k, 0.0, 1.0, {})) for k, (s, _) in enumerate(north)]
    stand = [((30 + k) * DT, MovingObject(1, 3.0, 3.0, 0.0, 0.0, {})) for k in range(10)]
    truth = TruthTable.from_frames(frames_of(40, east + north + stand))
    paths = segment_paths(truth, EvaluationConfig())
    assert [(p.first_frame, p.last_frame) for p in paths] == [(0, 14), (15, 29)]
    assert paths[0].heading_deg == pytest.approx(0.0) and paths[1].heading_deg == pytest.approx(90)
    s = score(truth, TrackTable.from_rows(perfect_rows(east)))  # tracked only going east
    d = s.as_dict()
    assert d['paths_taken'] == 2 and d['paths_detected'] == 1
    # the standing object is not required: no misses counted while it stands
    assert s.clear_mot['detectable']['num_objects'] == 30
    assert s.clear_mot['present']['num_objects'] == 40
    # a speed change of 0.5 m/s starts a new path; a short path (< 1 s) is not taken
    slow = walker(4, start=(0.0, 0.0), vel=(0.5, 0.0))
    fast = [((4 + k) * DT, o) for k, (_, o) in enumerate(walker(20, start=(0.4, 0), vel=(1, 0)))]
    s2 = score(TruthTable.from_frames(frames_of(24, slow + fast)), TrackTable.from_rows([]))
    assert len(s2.paths) == 2 and s2.as_dict()['paths_taken'] == 1
    assert s2.as_dict()['paths_detected'] == 0


def test_invisible_object_is_not_required_and_a_track_on_it_is_not_false():
    hidden = walker(visible=lambda k: False)
    seen = walker(oid=2, start=(0, 5), visible=lambda k: True)
    truth = TruthTable.from_frames(frames_of(50, hidden, seen))
    assert truth.has_visibility
    s = score(truth, TrackTable.from_rows(perfect_rows(hidden, 5) + perfect_rows(seen, 6)))
    det = s.clear_mot['detectable']
    assert det['num_objects'] == 50 and det['num_false_positives'] == 0 and det['mota'] == 1
    assert s.clear_mot['present']['num_objects'] == 100
    assert s.false_detections == []
    assert s.as_dict()['paths_taken'] == 1  # the path invisible throughout is ignored
    assert s.objects_passing == 1


def test_clearly_incorrect_velocity():
    objs = walker()
    reverse = [(s, 3, o.x, o.y, -o.vx, -o.vy, 80.0, True) for s, o in objs[:10]]
    too_fast = [(s, 4, o.x, o.y, 2.5 * o.vx, o.vy, 80.0, True) for s, o in objs[10:20]]
    fine = [(s, 5, o.x, o.y, 0.8 * o.vx + 0.1, 0.3, 80.0, True) for s, o in objs[20:]]
    s = score(TruthTable.from_frames(frames_of(50, objs)),
              TrackTable.from_rows(reverse + too_fast + fine))
    assert s.incorrect_tracks == [3, 4] and s.incorrect_rows == 20
    assert s.incorrect_steady == [3, 4]


def test_velocity_lag_just_after_a_reversal_is_counted_apart():
    east = walker(15, start=(0.0, 0.0), vel=(1.0, 0.0))
    west = [((15 + k) * DT, MovingObject(1, 3.0 - 0.2 * k, 0.0, -1.0, 0.0, {}))
            for k in range(15)]
    # the track keeps the old velocity for one scan after the object turned back
    rows = perfect_rows(east) + [(s, 100, o.x, o.y, 1.0 if k == 0 else o.vx, 0.0, 80.0, True)
                                 for k, (s, o) in enumerate(west)]
    s = score(TruthTable.from_frames(frames_of(30, east + west)), TrackTable.from_rows(rows))
    assert s.incorrect_tracks == [100] and s.incorrect_rows == 1
    assert s.incorrect_steady == []
    assert s.incorrect_list[0]['since_velocity_change_s'] == pytest.approx(0.0)


def _drift(k):
    """An odometry frame that drifts from map: ego-motion error growing with time."""
    return np.array([0.05 * k, -0.02 * k, 0.01 * k])


def test_frames_conversion_with_drifting_odometry_gives_the_perfect_frame_score():
    n = 50
    objs = walker(n)
    stamps = np.arange(n) * DT
    true_poses = np.array([[0.3 * t, 0.1 * t, 0.2 * t] for t in stamps])  # platform moves
    est_poses = np.array([compose(_drift(k), true_poses[k]) for k in range(n)])
    rows = []
    for k, (s, o) in enumerate(objs):
        scan = transform_points(inverse(true_poses[k]), np.array([[o.x, o.y]]))
        odom = transform_points(est_poses[k], scan)[0]
        rot = true_poses[k][2] - est_poses[k][2]
        c, si = math.cos(-rot), math.sin(-rot)
        rows.append((s, 9, odom[0], odom[1], c * o.vx - si * o.vy, si * o.vx + c * o.vy,
                     80.0, True))
    raw = TrackTable.from_rows(rows)
    truth = TruthTable.from_frames(frames_of(n, objs))
    mapped = tracks_to_map(raw, stamps, est_poses, stamps, true_poses, tolerance=0.05)
    assert np.allclose(mapped.x, [o.x for _, o in objs]) and np.allclose(mapped.vx, 1.0)
    perfect = score(truth, TrackTable.from_rows(perfect_rows(objs, 9)))
    converted = score(truth, mapped)
    for mode in ('detectable', 'present'):
        assert converted.clear_mot[mode] == pytest.approx(perfect.clear_mot[mode], abs=1e-9)
    assert converted.incorrect_tracks == [] and converted.false_detections == []
    # without the conversion, the drift makes the same tracks score worse
    assert score(truth, raw).clear_mot['detectable']['mota'] < 1.0


def test_unlabelled_estimate():
    walk = [(k * 0.1, 1, 0.1 * k, 0.0, 1.0, 0.0, 80.0, k >= 4) for k in range(20)]
    still = [(k * 0.1, 2, 3.0, 3.0 + 0.01 * k, 0.2, 0.0, 80.0, k >= 4) for k in range(10)]
    never = [(k * 0.1, 3, 5.0, 5.0, 0.0, 0.0, 10.0, False) for k in range(3)]
    jumpy = [(k * 0.1, 4, 8.0 + 0.2 * k, 0.0, 0.1, 0.0, 80.0, True) for k in range(5)]
    r = score_unlabelled(TrackTable.from_rows(walk + still + never + jumpy),
                         np.arange(600) * 0.1)
    assert r['duration_s'] == pytest.approx(60.0)
    assert r['confirmed_tracks'] == 3 and r['confirmed_per_minute'] == pytest.approx(3.0)
    assert r['estimated_false'] == 2 and r['estimated_false_per_minute'] == pytest.approx(2.0)
    assert r['hypotheses'] == 4
    assert {t['track']: t['frames'] for t in r['tracks']} == {1: 16, 2: 6, 4: 5}
    assert {t['track'] for t in r['tracks'] if t['estimated_false']} == {2, 4}
    assert r['confirmed_frames_histogram'] == {'1': 0, '2': 0, '3-5': 1, '6-10': 1,
                                               '11-30': 1, '>30': 0}


# ------------------------------------------------------------------------- command line


def write_replay(folder: Path, ego_rows, track_rows, summary=None, confirmed_words=('1', '0')):
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / 'ego_motion.csv', 'w') as fh:
        fh.write('stamp,x,y,theta\n')
        for r in ego_rows:
            fh.write(','.join(f'{v:.9f}' for v in r) + '\n')
    with open(folder / 'tracks.csv', 'w') as fh:
        fh.write('stamp,track_id,x,y,vx,vy,weight,confirmed\n')
        for s, tid, x, y, vx, vy, w, c in track_rows:
            flag = confirmed_words[0] if c else confirmed_words[1]
            fh.write(f'{s:.9f},{tid},{x:.6f},{y:.6f},{vx:.6f},{vy:.6f},{w:.1f},{flag}\n')
    if summary is not None:
        (folder / 'summary.json').write_text(json.dumps(summary))


def write_bag(path: Path, n=30, ground_truth=True):
    from laser_tracker.conversions import PlanarOdometry, objects_to_marker_array, \
        odometry_to_msg
    from laser_tracker.tools.bag import FACTORY, BagWriter

    platform = (1.0, 2.0, 0.5)  # a stationary platform away from the map origin
    with BagWriter(path) as bag:
        for k in range(n):
            t = 1.0 + k * DT
            bag.write('/odom', odometry_to_msg(FACTORY, PlanarOdometry(t, 0.0, 0.0, 0.0)), t)
            if ground_truth:
                obj = MovingObject(1, 0.0 + 1.0 * k * DT, 4.0, 1.0, 0.0, {'kind': 'person'})
                bag.write('/ground_truth',
                          objects_to_marker_array(FACTORY, [obj], t, 'map', 'ground_truth'), t)
                bag.write('/ground_truth/platform', odometry_to_msg(
                    FACTORY, PlanarOdometry(t, *platform, frame_id='map')), t)
    return platform


def run_cli(*argv):
    from laser_tracker.tools.cli import main
    return main(list(map(str, argv)))


def test_evaluate_command_end_to_end_on_a_small_bag(tmp_path, capsys):
    bag = tmp_path / 'gt_bag'
    platform = write_bag(bag)
    n = 30
    ego = [(1.0 + k * DT, 0.0, 0.0, 0.0) for k in range(n)]  # odometry frame = scanner start
    rows = []
    for k in range(n):
        t = 1.0 + k * DT
        p = transform_points(inverse(platform), np.array([[1.0 * k * DT, 4.0]]))[0]
        c, s = math.cos(-platform[2]), math.sin(-platform[2])
        rows.append((t, 4, p[0], p[1], c * 1.0, s * 1.0, 80.0, k >= 4))
    rows.append((1.0 + 5 * DT, 8, 20.0, 20.0, 0.0, 1.0, 70.0, True))  # one false frame
    replay = tmp_path / 'replay'
    write_replay(replay, ego, rows, summary={'hypotheses_created': 12},
                 confirmed_words=('true', 'false'))
    assert run_cli('evaluate', replay, bag) == 0
    out = capsys.readouterr().out
    assert 'MOTA' in out and 'false detections' in out
    result = json.loads((replay / 'evaluation.json').read_text())
    assert result['frames'] == n
    assert result['hypotheses_made'] == 12 and result['hypotheses_source'] == 'summary.json'
    assert result['false_detections'] == 1 and result['false_detection_frames'] == [1]
    assert result['clear_mot']['detectable']['num_misses'] == 4  # before confirmation
    assert result['clear_mot']['detectable']['num_matches'] == n - 4
    assert result['position_error']['median'] == pytest.approx(0.0, abs=1e-5)
    assert result['paths_taken'] == 1 and result['paths_detected'] == 1
    for name in result['figures']:
        assert Path(name).is_file()
    # --json elsewhere, --all, and a missing summary falls back to distinct track ids
    (replay / 'summary.json').unlink()
    out_json = tmp_path / 'x' / 'e.json'
    assert run_cli('evaluate', replay, bag, '--all', '--no-figures', '--json', out_json) == 0
    again = json.loads(out_json.read_text())
    assert again['hypotheses_made'] == 2 and again['clear_mot']['detectable']['num_misses'] == 0


def test_evaluate_refuses_a_replay_of_another_recording(tmp_path, capsys):
    bag = tmp_path / 'gt_bag'
    write_bag(bag)
    replay = tmp_path / 'replay'
    write_replay(replay, [(100.0 + k * DT, 0, 0, 0) for k in range(5)], [])
    assert run_cli('evaluate', replay, bag) == 2
    assert 'was it replayed from that recording' in capsys.readouterr().err


def test_evaluate_refuses_a_bag_without_ground_truth(tmp_path, capsys):
    bag = tmp_path / 'real_recording'
    write_bag(bag, ground_truth=False)
    replay = tmp_path / 'replay'
    write_replay(replay, [(1.0, 0, 0, 0)], [])
    assert run_cli('evaluate', replay, bag) == 2
    err = capsys.readouterr().err
    assert str(bag) in err and 'no ground truth' in err and '--no-ground-truth' in err
    assert not (replay / 'evaluation.json').exists()


def test_evaluate_on_a_missing_folder(tmp_path, capsys):
    missing = tmp_path / 'nowhere'
    assert run_cli('evaluate', missing, tmp_path / 'bag') == 2
    assert str(missing) in capsys.readouterr().err


def test_evaluate_on_a_folder_without_tracks(tmp_path, capsys):
    replay = tmp_path / 'replay'
    replay.mkdir()
    (replay / 'ego_motion.csv').write_text('stamp,x,y,theta\n1.0,0,0,0\n')
    assert run_cli('evaluate', replay, '--no-ground-truth') == 2
    assert 'tracks.csv' in capsys.readouterr().err
    (replay / 'tracks.csv').write_text('stamp,id,x\n')
    assert run_cli('evaluate', replay, '--no-ground-truth') == 2
    assert 'track_id' in capsys.readouterr().err


def test_unlabelled_report_command_skips_bad_rows(tmp_path, capsys, caplog):
    replay = tmp_path / 'replay'
    walk = [(k * 0.1, 1, 0.1 * k, 0.0, 1.0, 0.0, 80.0, k >= 4) for k in range(20)]
    write_replay(replay, [(k * 0.1, 0, 0, 0) for k in range(300)], walk)
    with open(replay / 'tracks.csv', 'a') as fh:
        fh.write('2.5,3,nan,1,0,0,50,1\n2.6,3,1,1,0,0,50,maybe\n')
    assert run_cli('evaluate', replay, '--no-ground-truth') == 0
    out = capsys.readouterr().out
    assert 'confirmed tracks' in out and 'per minute' in out
    result = json.loads((replay / 'evaluation.json').read_text())
    assert result['mode'] == 'unlabelled' and result['confirmed_tracks'] == 1
    assert result['confirmed_per_minute'] == pytest.approx(2.0)
    assert result['estimated_false'] == 0
    assert 'malformed' in caplog.text
    assert (replay / 'report_tracks.png').is_file()



def test_evaluation_reports_camera_captures_on_a_bundled_recording(tmp_path):
    """The active-head row of the paper's Table 4 (captured by the camera), on fig8."""
    from pathlib import Path

    import pytest

    from laser_tracker.tools.evaluate import evaluate_replay, format_table
    from laser_tracker.tools.replay import replay_bag

    bag = Path(__file__).resolve().parents[1] / 'bags' / 'fig8_robot_target'
    if not bag.exists():
        pytest.skip(f'{bag} not generated')
    replay_bag(bag, out_dir=tmp_path, progress=False)
    result = evaluate_replay(tmp_path, bag).result
    cam = result['camera']
    assert cam['objects_passing'] == 1
    assert 0 <= cam['objects_captured'] <= cam['objects_passing']
    assert cam['objects_captured'] == 1      # a slow robot in front of the scanner is captured
    assert 'captured by the camera' in format_table(result)
