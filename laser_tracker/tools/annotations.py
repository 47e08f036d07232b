"""Hand-annotated people in a real recording (the leg_tracker benchmarks) and their scores.

Reading (:func:`read_annotations`)
    ``/ground_truth_people_tracks``: leg_tracker/msg/Person (``pose``, ``id``; the definition
    travels inside the bag), one message per annotated person per scan, its position in the
    scan's frame. The annotation tool writes each one halfway between the *receive* times of
    the scan it belongs to and the next scan, so an annotation belongs to the scan whose bag
    receive time last precedes it (the rule of the benchmark's scoring script,
    ``clear_mot/scripts/clear_mot.py`` in angusleigh/leg_tracker_benchmarks). Header stamps
    may run far from receive times (about 130 s ahead in person_following_outdoor_1), and a
    replay names its scans by header stamp, so the receive time -> header stamp mapping comes
    from the bag's own scan topic. Annotations before the first scan are dropped (the script
    drops them too); after the last scan they are attached to it when within
    ``LAST_SCAN_PERIODS`` scan periods (the tool writes the last one there), else dropped.
    A second annotation of the same id at the same scan replaces the first; non-finite
    positions are dropped. Everything dropped is counted and reported.

Speed of an annotated person (:func:`annotation_velocities`)
    Judged in the odometry (world) frame, not the scanner's: a followed person stays put in
    the scanner frame while walking. Each annotation is placed in the odometry frame with the
    replay's ego-motion pose of its scan, and the velocity is the least-squares slope of the
    person's positions within ``speed_window`` seconds centred on it and in the same
    ego-motion run (the ego-motion restarts in a new frame after losing track; a run ends
    where consecutive poses imply more than ``restart_speed`` or are ``restart_gap`` apart).
    At least 3 annotations spanning 40 % of the window are needed, else the speed is unknown
    and the person counts as walking. Hand clicks jitter by a few centimetres, which a 1 s
    fit reduces to about 0.05 m/s. The speed inherits the ego-motion's errors: a replay whose
    ego-motion is poor judges walking less well.

CLEAR MOT (:func:`score_clear_mot`, motmetrics)
    Frames are the bag's scans that the replay has an ego-motion pose for; tracks (confirmed
    unless asked otherwise) are brought into the scan frame of their scan with the inverse of
    its ego-motion pose and matched within the threshold (0.75 m by default, as the benchmark).
    ``all``: every annotated person. ``walking``: an annotation slower than ``min_speed``
    (0.3 m/s) is "don't care": not a miss, and a track assigned to it (Hungarian, within the
    threshold) is not a false positive. Only the annotated people are labelled, so every track
    on a passer-by counts as a false positive in both.

Person following (:func:`score_following`)
    The counting of ``clear_mot.py`` (leg_tracker_benchmarks), whose person-following table
    reports tracked positions, ID switches and misses (false positives ignored, as only the
    followed person is annotated). Per frame, in receive order:

    1. a (track id -> person id) pair matched at an earlier frame is kept when both ids are
       present and closer than the threshold (strictly);
    2. the remaining tracks and people are paired by a minimum-total-distance assignment on
       the plain distances (not capped at the threshold); a pair closer than the threshold
       is a match;
    3. people without a match are misses, tracks without a match false positives;
    4. a match is an ID switch when its track was last matched to another person, or (the
       track never matched before) its person was last matched to another track; otherwise
       it is a correct ("tracked") position;
    5. the remembered pairs that share a track or a person with this frame's matches are
       replaced by them; the others stay remembered (across frames where they are absent).

    ``objects = tracked + ID switches + misses``; MOTA and MOTP as in the script.

People out of sight (``HIDDEN_TOPIC``, optional)
    Where a recording knows where people are whom no beam sees (a composite that puts
    labelled people into another recording knows which of them its building hides), it may
    carry them on ``/ground_truth_people_hidden`` (the same Person messages). They are not
    scored: a track on one is still a false positive, as annotators of the people in view
    would count it, but such false positives are counted apart
    (``false_positives_on_hidden``): a track that follows a person through an occlusion is
    where that person is.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from laser_tracker.errors import InputFileError
from laser_tracker.tools.bag import ScanTimes

log = logging.getLogger(__name__)

ANNOTATION_TOPIC = '/ground_truth_people_tracks'
HIDDEN_TOPIC = '/ground_truth_people_hidden'
PERSON_MSGTYPE = 'leg_tracker/msg/Person'
PERSON_DEFINITION = 'geometry_msgs/Pose pose\nuint32 id\n'
LAST_SCAN_PERIODS = 1.5


# ------------------------------------------------------------------------------ reading


@dataclass
class Annotations:
    """Annotated positions (A,) placed at the scans (S,) of the bag's scan topic."""

    bag: str
    topic: str
    scans: ScanTimes
    scan: np.ndarray       # (A,) index into scans (receive order)
    obj_id: np.ndarray     # (A,)
    x: np.ndarray          # (A,) scan frame
    y: np.ndarray
    counts: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.scan.size)

    @property
    def header_offset(self) -> float:
        """Median of header stamp minus receive time over the scans (s)."""
        return float(np.median(self.scans.stamps - self.scans.receive_ns * 1e-9))

    def ids(self) -> list[int]:
        return sorted(int(i) for i in np.unique(self.obj_id))

    def select(self, mask) -> Annotations:
        return Annotations(self.bag, self.topic, self.scans, self.scan[mask], self.obj_id[mask],
                           self.x[mask], self.y[mask], dict(self.counts))

    def mirrored(self) -> Annotations:
        """The positions in the frame of an upside-down scanner turned right side up, the
        frame of its replay (``Scan.mirrored``)."""
        return Annotations(self.bag, self.topic, self.scans, self.scan, self.obj_id, self.x,
                           -self.y, dict(self.counts))


