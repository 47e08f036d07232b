"""``laser-tracker evaluate DIR BAG``: score a replay folder against the recording's labels.

DIR is a ``laser-tracker replay`` output (``ego_motion.csv``, ``tracks.csv``, optionally
``summary.json``); scans are named by their header stamps. What BAG carries decides the score
(:func:`recording_kind`):

* simulated ground truth (``/ground_truth``): CLEAR MOT (motmetrics), the paper's table rows
  and the position error distribution (``laser_tracker.tools.scoring``);
* hand-annotated people (``/ground_truth_people_tracks``, the leg_tracker benchmarks): CLEAR
  MOT over all annotated people and over the walking ones, and the person-following counts
  of the benchmark (``--mode following`` prints only those) (``laser_tracker.tools.annotations``);
* reference poses only (``/ground_truth/platform``, e.g. a SLAM-corrected CARMEN log): false
  confirmed tracks on static structure per minute (``laser_tracker.tools.static_map``);
  ``--static-map reference|ego`` adds that count to any recording (``ego``: mapped with the
  replay's own poses, for raw logs).

Results go to ``DIR/evaluation.json`` (unless ``--json``) with figures in DIR. A recording
without labels is refused with a clear error; ``--no-ground-truth`` reports confirmed tracks
and estimated false detections per minute instead.
"""
from __future__ import annotations

import argparse
import csv
import json
import logging
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from laser_tracker.core.geometry import interpolate_poses
from laser_tracker.core.head import HeadConfig, captured_objects, simulate_head
from laser_tracker.errors import InputFileError, LaserTrackerError
from laser_tracker.tools.atomic import check_output, write_json
from laser_tracker.tools.figures import pyplot, save_figure
from laser_tracker.tools.scoring import (EvaluationConfig, Scores, TrackTable, TruthTable,
                                         match_stamps, median_period, score, score_unlabelled,
                                         tracks_to_map)

log = logging.getLogger(__name__)

EGO_COLUMNS = ('stamp', 'x', 'y', 'theta')
TRACK_COLUMNS = ('stamp', 'track_id', 'x', 'y', 'vx', 'vy', 'weight', 'confirmed')
TRUE_WORDS = {'1', 'true', 'True', 'TRUE', '1.0'}
FALSE_WORDS = {'0', 'false', 'False', 'FALSE', '0.0'}
ERROR_FIGURE = 'evaluation_position_error.png'
TRACKS_FIGURE = 'evaluation_tracks.png'
REPORT_FIGURE = 'report_tracks.png'
STATIC_FIGURE = 'evaluation_static.png'


# ------------------------------------------------------------------------------ reading


@dataclass
class Replay:
    folder: Path
    ego_stamps: np.ndarray
    ego_poses: np.ndarray
    tracks: TrackTable
    summary: dict


def _read_csv(path: Path, columns: tuple[str, ...], convert) -> list[tuple]:
    """Rows of a CSV file with the given header; a malformed row is skipped with a warning."""
    if not path.is_file():
        raise InputFileError(path, 'not found (is the folder a `laser-tracker replay` output?)')
    rows, bad = [], 0
    try:
        with path.open(newline='') as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header is None:
                raise InputFileError(path, 'empty file (no header)')
            header = [h.strip() for h in header]
            missing = [c for c in columns if c not in header]
            if missing:
                raise InputFileError(path, f'header lacks {", ".join(missing)} '
                                     f'(expected {",".join(columns)})', 'line 1')
            index = [header.index(c) for c in columns]
            for line_no, row in enumerate(reader, start=2):
                if not row:
                    continue
                try:
                    rows.append(convert([row[i].strip() for i in index]))
                except (ValueError, IndexError) as exc:
                    bad += 1
                    if bad <= 3:
                        log.warning('%s: line %d skipped: %s', path, line_no, exc or 'malformed')
    except UnicodeDecodeError as exc:
        raise InputFileError(path, f'not a text CSV file: {exc}') from None
    if bad:
        log.warning('%s: %d malformed row(s) skipped', path, bad)
    return rows


def _flag(text: str) -> bool:
    if text in TRUE_WORDS:
        return True
    if text in FALSE_WORDS:
        return False
    raise ValueError(f'confirmed must be 0/1 or true/false, got {text!r}')


def _finite(values):
    out = [float(v) for v in values]
    if not all(math.isfinite(v) for v in out):
        raise ValueError('non-finite value')
    return out


def _ego_row(r):
    """stamp, x, y, theta; a pose of NaN (a scan the replay could not place) is kept."""
    stamp, x, y, theta = (float(v) for v in r)
    if not math.isfinite(stamp) or any(math.isinf(v) for v in (x, y, theta)):
        raise ValueError('non-finite value')
    return stamp, x, y, theta


def _track_row(r):
    stamp, x, y, vx, vy = _finite([r[0], r[2], r[3], r[4], r[5]])
    weight = float(r[6])
    return stamp, int(float(r[1])), x, y, vx, vy, weight, _flag(r[7])