def register_person_type(typestore) -> None:
    """Add leg_tracker/msg/Person to a rosbags typestore (to write test recordings)."""
    from rosbags.typesys import get_types_from_msg

    if PERSON_MSGTYPE not in typestore.fielddefs:
        typestore.register(get_types_from_msg(PERSON_DEFINITION, PERSON_MSGTYPE))


def choose_scan_topic(bag: str | Path, ego_stamps: np.ndarray | None,
                      tolerance: float = 0.02) -> ScanTimes:
    """The LaserScan topic of ``bag`` whose header stamps the replay's scans have.

    With one LaserScan topic it is that one; with several, the one matching most of
    ``ego_stamps`` (within ``tolerance`` s). InputFileError when there is none.
    """
    from laser_tracker.tools.bag import read_scan_times, scan_topics
    from laser_tracker.tools.scoring import match_stamps

    names = scan_topics(bag)
    if not names:
        raise InputFileError(bag, 'has no LaserScan topic to place the annotations at')
    if len(names) == 1 or ego_stamps is None:
        if len(names) > 1:
            raise InputFileError(bag, f'has several LaserScan topics ({", ".join(names)}): '
                                 'name the replayed one with --scan-topic')
        return read_scan_times(bag, names[0])
    best, best_hits = None, -1
    ego = np.sort(np.asarray(ego_stamps, float))
    for name in names:
        times = read_scan_times(bag, name)
        hits = int((match_stamps(ego, np.sort(times.stamps), tolerance) >= 0).sum())
        if hits > best_hits:
            best, best_hits = times, hits
    log.info('%s: scan topic %s chosen (%d of %d replayed scans have its header stamps)',
             bag, best.topic, best_hits, ego.size)
    return best


def read_annotations(bag: str | Path, topic: str = ANNOTATION_TOPIC,
                     scans: ScanTimes | None = None, scan_topic: str | None = None
                     ) -> Annotations:
    """The annotations of ``bag`` placed at the scans of its scan topic (module docstring).

    ``scans``: the scan topic's times if already read; else ``scan_topic`` (or the only
    LaserScan topic) is read. InputFileError for a recording without annotations or scans.
    """
    from laser_tracker.tools.bag import iter_messages, read_scan_times, topics

    info = topics(bag)
    if topic not in info:
        raise InputFileError(bag, f'has no annotations (no {topic} topic)')
    if not info[topic][0].endswith('/Person'):
        raise InputFileError(bag, f'{topic} is {info[topic][0]}, not a leg_tracker Person '
                             '(pose, id)')
    if scans is None:
        scans = (read_scan_times(bag, scan_topic) if scan_topic
                 else choose_scan_topic(bag, None))
    if len(scans) == 0:
        raise InputFileError(bag, f'the scan topic {scans.topic} holds no messages')
    if np.any(np.diff(scans.stamps) <= 0):
        log.warning('%s: header stamps of %s do not increase with receive time at %d scan(s)',
                    bag, scans.topic, int((np.diff(scans.stamps) <= 0).sum()))
    times, ids, xs, ys = [], [], [], []
    for index, (_, t_ns, msg) in enumerate(iter_messages(bag, [topic])):
        try:
            p = msg.pose.position
            x, y, oid = float(p.x), float(p.y), int(msg.id)
        except (AttributeError, TypeError, ValueError):
            raise InputFileError(bag, f'{topic} is {info[topic][0]}, not a leg_tracker Person '
                                 f'(pose, id)', f'message {index}') from None
        times.append(int(t_ns))
        ids.append(oid)
        xs.append(x)
        ys.append(y)
    if not times:
        raise InputFileError(bag, f'the {topic} topic holds no messages')
    t = np.asarray(times, np.int64)
    x, y, oid = np.asarray(xs, float), np.asarray(ys, float), np.asarray(ids, np.int64)
    counts = {'messages': int(t.size)}

    receive = scans.receive_ns
    k = np.searchsorted(receive, t, side='right') - 1
    period_ns = float(np.median(np.diff(receive))) if receive.size > 1 else 1e8
    after = t > receive[-1]
    late = after & (t - receive[-1] > LAST_SCAN_PERIODS * period_ns)
    before = k < 0
    finite = np.isfinite(x) & np.isfinite(y)
    counts['before_first_scan'] = int(before.sum())
    counts['after_last_scan_attached'] = int((after & ~late).sum())
    counts['after_last_scan_dropped'] = int(late.sum())
    counts['non_finite'] = int((~finite & ~before & ~late).sum())
    keep = ~before & ~late & finite
    # a second annotation of one id at one scan replaces the first (receive order)
    order = np.flatnonzero(keep)
    key = k[order] * (int(oid.max()) - int(oid.min()) + 1) + (oid[order] - oid.min())
    _, last_rev = np.unique(key[::-1], return_index=True)
    chosen = order[::-1][last_rev]
    counts['duplicates'] = int(order.size - chosen.size)
    chosen.sort()
    out = Annotations(str(bag), topic, scans, k[chosen], oid[chosen], x[chosen], y[chosen],
                      counts)
    _warn_dropped(bag, topic, scans, counts)
    return out


def _warn_dropped(bag, topic, scans: ScanTimes, counts: dict) -> None:
    reasons = {
        'before_first_scan': f'received before the first scan of {scans.topic}: dropped',
        'after_last_scan_dropped': f'received more than {LAST_SCAN_PERIODS:g} scan periods '
                                   f'after the last scan of {scans.topic} (scans missing?): '
                                   'dropped',
        'non_finite': 'with a non-finite position: dropped',
        'duplicates': 'repeat an id already annotated at the same scan: the later one kept',
    }
    for key, text in reasons.items():
        if counts.get(key):
            log.warning('%s: %d of %d %s message(s) %s', bag, counts[key], counts['messages'],
                        topic, text)


# ------------------------------------------------------------------------------ frames


def to_frame(poses: np.ndarray, x, y) -> tuple[np.ndarray, np.ndarray]:
    """Points given in the frames of ``poses`` (N, 3), one pose per point, into their parent."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return c * x - s * y + poses[:, 0], s * x + c * y + poses[:, 1]


def from_frame(poses: np.ndarray, x, y) -> tuple[np.ndarray, np.ndarray]:
    """Points of the parent frame into the frames of ``poses`` (N, 3), one pose per point."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    dx, dy = x - poses[:, 0], y - poses[:, 1]
    return c * dx + s * dy, -s * dx + c * dy