def read_replay(folder: str | Path) -> Replay:
    """The files of a replay folder; InputFileError names whatever is missing or unreadable."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputFileError(folder, 'no such replay folder (run `laser-tracker replay BAG '
                             '--out DIR` first)')
    ego = np.array(_read_csv(folder / 'ego_motion.csv', EGO_COLUMNS, _ego_row),
                   float).reshape(-1, 4)
    unposed = ~np.all(np.isfinite(ego[:, 1:]), axis=1)
    if unposed.any():
        log.warning('%s: %d of %d scan(s) without an ego-motion pose: not scored',
                    folder / 'ego_motion.csv', int(unposed.sum()), ego.shape[0])
    ego = ego[~unposed]
    if ego.shape[0] == 0:
        raise InputFileError(folder / 'ego_motion.csv', 'no scans with a pose in the replay')
    tracks = TrackTable.from_rows(_read_csv(folder / 'tracks.csv', TRACK_COLUMNS, _track_row))
    summary = {}
    summary_path = folder / 'summary.json'
    if summary_path.is_file():
        try:
            summary = json.loads(summary_path.read_text())
        except (OSError, ValueError) as exc:
            log.warning('%s: unreadable, ignored: %s', summary_path, exc)
        if not isinstance(summary, dict):
            summary = {}
    return Replay(folder, ego[:, 0].copy(), ego[:, 1:].copy(), tracks, summary)


def hypotheses_made(replay: Replay) -> tuple[int, str]:
    """summary.json ``hypotheses_created``, else the distinct track ids of tracks.csv."""
    value = replay.summary.get('hypotheses_created')
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0:
        return int(value), 'summary.json'
    return int(np.unique(replay.tracks.track_id).size), 'tracks.csv (distinct ids)'


def load_truth(bag: str | Path) -> tuple[TruthTable, np.ndarray, np.ndarray]:
    """Ground truth and platform truth of a recording; a clear error if it has none."""
    from laser_tracker.tools.bag import read_ground_truth, read_platform_truth

    try:
        frames = read_ground_truth(bag)
    except InputFileError as exc:
        if 'no ground truth' in exc.reason:
            raise InputFileError(bag, 'has no ground truth (no /ground_truth topic): a real '
                                 'recording? use `laser-tracker evaluate DIR '
                                 '--no-ground-truth` for the unlabelled report') from None
        raise
    if not frames:
        raise InputFileError(bag, 'the /ground_truth topic holds no messages')
    frame_ids = {f.frame_id for f in frames if f.objects}
    if frame_ids - {'map'}:
        log.warning('%s: ground truth in frame(s) %s, taken as the platform truth frame',
                    bag, sorted(frame_ids))
    platform = read_platform_truth(bag)
    if len(platform) == 0:
        raise InputFileError(bag, 'the platform truth topic holds no messages')
    order = np.argsort(platform.stamps, kind='stable')
    poses = platform.poses[order]
    mount = scanner_mount(bag)
    if mount is not None:      # the platform truth is of the base; tracks are the scanner's
        from laser_tracker.core.geometry import compose
        poses = np.array([compose(p, mount) for p in poses])
    return TruthTable.from_frames(frames), platform.stamps[order], poses


def scanner_mount(bag) -> np.ndarray | None:
    """The base -> scanner mount a recording carries on /tf_static (None: none known)."""
    from laser_tracker.tools.bag import topics
    from laser_tracker.tools.mount import recording_mount

    info = topics(bag)
    odom = '/odom' if '/odom' in info else None
    if odom is None:
        return None
    mount = recording_mount(bag, '/scan', odom, _ZeroMount())
    return np.array([mount.x, mount.y, mount.yaw]) if mount.from_recording else None


class _ZeroMount:
    mount_x = mount_y = mount_yaw = 0.0


# ------------------------------------------------------------------------------ scoring


@dataclass
class Evaluation:
    """The result of :func:`evaluate_replay`: JSON dict plus what the figures need."""

    result: dict
    scores: Scores | None
    replay: Replay
    truth: TruthTable | None = None
    tracks_map: TrackTable | None = None
    platform_poses: np.ndarray | None = None
    annotated: object | None = None     # annotations.AnnotatedEvaluation
    static: object | None = None        # static_map.StaticEvaluation


def evaluate_replay(folder: str | Path, bag: str | Path,
                    config: EvaluationConfig = EvaluationConfig(),
                    replay: Replay | None = None) -> Evaluation:
    """Score a replay folder (or its ``replay``, already read) against a bag's ground truth
    (a path or a bundled name)."""
    from laser_tracker.tools.bag import resolve_bag

    replay = replay or read_replay(folder)
    bag = resolve_bag(bag)
    truth, true_stamps, true_poses = load_truth(bag)
    # the nearer of the two periods: a replay may use fewer scans than the recording has
    # (difference.max_scan_rate), or the truth may have fewer frames than scans
    tol = config.stamp_tolerance * min(median_period(replay.ego_stamps),
                                       median_period(truth.stamps))
    tracks = tracks_to_map(replay.tracks, replay.ego_stamps, replay.ego_poses,
                           true_stamps, true_poses, tol)
    replayed = match_stamps(truth.stamps, np.sort(replay.ego_stamps), tol) >= 0
    skipped = int((~replayed).sum())
    if not replayed.any():
        raise InputFileError(folder, f'no scan of this replay has the stamp of a ground-truth '
                             f'frame of {bag}: was it replayed from that recording?')
    if skipped:
        log.warning('%d of %d ground-truth frame(s) have no replayed scan and are not scored',
                    skipped, truth.stamps.size)
        truth = truth.keep_frames(replayed)
    scores = score(truth, tracks, config)
    scores.unlabelled = {k: v for k, v in score_unlabelled(
        replay.tracks, replay.ego_stamps, config).items() if k != 'tracks'}
    made, source = hypotheses_made(replay)
    camera = camera_capture(replay, truth, true_stamps, true_poses, tol, config)
    result = {'mode': 'ground_truth', 'replay': str(folder), 'bag': str(bag),
              'config': asdict(config), 'ground_truth_frames_not_replayed': skipped,
              'ground_truth_has_visibility': truth.has_visibility,
              'hypotheses_made': made, 'hypotheses_source': source}
    result.update(scores.as_dict())
    result['camera'] = camera
    return Evaluation(result, scores, replay, truth, tracks, true_poses)


def camera_capture(replay: Replay, truth: TruthTable, true_stamps, true_poses, tolerance,
                   config: EvaluationConfig, head: HeadConfig | None = None) -> dict:
    """The paper's Table 4 row: objects captured by the camera on the active head.

    The head (``core.head``: target choice, lead of up to 3 s, command delay, pan speed
    limit, field of view) is driven by the replay's confirmed tracks and the ego-motion poses;
    an object is captured when it stays in the simulated camera's view for
    ``capture_samples`` scans (judged with the true platform pose and object positions).
    """
    head = head or HeadConfig()
    order = np.argsort(replay.ego_stamps, kind='stable')
    stamps, poses = replay.ego_stamps[order], replay.ego_poses[order]
    t = replay.tracks
    keep = t.confirmed
    scan_of_row = match_stamps(t.stamp[keep], stamps, tolerance)
    rows = np.column_stack((t.track_id[keep], t.x[keep], t.y[keep], t.vx[keep], t.vy[keep],
                            t.weight[keep]))
    per_scan = [rows[scan_of_row == k] for k in range(stamps.size)]
    pans = simulate_head(stamps, poses, per_scan, head)
    truth_frame = match_stamps(stamps, truth.stamps, tolerance)
    platform = interpolate_poses(true_stamps, true_poses, stamps)
    moving = np.hypot(truth.vx, truth.vy) >= config.min_speed
    visible_rows = truth.visible & moving
    objects = []
    for k in range(stamps.size):
        f = truth_frame[k]
        sel = visible_rows & (truth.frame == f) if f >= 0 else np.zeros(truth.frame.size, bool)
        objects.append(np.column_stack((truth.obj_id[sel], truth.x[sel], truth.y[sel])))
    captured = captured_objects(pans, platform, objects, head)
    passing = set(truth.obj_id[visible_rows].tolist())
    return {'objects_passing': len(passing), 'objects_captured': len(captured & passing),
            'captured_share': (len(captured & passing) / len(passing)) if passing else None,
            'head': asdict(head)}


def report_unlabelled(folder: str | Path,
                      config: EvaluationConfig = EvaluationConfig()) -> Evaluation:
    """Confirmed tracks and estimated false detections of a replay without ground truth."""
    replay = read_replay(folder)
    result = {'mode': 'unlabelled', 'replay': str(folder), 'config': asdict(config)}
    result.update(score_unlabelled(replay.tracks, replay.ego_stamps, config))
    made, source = hypotheses_made(replay)
    result.update(hypotheses_made=made, hypotheses_source=source)
    return Evaluation(result, None, replay)


def recording_kind(bag: str | Path, annotation_topic: str | None = None) -> str:
    """What a recording is scored against: ``simulated`` (``/ground_truth``), ``annotated``
    (hand annotations of people), ``reference`` (reference poses only, e.g. a SLAM-corrected
    CARMEN log) or ``unlabelled``."""
    from laser_tracker.tools.annotations import ANNOTATION_TOPIC
    from laser_tracker.tools.bag import GROUND_TRUTH_TOPIC, PLATFORM_TRUTH_TOPIC, topics

    info = topics(bag)
    if GROUND_TRUTH_TOPIC in info:
        return 'simulated'
    if (annotation_topic or ANNOTATION_TOPIC) in info:
        return 'annotated'
    if PLATFORM_TRUTH_TOPIC in info:
        return 'reference'
    return 'unlabelled'


def check_replayed(replay: Replay, bag: Path) -> None:
    """Refuse a recording other than the one the replay was made of (``summary.json`` names
    it): the scores would be meaningless. The same path, or a recording of the same name
    (a copy, a regenerated one), passes."""
    replayed = replay.summary.get('bag')
    if not isinstance(replayed, str) or not replayed:
        return
    replayed = Path(replayed)
    if replayed.resolve() == bag.resolve() or replayed.resolve().name == bag.resolve().name:
        return
    raise LaserTrackerError(f'{replay.folder} is a replay of {replayed} (its summary.json), '
                            f'not of {bag}: evaluate it against that recording, or give '
                            '--force to score it anyway')


def evaluate_recording(folder: str | Path, bag: str | Path,
                       config: EvaluationConfig = EvaluationConfig(), *,
                       static: str | None = None, scan_topic: str | None = None,
                       annotation_topic: str | None = None, persons=None,
                       static_config=None, force: bool = False, area=None,
                       sector=None) -> Evaluation:
    """Score a replay folder against whatever ground truth ``bag`` carries.

    The replay must be of ``bag`` (:func:`check_replayed`) unless ``force``.

    Simulated ground truth: :func:`evaluate_replay`; hand annotations:
    ``annotations.evaluate_annotated``; reference poses only: false tracks on static
    structure (``static_map.evaluate_static``). ``static`` (``reference`` or ``ego``) adds the
    static-structure count to any of them, or asks for it on an unlabelled recording.
    ``area``: hand annotations only, the box of the scan frame they cover (tracks outside it
    are not scored); ``sector``: hand annotations only, the bearings (degrees, scan frame)
    scored (annotations and tracks outside them are not).
    """
    from laser_tracker.tools.annotations import ANNOTATION_TOPIC, evaluate_annotated
    from laser_tracker.tools.bag import resolve_bag, scan_topic_of
    from laser_tracker.tools.static_map import StaticMapConfig, evaluate_static

    replay = read_replay(folder)
    bag = resolve_bag(bag)
    if not force:
        check_replayed(replay, bag)
    if scan_topic is not None:
        scan_topic = scan_topic_of(bag, scan_topic)
    annotation_topic = annotation_topic or ANNOTATION_TOPIC
    kind = recording_kind(bag, annotation_topic)
    if kind == 'reference' and static is None:
        static = 'reference'
    if kind == 'simulated':
        ev = evaluate_replay(folder, bag, config, replay)
    elif kind == 'annotated':
        ann = evaluate_annotated(replay, bag, config, annotation_topic, scan_topic, persons,
                                 area, sector)
        ev = Evaluation(ann.result, None, replay, annotated=ann)
    elif static is not None:
        result = {'mode': 'static', 'replay': str(folder), 'bag': str(bag)}
        estimate = score_unlabelled(replay.tracks, replay.ego_stamps, config)
        result['unlabelled_estimate'] = {k: v for k, v in estimate.items() if k != 'tracks'}
        ev = Evaluation(result, None, replay)
    else:
        raise InputFileError(bag, 'has no ground truth (no /ground_truth, annotation or '
                             'reference pose topic): a real recording? use `laser-tracker '
                             'evaluate DIR BAG --static-map ego` (false tracks on static '
                             'structure) or `laser-tracker evaluate DIR --no-ground-truth`')
    if static is not None:
        ev.static = evaluate_static(ev.replay, bag, static, scan_topic,
                                    static_config or StaticMapConfig(), config)
        ev.result['static_structure'] = ev.static.result
    return ev


# ------------------------------------------------------------------------------ output


def _num(v, fmt='{:.3f}'):
    return '-' if v is None else fmt.format(v)


def format_table(result: dict, view: str = 'clear-mot') -> str:
    """The human-readable table of an evaluation result (``evaluation.json``).

    ``view`` ``following`` prints only the person-following counts of an annotated recording.
    """
    mode = result['mode']
    if mode == 'unlabelled':
        return format_unlabelled(result)
    if mode == 'annotated':
        text = format_annotated(result, view)
    elif mode == 'static':
        text = format_static_only(result)
    else:
        text = format_ground_truth(result)
    if result.get('static_structure') and not (mode == 'annotated' and view == 'following'):
        text += '\n\n' + format_static(result['static_structure'])
    return text


def format_ground_truth(result: dict) -> str:
    cfg = result['config']
    which = 'confirmed tracks' if cfg['confirmed_only'] else 'all hypotheses'
    lines = [f'evaluation of {result["replay"]} against {result["bag"]}',
             f'  {result["frames"]} frames, match threshold {cfg["threshold"]:.2f} m, '
             f'{which} ({result["tracks_scored"]} scored)', '', 'paper rows']
    lengths = result['false_detection_frames']
    rows = [
        ('constant-velocity paths taken / detected',
         f'{result["paths_taken"]} / {result["paths_detected"]}'),
        ('false detections', f'{result["false_detections"]}  '
         f'({result["false_detections_after_match"]} right after the track was on an object)'),
        ('  length in frames (longest)',
         (', '.join(map(str, lengths[:20])) + (' ...' if len(lengths) > 20 else '')
          + f'  ({max(lengths)})') if lengths else '-'),
        ('velocity hypotheses made', f'{result["hypotheses_made"]}  '
                                     f'[{result["hypotheses_source"]}]'),
        ('clearly incorrect hypotheses', f'{result["incorrect_hypotheses"]}  '
         f'({result["incorrect_hypotheses_steady"]} at least '
         f'{cfg["settle_time"]:.1f} s after a velocity change)'),
        ('passing objects / detected',
         f'{result["objects_passing"]} / {result["objects_detected"]}'),
    ]
    cam = result.get('camera')
    if cam and cam['objects_passing']:
        rows.append(('captured by the camera (simulated head)',
                     f'{cam["objects_captured"]} of {cam["objects_passing"]} '
                     f'({100 * cam["captured_share"]:.0f} %)'))
    lines += [f'  {k:<42} {v}' for k, v in rows]
    det, pre = result['clear_mot']['detectable'], result['clear_mot']['present']
    lines += ['', f'CLEAR MOT {"":<32} {"detectable":>11} {"present":>11}']
    names = [('MOTA', 'mota', '{:.3f}'), ('MOTP (m)', 'motp', '{:.3f}'),
             ('ID switches', 'num_switches', '{:d}'),
             ('false positives', 'num_false_positives', '{:d}'),
             ('misses', 'num_misses', '{:d}'), ('matches', 'num_matches', '{:d}'),
             ('objects (ground-truth rows)', 'num_objects', '{:d}'),
             ('precision', 'precision', '{:.3f}'), ('recall', 'recall', '{:.3f}')]
    for label, key, fmt in names:
        lines.append(f'  {label:<40} {_num(det[key], fmt):>11} {_num(pre[key], fmt):>11}')
    e = result['position_error']
    lines += ['', f'position error (Fig. 8), {e["count"]} matches']
    if e['count']:
        lines.append(f'  median {e["median"]:.3f} m, mean {e["mean"]:.3f} m, '
                     f'95th percentile {e["p95"]:.3f} m, '
                     f'within 0.2 m {100 * e["within_0_2m"]:.0f} %')
    u = result.get('unlabelled_estimate') or {}
    if u:
        lines += ['', f'unlabelled estimate (cross-check of --no-ground-truth): '
                  f'{u["estimated_false"]} of {u["confirmed_tracks"]} confirmed tracks '
                  f'would count as false ({_rule(u)})']
    return '\n'.join(lines)


def _n(v) -> str:
    return f'{v:,}'


def format_following(result: dict) -> list[str]:
    f, c = result['following'], result['following_all_annotations']
    share = f'{100 * f["tracked_share"]:.1f} %' if f['tracked_share'] is not None else '-'
    share_all = f'{100 * c["tracked"] / c["objects"]:.1f} %' if c['objects'] else '-'
    return [
        f'person following (leg_tracker benchmark counting, false positives ignored), '
        f'threshold {result["config"]["threshold"]:.2f} m',
        f'  scored scans:     {_n(f["tracked"])} of {_n(f["objects"])} positions tracked '
        f'({share}), {_n(f["id_switches"])} ID switches, {_n(f["misses"])} misses'
        f'  [{_n(f["false_positives"])} false positives not counted]',
        f'  all annotations:  {_n(c["tracked"])} of {_n(c["objects"])} positions tracked '
        f'({share_all}), {_n(c["id_switches"])} ID switches, {_n(c["misses"])} misses'
        f'  (as the benchmark table counts; positions at unscored scans are misses)']


def format_annotated(result: dict, view: str = 'clear-mot') -> str:
    a, cfg = result['annotations'], result['config']
    which = 'confirmed tracks' if cfg['confirmed_only'] else 'all hypotheses'
    off = result['header_minus_receive_s']
    lines = [f'evaluation of {result["replay"]} against {result["bag"]} '
             f'(hand-annotated people on {result["annotation_topic"]})',
             f'  scans of {result["scan_topic"]} (frame {result["scan_frame"] or "?"}): '
             f'{_n(result["scans"])}; scored (the replay has an ego-motion pose): '
             f'{_n(result["frames_scored"])}']
    if abs(off) > 1.0:
        lines.append(f'  header stamps run {abs(off):.1f} s {"ahead of" if off > 0 else "behind"}'
                     f' receive times: each annotation is placed at the scan received before '
                     f'it')
    dropped = ', '.join(f'{a[k]} {text}' for k, text in (
        ('before_first_scan', 'before the first scan'),
        ('after_last_scan_dropped', 'long after the last scan'),
        ('non_finite', 'non-finite'), ('duplicates', 'duplicate')) if a.get(k))
    lines.append(f'  annotations: {_n(a["messages"])} messages, {_n(a["placed"])} placed'
                 f'{" (dropped: " + dropped + ")" if dropped else ""}; person id(s) '
                 f'{", ".join(map(str, a["persons"]))}')
    lines.append(f'    scored {_n(a["scored"])} ({_n(a["not_scored_no_pose"])} at scans '
                 f'without an ego-motion pose); walking {_n(a["walking"])}, standing '
                 f'{_n(a["standing"])} (slower than {cfg["walking_speed"]:.2f} m/s in the '
                 f'odometry frame over {cfg["speed_window"]:.1f} s), speed unknown '
                 f'{_n(a["speed_unknown"])} (counted as walking)')
    lines.append(f'  {which}: {result["tracks_scored"]} scored')
    if view == 'following':
        return '\n'.join(lines + [''] + format_following(result))
    mot = result['clear_mot']
    lines += ['', f'CLEAR MOT, threshold {cfg["threshold"]:.2f} m {"":<14} {"all":>11} '
              f'{"walking":>11}']
    names = [('MOTA', 'mota', '{:.3f}'), ('MOTP (m)', 'motp', '{:.3f}'),
             ('ID switches', 'num_switches', '{:d}'),
             ('false positives', 'num_false_positives', '{:d}'),
             ('misses', 'num_misses', '{:d}'), ('matches', 'num_matches', '{:d}'),
             ('objects (annotated positions)', 'num_objects', '{:d}'),
             ('precision', 'precision', '{:.3f}'), ('recall', 'recall', '{:.3f}')]
    for label, key, fmt in names:
        lines.append(f'  {label:<40} {_num(mot["all"][key], fmt):>11} '
                     f'{_num(mot["walking"][key], fmt):>11}')
    lines.append('  (only the annotated people are labelled: tracks on anyone else are false '
                 'positives here)')
    if result.get('false_positives_on_hidden') is not None:
        lines.append(f'  of the false positives, within the threshold of a person out of sight '
                     f'({_n(a["hidden"])} such positions): '
                     f'{_n(result["false_positives_on_hidden"])}')
    lines += [''] + format_following(result)
    return '\n'.join(lines)


def format_static(st: dict) -> str:
    cfg = st['config']
    source = ('reference poses (/ground_truth/platform)' if st['mode'] == 'reference' else
              f'the replay\'s ego-motion poses, scans within {cfg["window"]:g} s of each track')
    per = _num(st['confirmed_per_minute'], '{:.1f}')
    fper = _num(st['false_per_minute'], '{:.2f}')
    lines = [f'false tracks on static structure, map from {source}',
             f'  {_n(st["scans_placed"])} of {_n(st["scans"])} scans placed; '
             f'{st["duration_s"]:.1f} s ({st["duration_s"] / 60:.1f} min)',
             f'  confirmed tracks {st["confirmed_tracks"]} ({per} per minute); false (on static'
             f' structure) {st["false_tracks"]} ({fper} per minute)',
             f'  of the others: unsupported (no return of their scan within '
             f'{cfg["support"]:g} m) {st["unsupported_tracks"]} '
             f'({_num(st["unsupported_per_minute"], "{:.2f}")} per minute), moving '
             f'{st["moving_tracks"]}',
             f'  rule: static cell = hit by at least {100 * cfg["static_share"]:.0f} % of the '
             f'(at least {cfg["min_observations"]}) scans that observed it '
             f'({cfg["resolution"]:g} m cells); false track = at least '
             f'{100 * cfg["false_share"]:.0f} % of its confirmed positions within '
             f'{cfg["near"]:g} m of a static cell']
    if st['false_list']:
        lines.append('  false tracks: id, time from the start, place (median position), '
                     'positions on structure / confirmed')
        for f in st['false_list'][:20]:
            lines.append(f'    #{f["track"]:<7} {f["time_s"]:8.1f} s  ({f["x"]:7.2f}, '
                         f'{f["y"]:7.2f})  {f["on_structure"]}/{f["positions"]}')
        if len(st['false_list']) > 20:
            lines.append(f'    ... {len(st["false_list"]) - 20} more in the JSON')
    return '\n'.join(lines)


def format_static_only(result: dict) -> str:
    lines = [f'evaluation of {result["replay"]} against {result["bag"]} (no labels: static '
             f'structure only)']
    u = result.get('unlabelled_estimate') or {}
    if u:
        lines.append(f'  unlabelled estimate (cross-check): {u["estimated_false"]} of '
                     f'{u["confirmed_tracks"]} confirmed tracks would count as false '
                     f'({_rule(u)})')
    return '\n'.join(lines)


def _rule(r: dict) -> str:
    return (f'moved < {r["min_displacement"]:.2f} m or mean speed < '
            f'{r["min_track_speed"]:.2f} m/s while confirmed')


def format_unlabelled(result: dict) -> str:
    per = result['confirmed_per_minute']
    fper = result['estimated_false_per_minute']
    lines = [f'unlabelled report of {result["replay"]} (no ground truth)',
             f'  {result["scans"]} scans over {result["duration_s"]:.1f} s',
             f'  velocity hypotheses made          {result["hypotheses_made"]}  '
             f'[{result["hypotheses_source"]}]',
             f'  confirmed tracks                  {result["confirmed_tracks"]}'
             f'  ({_num(per, "{:.1f}")} per minute)',
             f'  estimated false detections        {result["estimated_false"]}'
             f'  ({_num(fper, "{:.1f}")} per minute)',
             f'    counted as false: {_rule(result)}']
    if result['confirmed_tracks']:
        hist = ', '.join(f'{k}: {v}' for k, v in result['confirmed_frames_histogram'].items())
        lines.append(f'  confirmed life in frames          median '
                     f'{result["confirmed_frames_median"]:.0f}, '
                     f'max {result["confirmed_frames_max"]}')
        lines.append(f'    tracks by confirmed frames      {hist}')
    return '\n'.join(lines)


def error_figure(errors: np.ndarray, path: Path, threshold: float) -> Path:
    """Fig. 8: histogram and CDF of the distance between matched tracks and their objects."""
    plt = pyplot()

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    if errors.size:
        ax1.hist(errors, bins=np.linspace(0, threshold, 31), color='tab:blue')
        xs = np.sort(errors)
        ax2.plot(xs, np.arange(1, xs.size + 1) / xs.size, color='tab:blue')
        for ax in (ax1, ax2):
            ax.axvline(float(np.median(errors)), color='k', ls='--', lw=1, label='median')
            ax.axvline(0.2, color='tab:red', ls=':', lw=1, label='0.2 m (paper)')
        ax2.legend(loc='lower right')
    else:
        ax1.text(0.5, 0.5, 'no matches', ha='center', transform=ax1.transAxes)
    ax1.set(xlabel='distance track - object (m)', ylabel='matches',
            title=f'position error ({errors.size} matches)')
    ax2.set(xlabel='distance track - object (m)', ylabel='fraction', ylim=(0, 1.01),
            xlim=(0, threshold), title='cumulative')
    fig.tight_layout()
    out = save_figure(fig, path)
    plt.close(fig)
    return out


def tracks_figure(truth: TruthTable | None, tracks: TrackTable, false_ids: set[int],
                  path: Path, title: str, platform: np.ndarray | None = None,
                  arrow_s: float = 1.0, people: tuple | None = None,
                  static_cells: np.ndarray | None = None, segments=None) -> Path:
    """Ground truth (thick green), the scanner path (black, dashed), tracks (the longest
    labelled with their id and velocity arrows of ``arrow_s`` s of travel), false ones red.

    ``people``: ``(xy (A, 2), ids (A,), walking (A,))`` annotated people (walking: filled,
    standing: hollow); ``static_cells`` (K, 2) drawn as grey squares underneath.
    """
    from laser_tracker.tools.figures import (GROUND_TRUTH_COLOUR, draw_scanner, draw_tracks,
                                             MAX_ARROW, fit_view, tracks_legend)
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(9, 8))
    if static_cells is not None and len(static_cells):
        ax.plot(static_cells[:, 0], static_cells[:, 1], 's', color='0.8', ms=1.2,
                label='static structure', zorder=1)
    if platform is not None and len(platform):
        draw_scanner(ax, platform, segments=segments)
    if truth is not None:
        for k, oid in enumerate(np.unique(truth.obj_id)):
            m = truth.obj_id == oid
            ax.plot(truth.x[m], truth.y[m], color=GROUND_TRUTH_COLOUR, lw=5, alpha=0.35,
                    solid_capstyle='round', label='ground truth' if k == 0 else None,
                    zorder=2)
    if people is not None and len(people[0]):
        xy, _, walking = people
        walking = np.asarray(walking, bool)
        ax.plot(xy[walking, 0], xy[walking, 1], 'o', color=GROUND_TRUTH_COLOUR, ms=3,
                alpha=0.5, label='annotated person, walking', zorder=2)
        ax.plot(xy[~walking, 0], xy[~walking, 1], 'o', mfc='none', color=GROUND_TRUTH_COLOUR,
                ms=4, alpha=0.7, label='annotated person, standing (don\'t care)', zorder=2)
    n = int(np.unique(tracks.track_id).size)
    shown = draw_tracks(ax, tracks.stamp, tracks.track_id, tracks.x, tracks.y, tracks.vx,
                        tracks.vy, false_ids, arrow_s=arrow_s) if n else 0
    fit_view(ax, np.column_stack((tracks.x, tracks.y)), platform, static_cells,
             None if truth is None else np.column_stack((truth.x, truth.y)),
             None if people is None else people[0], pad=MAX_ARROW if arrow_s > 0 else 1.0)
    ax.set(xlabel='x (m)', ylabel='y (m)', title=title)
    ax.grid(True, lw=0.3)
    false_shown = len({int(t) for t in np.unique(tracks.track_id)} & set(false_ids))
    tracks_legend(ax, n, shown, arrow_s, false=false_shown)
    fig.tight_layout()
    out = save_figure(fig, path)
    plt.close(fig)
    return out


def write_figures(ev: Evaluation, folder: str | Path) -> list[Path]:
    """The figures of an evaluation, in ``folder``; a figure that fails is a warning only."""
    folder, result, replay = Path(folder), ev.result, ev.replay
    written = []
    try:
        conf = replay.tracks.select(replay.tracks.confirmed)
        if result['mode'] == 'unlabelled':
            false_ids = {t['track'] for t in result['tracks'] if t['estimated_false']}
            written.append(tracks_figure(
                None, conf, false_ids, folder / REPORT_FIGURE,
                f'confirmed tracks (odometry frame): {len(result["tracks"])}, '
                f'{len(false_ids)} estimated false (red)',
                platform=replay.ego_poses))
        elif result['mode'] == 'annotated':
            a = ev.annotated
            scored = replay.tracks if not result['config']['confirmed_only'] else conf
            written.append(tracks_figure(
                None, scored, set(), folder / TRACKS_FIGURE,
                'annotated people and tracks (odometry frame of the replay'
                + (f'; {result["ego_motion_runs"]} ego-motion runs overlaid)'
                   if result['ego_motion_runs'] > 1 else ')'),
                platform=a.scan_poses, people=(a.people_odom, a.people_id, a.people_walking),
                segments=a.scan_segments))
        elif result['mode'] == 'ground_truth':
            written.append(error_figure(ev.scores.errors, folder / ERROR_FIGURE,
                                        result['config']['threshold']))
            tracks = ev.tracks_map
            if result['config']['confirmed_only']:
                tracks = tracks.select(tracks.confirmed)
            written.append(tracks_figure(
                ev.truth, tracks, {f['track'] for f in result['false_detection_list']},
                folder / TRACKS_FIGURE, 'scored tracks (map frame) and ground truth',
                platform=ev.platform_poses))
        if ev.static is not None:
            written.append(static_figure(ev.static, folder / STATIC_FIGURE))
    except Exception as exc:  # a figure is a by-product: never lose the scores for it
        log.warning('figure not written: %s: %s', type(exc).__name__, exc)
    return written


def static_figure(st, path: Path) -> Path:
    """Static structure (grey), the scanner path and the confirmed tracks, false ones red."""
    r = st.result
    tid = st.track_id
    tracks = TrackTable(stamp=st.track_stamp, track_id=tid, x=st.track_xy[:, 0],
                        y=st.track_xy[:, 1], vx=np.zeros(tid.size), vy=np.zeros(tid.size),
                        weight=np.zeros(tid.size), confirmed=np.ones(tid.size, bool))
    frame = 'reference (map) frame' if r['mode'] == 'reference' else 'odometry frame'
    return tracks_figure(None, tracks, {v.track for v in st.verdicts if v.false}, path,
                         f'confirmed tracks on static structure ({frame}): '
                         f'{r["false_tracks"]} of {r["confirmed_tracks"]} false (red)',
                         platform=st.scanner, arrow_s=0.0,
                         static_cells=st.static.static_cells())


# ------------------------------------------------------------------------------ command


def config_from_args(args: argparse.Namespace) -> EvaluationConfig:
    from laser_tracker.config import from_dict

    values = {'threshold': args.threshold, 'confirmed_only': args.confirmed_only,
              'min_speed': args.min_speed, 'min_displacement': args.min_displacement,
              'min_track_speed': args.min_track_speed, 'walking_speed': args.walking_speed}
    return from_dict(EvaluationConfig, values)


def static_config_from_args(args: argparse.Namespace):
    from laser_tracker.config import from_dict
    from laser_tracker.tools.static_map import StaticMapConfig

    values = {} if args.static_window is None else {'window': args.static_window}
    return from_dict(StaticMapConfig, values)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    d = EvaluationConfig()
    parser.add_argument('dir', metavar='DIR', help='a `laser-tracker replay` output folder')
    parser.add_argument('bag', metavar='BAG', nargs='?',
                        help='the replayed recording: simulated (/ground_truth), hand-annotated'
                             ' (/ground_truth_people_tracks) or with reference poses '
                             '(/ground_truth/platform); not needed with --no-ground-truth')
    parser.add_argument('--threshold', type=float, default=d.threshold,
                        help=f'match distance in metres (default {d.threshold})')
    group = parser.add_mutually_exclusive_group()
    group.add_argument('--confirmed-only', dest='confirmed_only', action='store_true',
                       default=True, help='score confirmed tracks only (default)')
    group.add_argument('--all', dest='confirmed_only', action='store_false',
                       help='score every hypothesis, confirmed or not')
    parser.add_argument('--min-speed', type=float, default=d.min_speed,
                        help=f'objects slower than this (m/s) are standing: not required to '
                             f'be detected, and they end a path (default {d.min_speed})')
    parser.add_argument('--mode', choices=('clear-mot', 'following'), default='clear-mot',
                        help='annotated recordings: print CLEAR MOT over all and walking '
                             'people (default) or only the person-following counts of the '
                             'leg_tracker benchmarks (tracked, ID switches, misses)')
    parser.add_argument('--walking-speed', type=float, default=d.walking_speed,
                        help='annotated recordings: a person slower than this (m/s, '
                             f'odometry frame) is "don\'t care" in the walking figures '
                             f'(default {d.walking_speed})')
    parser.add_argument('--scan-topic', help='the replayed LaserScan topic (default: the '
                                             'one whose header stamps the replay has)')
    parser.add_argument('--annotation-topic', help='hand annotations (leg_tracker Person) '
                                                   '(default /ground_truth_people_tracks)')
    parser.add_argument('--person', type=int, action='append', metavar='ID',
                        help='annotated recordings: score only this person id (repeatable)')
    parser.add_argument('--area', nargs=4, type=float, metavar=('XMIN', 'XMAX', 'YMIN', 'YMAX'),
                        help='annotated recordings: only this box of the scan frame is '
                             'annotated; tracks outside it are scored only on an annotated '
                             'person')
    parser.add_argument('--sector', nargs=2, type=float, metavar=('MIN_DEG', 'MAX_DEG'),
                        help='annotated recordings: score only the annotations and tracks '
                             'whose bearing in the scan frame lies between these angles '
                             '(degrees), as leg_tracker\'s benchmarks score their recordings '
                             'of a moving robot (-80 12)')
    static = parser.add_mutually_exclusive_group()
    static.add_argument('--static-map', choices=('reference', 'ego'),
                        help='also count false confirmed tracks on static structure, mapped '
                             'with the reference poses (/ground_truth/platform, e.g. a '
                             'corrected CARMEN log; the default for such a recording) or with '
                             'the replay\'s own ego-motion poses over local time windows')
    static.add_argument('--reference-poses', dest='static_map', action='store_const',
                        const='reference', help='same as --static-map reference')
    parser.add_argument('--static-window', type=float, default=None, metavar='S',
                        help='--static-map ego: scans within this time of a track build its '
                             'map (default 30 s)')
    parser.add_argument('--no-ground-truth', action='store_true',
                        help='unlabelled recording: confirmed tracks and estimated false '
                             'detections per minute')
    parser.add_argument('--min-displacement', type=float, default=d.min_displacement,
                        help='--no-ground-truth: a confirmed track moving less than this (m) '
                             f'counts as a false detection (default {d.min_displacement})')
    parser.add_argument('--min-track-speed', type=float, default=d.min_track_speed,
                        help='--no-ground-truth: a confirmed track slower than this on '
                             f'average (m/s) counts as a false detection (default '
                             f'{d.min_track_speed})')
    parser.add_argument('--force', action='store_true',
                        help='score DIR against BAG even if DIR is a replay of another '
                             'recording (its summary.json names the replayed one)')
    parser.add_argument('--json', metavar='OUT', help='JSON output (default DIR/evaluation.json)')
    parser.add_argument('--no-figures', action='store_true', help='write no figures')


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format='%(levelname)s %(name)s: %(message)s')
    config = config_from_args(args)
    folder = Path(args.dir)
    check_output(args.json or folder / 'evaluation.json', overwrite=True)
    if args.no_ground_truth:
        if args.bag:
            log.warning('BAG %s ignored with --no-ground-truth', args.bag)
        ev = report_unlabelled(folder, config)
    else:
        if not args.bag:
            raise LaserTrackerError('BAG is required (the recording with /ground_truth), '
                                    'or --no-ground-truth for an unlabelled report')
        ev = evaluate_recording(folder, args.bag, config, static=args.static_map,
                                scan_topic=args.scan_topic,
                                annotation_topic=args.annotation_topic, persons=args.person,
                                static_config=static_config_from_args(args),
                                force=args.force, area=args.area, sector=args.sector)
    result = ev.result
    figures = [] if args.no_figures else write_figures(ev, folder)
    result['figures'] = [str(p) for p in figures]
    out = write_json(args.json or folder / 'evaluation.json', result)
    print(format_table(result, args.mode))
    print()
    for p in figures:
        print(f'figure: {p}')
    print(f'json:   {out}')
    sys.stdout.flush()
    return 0