def rotate_into(poses: np.ndarray, vx, vy) -> tuple[np.ndarray, np.ndarray]:
    """Vectors of the parent frame expressed in the axes of ``poses`` (N, 3)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return c * vx + s * vy, -s * vx + c * vy


def annotation_velocities(stamps: np.ndarray, obj_id: np.ndarray, x: np.ndarray, y: np.ndarray,
                          window: float = 1.0, segment: np.ndarray | None = None,
                          min_points: int = 3, min_span_share: float = 0.4) -> np.ndarray:
    """(A, 2) velocity of each annotation: least-squares slope of its person's positions
    (``x``, ``y``, odometry frame, NaN where unknown) within ``window`` s centred on it and
    in the same ego-motion run (``segment``: positions of different runs are in different
    frames); NaN where fewer than ``min_points`` positions spanning ``min_span_share`` of the
    window.
    """
    stamps, obj_id = np.asarray(stamps, float), np.asarray(obj_id)
    seg = np.zeros(stamps.size, np.int64) if segment is None else np.asarray(segment)
    out = np.full((stamps.size, 2), np.nan)
    usable = np.isfinite(x) & np.isfinite(y) & np.isfinite(stamps)
    half = window / 2.0
    for oid, sid in {(int(o), int(g)) for o, g in zip(obj_id[usable], seg[usable])}:
        rows = np.flatnonzero(usable & (obj_id == oid) & (seg == sid))
        rows = rows[np.argsort(stamps[rows], kind='stable')]
        t = stamps[rows] - stamps[rows[0]]
        px, py = x[rows], y[rows]
        lo = np.searchsorted(t, t - half, side='left')
        hi = np.searchsorted(t, t + half, side='right')
        csum = [np.concatenate(([0.0], np.cumsum(v)))
                for v in (np.ones_like(t), t, t * t, px, py, t * px, t * py)]
        n, st, stt, sx, sy, stx, sty = (c[hi] - c[lo] for c in csum)
        den = n * stt - st * st
        span = t[hi - 1] - t[lo]
        ok = (n >= min_points) & (span >= min_span_share * window) & (den > 1e-12)
        with np.errstate(invalid='ignore', divide='ignore'):
            vx = (n * stx - st * sx) / den
            vy = (n * sty - st * sy) / den
        out[rows[ok], 0] = vx[ok]
        out[rows[ok], 1] = vy[ok]
    return out


# ------------------------------------------------------------------------------ scoring


@dataclass
class Frames:
    """Objects and tracks per frame: rows ``(frame, id, x, y)`` as columns, one frame space."""

    frame: np.ndarray
    obj_id: np.ndarray
    x: np.ndarray
    y: np.ndarray

    @classmethod
    def of(cls, frame, obj_id, x, y) -> Frames:
        return cls(np.asarray(frame, np.int64), np.asarray(obj_id, np.int64),
                   np.asarray(x, float), np.asarray(y, float))

    def groups(self, n: int) -> list[np.ndarray]:
        from laser_tracker.tools.scoring import _group
        return _group(self.frame, n)


@dataclass
class FollowingCounts:
    """The counts of the benchmark's ``clear_mot.py`` (module docstring)."""

    tracked: int = 0
    id_switches: int = 0
    misses: int = 0
    false_positives: int = 0
    distance_sum: float = 0.0
    frames: int = 0

    @property
    def objects(self) -> int:
        return self.tracked + self.id_switches + self.misses

    @property
    def matches(self) -> int:
        return self.tracked + self.id_switches

    def as_dict(self) -> dict:
        n = self.objects
        return {'frames': self.frames, 'objects': n, 'tracked': self.tracked,
                'id_switches': self.id_switches, 'misses': self.misses,
                'false_positives': self.false_positives,
                'tracked_share': self.tracked / n if n else None,
                'mota': (1.0 - (self.id_switches + self.false_positives + self.misses) / n)
                if n else None,
                'motp': self.distance_sum / self.matches if self.matches else None}


def score_following(n_frames: int, people: Frames, tracks: Frames,
                    threshold: float = 0.75) -> FollowingCounts:
    """Count frames ``0 .. n_frames-1`` in order with the benchmark's rules (module docstring).

    Ids must be unique within a frame for each of ``people`` and ``tracks``.
    """
    counts = FollowingCounts(frames=n_frames)
    remembered: dict[int, int] = {}     # track id -> person id, as the script's dict
    p_groups, t_groups = people.groups(n_frames), tracks.groups(n_frames)
    for f in range(n_frames):
        prow, trow = p_groups[f], t_groups[f]
        pid, tid = people.obj_id[prow], tracks.obj_id[trow]
        d = np.hypot(tracks.x[trow][:, None] - people.x[prow][None, :],
                     tracks.y[trow][:, None] - people.y[prow][None, :])
        matched_t = np.full(trow.size, -1)       # column of the person each track matched
        matched_p = np.zeros(prow.size, bool)
        t_index = {int(i): j for j, i in reversed(list(enumerate(tid)))}
        p_index = {int(i): j for j, i in reversed(list(enumerate(pid)))}
        for track_id, person_id in remembered.items():          # rule 1
            j, i = t_index.get(track_id), p_index.get(person_id)
            if j is not None and i is not None and d[j, i] < threshold \
                    and matched_t[j] < 0 and not matched_p[i]:
                matched_t[j], matched_p[i] = i, True
        free_t, free_p = np.flatnonzero(matched_t < 0), np.flatnonzero(~matched_p)
        if free_t.size and free_p.size:                          # rule 2
            rows, cols = linear_sum_assignment(d[np.ix_(free_t, free_p)])
            for r, c in zip(rows, cols):
                j, i = free_t[r], free_p[c]
                if d[j, i] < threshold:
                    matched_t[j], matched_p[i] = i, True
        counts.misses += int((~matched_p).sum())                 # rule 3
        counts.false_positives += int((matched_t < 0).sum())
        pairs = [(int(tid[j]), int(pid[matched_t[j]]), float(d[j, matched_t[j]]))
                 for j in np.flatnonzero(matched_t >= 0)]
        earlier_people = set(remembered.values())
        for track_id, person_id, dist in pairs:                  # rule 4
            if track_id in remembered:
                same = remembered[track_id] == person_id
            else:
                same = person_id not in earlier_people
            if same:
                counts.tracked += 1
            else:
                counts.id_switches += 1
            counts.distance_sum += dist
        now_t = {p[0] for p in pairs}                             # rule 5
        now_p = {p[1] for p in pairs}
        remembered = {k: v for k, v in remembered.items() if k not in now_t and v not in now_p}
        remembered.update({t: p for t, p, _ in pairs})
    return counts


def score_clear_mot(n_frames: int, people: Frames, care: np.ndarray, tracks: Frames,
                    threshold: float = 0.75):
    """CLEAR MOT (motmetrics) over every person (``all``) and over the ``care`` ones
    (``walking``; a track assigned to a don't-care person is dropped from that frame).

    Returns ``({'all': ..., 'walking': ...}, match distances all, match distances walking,
    the per-frame verdicts over all (``scoring.FrameVerdicts``))``.
    """
    import motmetrics as mm

    from laser_tracker.tools.scoring import _assign, _mot_summary, frame_verdicts

    acc_all = mm.MOTAccumulator(auto_id=False)
    acc_walk = mm.MOTAccumulator(auto_id=False)
    care = np.asarray(care, bool)
    p_groups, t_groups = people.groups(n_frames), tracks.groups(n_frames)
    for f in range(n_frames):
        prow, trow = p_groups[f], t_groups[f]
        d = np.hypot(people.x[prow][:, None] - tracks.x[trow][None, :],
                     people.y[prow][:, None] - tracks.y[trow][None, :])
        d = d.reshape(prow.size, trow.size)
        dm = np.where(d <= threshold, d, np.nan)
        pid, tid = people.obj_id[prow], tracks.obj_id[trow]
        acc_all.update(pid.tolist(), tid.tolist(), dm, frameid=f)
        c = care[prow]
        drop = np.zeros(trow.size, bool)
        for r, k in _assign(d, threshold):
            if not c[r]:
                drop[k] = True
        acc_walk.update(pid[c].tolist(), tid[~drop].tolist(), dm[c][:, ~drop], frameid=f)

    def errors(acc):
        ev = acc.mot_events
        return ev.loc[ev['Type'].isin(['MATCH', 'SWITCH']), 'D'].to_numpy(float)

    def rows(frames: Frames):
        return frames.frame, frames.obj_id, np.column_stack((frames.x, frames.y))

    return ({'all': _mot_summary(acc_all, 'all'), 'walking': _mot_summary(acc_walk, 'walking')},
            errors(acc_all), errors(acc_walk), frame_verdicts(acc_all, rows(people), rows(tracks)))


def error_stats(errors: np.ndarray) -> dict:
    if errors.size == 0:
        return {'count': 0, 'median': None, 'mean': None, 'p95': None}
    return {'count': int(errors.size), 'median': float(np.median(errors)),
            'mean': float(errors.mean()), 'p95': float(np.percentile(errors, 95))}




# ------------------------------------------------------------------------------ evaluation


@dataclass
class AnnotatedEvaluation:
    """The result of :func:`evaluate_annotated`: JSON dict plus what the figures need."""

    result: dict
    people_odom: np.ndarray       # (A, 2) scored annotations in the odometry frame
    people_id: np.ndarray
    people_walking: np.ndarray    # (A,) bool
    scan_poses: np.ndarray        # (S', 3) ego poses of the scored scans
    scan_segments: np.ndarray     # (S',) their ego-motion run numbers
    frame_stamps: np.ndarray | None = None   # (S',) header stamps of the scored scans
    verdicts: object | None = None           # scoring.FrameVerdicts (all), scan frame


def _near_annotation(frame: np.ndarray, x: np.ndarray, y: np.ndarray, people: Frames,
                     threshold: float) -> np.ndarray:
    """Per track row (its scored frame and position, scan frame): an annotated person of that
    frame lies within ``threshold``."""
    out = np.zeros(frame.size, bool)
    order = np.argsort(people.frame, kind='stable')
    pf = people.frame[order]
    lo, hi = np.searchsorted(pf, frame, 'left'), np.searchsorted(pf, frame, 'right')
    for r in np.flatnonzero(hi > lo):
        rows = order[lo[r]:hi[r]]
        out[r] = (np.hypot(people.x[rows] - x[r], people.y[rows] - y[r]) <= threshold).any()
    return out


def _scan_frames(replay, scans: ScanTimes, tolerance: float, bag, folder, config):
    """Per bag scan, the replay's ego pose (NaN where none), its ego-motion run and the
    scored frame number (-1: not scored)."""
    from laser_tracker.tools.scoring import match_stamps
    from laser_tracker.tools.static_map import ego_segments

    order = np.argsort(replay.ego_stamps, kind='stable')
    ego_stamps, ego_poses = replay.ego_stamps[order], replay.ego_poses[order]
    ego_row = match_stamps(scans.stamps, ego_stamps, tolerance)
    posed = ego_row >= 0
    if not posed.any():
        raise InputFileError(folder, f'no scan of this replay has the header stamp of a scan '
                             f'of {bag} {scans.topic}: was it replayed from that recording?')
    by_stamp = np.argsort(scans.stamps, kind='stable')
    foreign = int((match_stamps(ego_stamps, scans.stamps[by_stamp], tolerance) < 0).sum())
    if foreign:
        log.warning('%d of %d replayed scan(s) have no scan of %s %s with their stamp: '
                    'not scored', foreign, ego_stamps.size, bag, scans.topic)
    poses = np.full((len(scans), 3), np.nan)
    poses[posed] = ego_poses[ego_row[posed]]
    runs = ego_segments(ego_stamps, ego_poses, config.restart_speed, config.restart_gap)
    segment = np.where(posed, runs[np.maximum(ego_row, 0)], -1)
    frame = np.where(posed, np.cumsum(posed) - 1, -1)
    return poses, segment, frame, foreign


def _in_sector(x: np.ndarray, y: np.ndarray, sector) -> np.ndarray:
    """Mask: points of the scan frame whose bearing lies in ``sector`` (degrees)."""
    bearing = np.degrees(np.arctan2(y, x))
    return (bearing >= sector[0]) & (bearing <= sector[1])


def _in_sector_only(ann: Annotations, sector) -> tuple[Annotations, int]:
    """``ann`` within ``sector`` (all for None) and how many positions lie outside it."""
    if sector is None:
        return ann, 0
    seen = _in_sector(ann.x, ann.y, sector)
    return ann.select(seen), int((~seen).sum())


def _hidden_people(bag, scans: ScanTimes, frame: np.ndarray, mirrored: bool, sector
                   ) -> Frames | None:
    """The people out of sight (``HIDDEN_TOPIC``) at the scored frames, in the frame the
    tracks are scored in (``sector`` in that frame); None for a recording without them
    (module docstring)."""
    from laser_tracker.tools.bag import topics

    info = topics(bag).get(HIDDEN_TOPIC)
    if info is None:
        return None
    if not info[1]:
        return Frames.of([], [], [], [])
    hid = read_annotations(bag, HIDDEN_TOPIC, scans)
    hid, _ = _in_sector_only(hid.mirrored() if mirrored else hid, sector)
    hid = hid.select(frame[hid.scan] >= 0)
    return Frames.of(frame[hid.scan], hid.obj_id, hid.x, hid.y)


def evaluate_annotated(replay, bag, config, topic: str = ANNOTATION_TOPIC,
                       scan_topic: str | None = None, persons=None,
                       area=None, sector=None) -> AnnotatedEvaluation:
    """Score a replay (``evaluate.Replay``) against the annotations of ``bag``.

    ``config``: ``scoring.EvaluationConfig`` (threshold, confirmed_only, walking_speed,
    speed_window, stamp_tolerance); ``persons``: annotated ids to score (default all);
    ``area`` (xmin, xmax, ymin, ymax): the box of the scan frame where every person is
    annotated (a recording labelled only there): a track outside it is scored only where it
    lies within the threshold of an annotated person (who may step out of the box), else it
    is ignored (someone walking elsewhere). ``sector`` (least, largest bearing, degrees, scan
    frame): the annotated field of view; annotations and tracks outside it are not scored
    (leg_tracker's benchmark evaluation, ``constrain_to_specific_angle``).
    """
    from laser_tracker.errors import LaserTrackerError
    from laser_tracker.tools.bag import read_scan_times
    from laser_tracker.tools.scoring import match_stamps, median_period

    if sector is not None and not -180.0 <= sector[0] < sector[1] <= 180.0:
        raise LaserTrackerError(f'--sector {sector[0]:g} {sector[1]:g}: the least and the '
                                'largest bearing, degrees from -180 to 180')

    scans = (read_scan_times(bag, scan_topic) if scan_topic
             else choose_scan_topic(bag, replay.ego_stamps))
    offset = float(np.median(scans.stamps - scans.receive_ns * 1e-9)) if len(scans) else 0.0
    if abs(offset) > 1.0:    # reported once, in the table; here for the log only
        log.info('%s: header stamps of %s run %.1f s %s receive times: annotations are '
                 'placed by receive time, scans named by header stamp', bag, scans.topic,
                 abs(offset), 'ahead of' if offset > 0 else 'behind')
    ann = read_annotations(bag, topic, scans)
    mirrored = bool(replay.summary.get('scanner_mount', {}).get('mirrored'))
    if mirrored:
        # an upside-down scanner's replay is in the frame turned right side up
        ann = ann.mirrored()
        area = None if area is None else (area[0], area[1], -area[3], -area[2])
        sector = None if sector is None else (-sector[1], -sector[0])
    placed = len(ann)
    if persons:
        unknown = sorted({int(p) for p in persons} - set(ann.ids()))
        if unknown:
            raise LaserTrackerError(f'{bag}: no annotated person with id '
                                    f'{", ".join(map(str, unknown))} (ids: '
                                    f'{", ".join(map(str, ann.ids()))})')
        ann = ann.select(np.isin(ann.obj_id, list(persons)))
    ann, beside = _in_sector_only(ann, sector)
    tol = config.stamp_tolerance * median_period(scans.stamps)
    poses, segment, frame, foreign = _scan_frames(replay, scans, tol, bag, replay.folder,
                                                  config)
    n_frames = int(frame.max()) + 1
    scored = frame[ann.scan] >= 0
    not_scored = int((~scored).sum())
    if not_scored:
        log.warning('%d of %d annotated position(s) are at scans without an ego-motion pose '
                    'in the replay: not scored', not_scored, len(ann))
    a = ann.select(scored)
    a_pose = poses[a.scan]
    ox, oy = to_frame(a_pose, a.x, a.y)
    vel = annotation_velocities(scans.stamps[a.scan], a.obj_id, ox, oy, config.speed_window,
                                segment[a.scan])
    speed = np.hypot(vel[:, 0], vel[:, 1])
    unknown_speed = ~np.isfinite(speed)
    walking = unknown_speed | (speed >= config.walking_speed)   # unknown: cared about
    people = Frames.of(frame[a.scan], a.obj_id, a.x, a.y)

    t = replay.tracks
    if config.confirmed_only:
        t = t.select(t.confirmed)
    by_stamp = np.argsort(scans.stamps, kind='stable')
    hit = match_stamps(t.stamp, scans.stamps[by_stamp], tol)
    scan_of = np.where(hit >= 0, by_stamp[np.maximum(hit, 0)], -1)
    usable = (scan_of >= 0) & (frame[np.maximum(scan_of, 0)] >= 0)
    if (~usable).any():
        log.warning('%d track row(s) at stamps of no scored scan ignored', int((~usable).sum()))
    t, scan_of = t.select(usable), scan_of[usable]
    tx, ty = from_frame(poses[scan_of], t.x, t.y)
    if sector is not None:
        seen = _in_sector(tx, ty, sector)
        t, scan_of, tx, ty = t.select(seen), scan_of[seen], tx[seen], ty[seen]
    outside = 0
    if area is not None:
        x0, x1, y0, y1 = area
        inside = (tx >= x0) & (tx <= x1) & (ty >= y0) & (ty <= y1)
        inside |= _near_annotation(frame[scan_of], tx, ty, people, config.threshold)
        outside = int(np.unique(t.track_id[~inside]).size)
        t, scan_of, tx, ty = t.select(inside), scan_of[inside], tx[inside], ty[inside]
    tracks = Frames.of(frame[scan_of], t.track_id, tx, ty)

    follow = score_following(n_frames, people, tracks, config.threshold)
    mot, err_all, err_walk, verdicts = score_clear_mot(n_frames, people, walking, tracks,
                                                       config.threshold)
    hidden = _hidden_people(bag, scans, frame, mirrored, sector)
    on_hidden = None
    if hidden is not None:
        fp = verdicts.kind == 'FP'
        on_hidden = int(_near_annotation(verdicts.frame[fp], verdicts.track_xy[fp, 0],
                                         verdicts.track_xy[fp, 1], hidden,
                                         config.threshold).sum())
    fd = follow.as_dict()
    comparable = {'objects': len(ann),
                  'tracked': fd['tracked'], 'id_switches': fd['id_switches'],
                  'misses': fd['misses'] + not_scored}
    result = {
        'mode': 'annotated', 'replay': str(replay.folder), 'bag': str(bag),
        'config': {k: getattr(config, k) for k in (
            'threshold', 'confirmed_only', 'walking_speed', 'speed_window',
            'stamp_tolerance')},
        'annotation_topic': topic, 'scan_topic': scans.topic, 'scan_frame': scans.frame_id,
        'header_minus_receive_s': offset,
        'scans': len(scans), 'frames_scored': n_frames,
        'replayed_scans_not_in_bag': foreign,
        'ego_motion_runs': int(np.unique(segment[segment >= 0]).size),
        'annotations': {**ann.counts, 'placed': placed, 'persons': ann.ids(),
                        'scored': int(scored.sum()), 'not_scored_no_pose': not_scored,
                        'outside_sector': beside,
                        'walking': int((walking & ~unknown_speed).sum()),
                        'standing': int((~walking).sum()),
                        'speed_unknown': int(unknown_speed.sum()),
                        'hidden': None if hidden is None else int(hidden.frame.size)},
        'tracks_scored': int(np.unique(t.track_id).size),
        'area': None if area is None else [float(v) for v in area],
        'sector_deg': None if sector is None else [float(v) for v in sector],
        'tracks_outside_area': outside,
        'following': fd,
        'following_all_annotations': comparable,
        'clear_mot': mot,
        'false_positives_on_hidden': on_hidden,
        'position_error': {'all': error_stats(err_all), 'walking': error_stats(err_walk)},
    }
    return AnnotatedEvaluation(result, np.column_stack((ox, oy)), a.obj_id, walking,
                               poses[frame >= 0], segment[frame >= 0],
                               scans.stamps[frame >= 0], verdicts)
