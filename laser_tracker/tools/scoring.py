"""Scoring a replay against ground truth: CLEAR MOT, the paper's table rows, position errors.

Pure functions on numpy tables (no bag or file access; ``laser_tracker.tools.evaluate`` reads
the files and calls these). The definitions, which the paper leaves open, are:

Frames
    Tracks are estimated in the odometry frame of ego-motion, which drifts from ``map``. Each
    track row is brought into ``map`` at its own scan stamp as
    ``T_true(stamp) (+) inverse(T_est(stamp)) (+) p_odom`` (velocities rotated likewise), with
    ``T_est`` the replay's ego-motion pose and ``T_true`` the platform's true pose. This scores
    the tracker's *local* accuracy (where it puts an object relative to the scanner), not the
    odometry drift, which the ego-motion benchmark measures.

Objects scored
    Every ground-truth object present in a frame (``present``), and the ``detectable`` ones:
    visible (``extra['visible']``, taken as true when absent) and moving at least
    ``min_speed``. A difference-map tracker cannot see an occluded or standing object, so the
    primary CLEAR MOT figures use the detectable objects; a track assigned (Hungarian,
    within the threshold) to a present but undetectable object is then neither a match nor a
    false positive (the MOT16 "distractor" rule). Figures over every present object are
    reported beside them.

Tracks scored
    Confirmed tracks (the tracker's reported moving objects) unless ``confirmed_only`` is off.

Paper rows (a track is *near* an object when within ``threshold`` of it; the nearest present
object is the one it is compared with)
    * constant-velocity paths: each object's trajectory is cut where it disappears (a frame
      without it), stops (speed below ``min_speed``), turns by more than ``turn_deg`` or
      changes speed by more than ``speed_change`` relative to the segment's first velocity.
      Paths shorter than ``min_path_duration`` or invisible throughout are ignored; the rest
      are *taken*; a path is *detected* if a scored track is near the object in one of its
      frames.
    * false detections: a scored track farther than ``threshold`` from every present object;
      each maximal run of consecutive scans of one track is one false detection, its length
      in frames. (A duplicate track on a real object is not a false detection, though CLEAR
      MOT counts it as a false positive.) A run that starts right after the same track was
      near an object is flagged ``after_match``: a real track overshooting (coasting on)
      after its object turned or stopped, rather than a ghost.
    * clearly incorrect hypotheses: scored tracks that, at some scan where they are near an
      object, have a speed differing from the object's by more than ``wrong_speed`` or (both
      moving at least ``min_speed``) a direction differing by more than ``wrong_angle_deg``.
      The *steady* count leaves out scans less than ``settle_time`` after the object changed
      velocity (path start), where any filter still carries the old velocity.
    * passing objects: objects detectable in at least one frame; detected: near a scored
      track in at least one frame.

Position error (Fig. 8)
    The distance between each CLEAR MOT match (detectable objects) and its object; it is
    therefore bounded by the threshold, and MOTP is its mean.

Unlabelled recordings
    :func:`score_unlabelled` counts confirmed tracks and estimates false detections as the
    confirmed tracks that did not move like a walker: their displacement over their
    confirmed life (largest distance from their first confirmed position) is below
    ``min_displacement``, or their mean reported speed while confirmed is below
    ``min_track_speed``. ``laser-tracker evaluate`` prints the same estimate beside the
    measured count on labelled recordings, so the simulated recordings calibrate it.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from laser_tracker.config import param
from laser_tracker.core.geometry import (compose, interpolate_poses, inverse,
                                         pairwise_distances, wrap_angle)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvaluationConfig:
    """Definitions of the evaluation (not the tracker's): thresholds of matching and the rows."""

    threshold: float = param(0.75, 'match distance between a track and an object (m)',
                             min=0.01, max=10.0)
    confirmed_only: bool = param(True, 'score only confirmed tracks (else every hypothesis)')
    min_speed: float = param(0.1, 'an object slower than this is standing (m/s)',
                             min=0.0, max=5.0)
    turn_deg: float = param(30.0, 'a direction change above this starts a new path (deg)',
                            min=1.0, max=180.0)
    speed_change: float = param(0.3, 'a speed change above this starts a new path (m/s)',
                                min=0.01, max=10.0)
    min_path_duration: float = param(1.0, 'paths shorter than this are ignored (s)',
                                     min=0.0, max=60.0)
    wrong_angle_deg: float = param(90.0, 'velocity direction error of a clearly incorrect '
                                   'hypothesis (deg)', min=1.0, max=180.0)
    wrong_speed: float = param(1.0, 'speed error of a clearly incorrect hypothesis (m/s)',
                               min=0.01, max=20.0)
    settle_time: float = param(0.5, 'the steady count of clearly incorrect hypotheses ignores '
                               'scans this soon after the object changed velocity (s)',
                               min=0.0, max=10.0)
    min_displacement: float = param(0.3, 'unlabelled data: a confirmed track that moves less '
                                    'than this over its confirmed life counts as false (m)',
                                    min=0.0, max=10.0)
    min_track_speed: float = param(0.3, 'unlabelled data: a confirmed track whose mean '
                                   'reported speed is below this counts as false (m/s)',
                                   min=0.0, max=5.0)
    stamp_tolerance: float = param(0.25, 'a track row belongs to the scan whose stamp is '
                                   'within this fraction of the median scan period',
                                   min=0.01, max=0.5)
    walking_speed: float = param(0.3, 'annotated recordings: a person slower than this '
                                 '(odometry frame) is "don\'t care" in the walking figures '
                                 '(m/s)', min=0.0, max=5.0)
    speed_window: float = param(1.0, 'annotated recordings: an annotated person\'s speed is '
                                'fitted over this time (s)', min=0.2, max=10.0)
    restart_speed: float = param(3.0, 'real recordings: consecutive ego-motion poses implying a '
                                 'faster motion (m/s, or rad/s of turning) belong to different '
                                 'ego-motion runs (a restart)', min=0.1, max=100.0)
    restart_gap: float = param(1.0, 'real recordings: ego-motion poses further apart in time '
                               '(no pose in between) belong to different runs (s)',
                               min=0.1, max=3600.0)


# ----------------------------------------------------------------------------- tables


@dataclass
class TrackTable:
    """Rows of tracks.csv as columns: one row per hypothesis per scan."""

    stamp: np.ndarray
    track_id: np.ndarray
    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    weight: np.ndarray
    confirmed: np.ndarray

    @classmethod
    def from_rows(cls, rows) -> TrackTable:
        """From ``(stamp, track_id, x, y, vx, vy, weight, confirmed)`` tuples."""
        arr = list(rows)
        cols = list(zip(*arr)) if arr else [()] * 8
        return cls(stamp=np.asarray(cols[0], float), track_id=np.asarray(cols[1], np.int64),
                   x=np.asarray(cols[2], float), y=np.asarray(cols[3], float),
                   vx=np.asarray(cols[4], float), vy=np.asarray(cols[5], float),
                   weight=np.asarray(cols[6], float), confirmed=np.asarray(cols[7], bool))

    def __len__(self) -> int:
        return int(self.stamp.size)

    def select(self, mask) -> TrackTable:
        return TrackTable(**{k: v[mask] for k, v in self.__dict__.items()})


@dataclass
class TruthTable:
    """Ground truth: frame stamps (F,) and one row per object per frame."""

    stamps: np.ndarray
    frame: np.ndarray
    obj_id: np.ndarray
    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    visible: np.ndarray
    kind: np.ndarray

    @classmethod
    def from_frames(cls, frames) -> TruthTable:
        """From ``GroundTruthFrame``-like items (``stamp``, ``objects`` of MovingObject).

        Frames are sorted by stamp; a frame whose stamp is not finite is skipped with a warning.
        """
        good = [f for f in frames if math.isfinite(f.stamp)]
        if len(good) < len(frames):
            log.warning('%d ground-truth frame(s) without a valid stamp skipped',
                        len(frames) - len(good))
        good.sort(key=lambda f: f.stamp)
        rows = []
        for i, f in enumerate(good):
            for o in f.objects:
                extra = o.extra or {}
                rows.append((i, o.id, o.x, o.y, o.vx, o.vy, bool(extra.get('visible', True)),
                             str(extra.get('kind', ''))))
        cols = list(zip(*rows)) if rows else [()] * 8
        return cls(stamps=np.array([f.stamp for f in good], float),
                   frame=np.asarray(cols[0], np.int64), obj_id=np.asarray(cols[1], np.int64),
                   x=np.asarray(cols[2], float), y=np.asarray(cols[3], float),
                   vx=np.asarray(cols[4], float), vy=np.asarray(cols[5], float),
                   visible=np.asarray(cols[6], bool), kind=np.asarray(cols[7], dtype=object))

    def keep_frames(self, keep) -> TruthTable:
        """Only the frames where ``keep`` (F,) is true, renumbered."""
        keep = np.asarray(keep, bool)
        new_index = np.cumsum(keep) - 1
        rows = keep[self.frame] if self.frame.size else np.zeros(0, bool)
        return TruthTable(stamps=self.stamps[keep], frame=new_index[self.frame[rows]],
                          obj_id=self.obj_id[rows], x=self.x[rows], y=self.y[rows],
                          vx=self.vx[rows], vy=self.vy[rows], visible=self.visible[rows],
                          kind=self.kind[rows])

    @property
    def has_visibility(self) -> bool:
        return bool(self.visible.size) and not bool(self.visible.all())


# ------------------------------------------------------------------------------ frames


def median_period(stamps: np.ndarray) -> float:
    d = np.diff(np.unique(np.asarray(stamps, float)))
    return float(np.median(d)) if d.size else 1.0


def match_stamps(query: np.ndarray, stamps: np.ndarray, tolerance: float) -> np.ndarray:
    """Per query stamp, the index of the nearest of sorted ``stamps``; -1 if beyond tolerance."""
    query = np.asarray(query, float)
    stamps = np.asarray(stamps, float)
    if stamps.size == 0:
        return np.full(query.shape, -1, np.int64)
    right = np.clip(np.searchsorted(stamps, query), 0, stamps.size - 1)
    left = np.clip(right - 1, 0, stamps.size - 1)
    pick = np.where(np.abs(stamps[left] - query) <= np.abs(stamps[right] - query), left, right)
    ok = np.abs(stamps[pick] - query) <= tolerance
    return np.where(ok, pick, -1).astype(np.int64)


def tracks_to_map(tracks: TrackTable, ego_stamps, ego_poses, true_stamps, true_poses,
                  tolerance: float) -> TrackTable:
    """Tracks from the estimated odometry frame into the true ``map`` frame, scan by scan.

    Each row at stamp s: ``T_true(s) (+) inverse(T_est(s)) (+) p``; velocities are rotated by
    the same correction. ``T_est(s)`` is the ego-motion row of that scan (a row without one is
    dropped with a warning); ``T_true(s)`` is interpolated from the platform truth.
    """
    order = np.argsort(ego_stamps, kind='stable')
    ego_stamps = np.asarray(ego_stamps, float)[order]
    ego_poses = np.asarray(ego_poses, float).reshape(-1, 3)[order]
    idx = match_stamps(tracks.stamp, ego_stamps, tolerance)
    if (idx < 0).any():
        log.warning('%d track row(s) at stamps with no ego-motion row dropped',
                    int((idx < 0).sum()))
    tracks = tracks.select(idx >= 0)
    idx = idx[idx >= 0]
    if len(tracks) == 0:
        return tracks
    true_stamps = np.asarray(true_stamps, float)
    lo, hi = true_stamps.min(), true_stamps.max()
    outside = (ego_stamps < lo - tolerance) | (ego_stamps > hi + tolerance)
    if outside.any():
        log.warning('%d scan(s) outside the platform truth [%.3f, %.3f] s: its end pose used',
                    int(outside.sum()), lo, hi)
    t_true = interpolate_poses(true_stamps, true_poses, ego_stamps)
    corr = np.array([compose(tt, inverse(te)) for tt, te in zip(t_true, ego_poses)])
    c = corr[idx]
    cos, sin = np.cos(c[:, 2]), np.sin(c[:, 2])
    out = TrackTable(**{k: v.copy() for k, v in tracks.__dict__.items()})
    out.x = cos * tracks.x - sin * tracks.y + c[:, 0]
    out.y = sin * tracks.x + cos * tracks.y + c[:, 1]
    out.vx = cos * tracks.vx - sin * tracks.vy
    out.vy = sin * tracks.vx + cos * tracks.vy
    return out


# ------------------------------------------------------------------------------ scoring


@dataclass
class Path:
    """A constant-velocity segment of one object's trajectory."""

    obj_id: int
    kind: str
    first_frame: int
    last_frame: int
    start: float
    end: float
    speed: float
    heading_deg: float
    visible: bool
    detected: bool = False

    @property
    def duration(self) -> float:
        return self.end - self.start


@dataclass
class FalseDetection:
    track_id: int
    start: float
    frames: int
    after_match: bool = False  # the same track was on an object the scan before (overshoot)


@dataclass
class Scores:
    """Everything :func:`score` measures; ``as_dict`` is the JSON form."""

    config: EvaluationConfig
    frames: int
    clear_mot: dict[str, dict]
    paths: list[Path]
    false_detections: list[FalseDetection]
    incorrect_tracks: list[int]
    incorrect_rows: int
    incorrect_list: list[dict]
    incorrect_steady: list[int]
    objects_passing: int
    objects_detected: int
    tracks_scored: int
    errors: np.ndarray
    unlabelled: dict = field(default_factory=dict)
    verdicts: FrameVerdicts | None = None    # CLEAR MOT over the detectable objects, per frame

    def is_taken(self, path: Path) -> bool:
        return path.visible and path.duration >= self.config.min_path_duration - 1e-9

    @property
    def paths_taken(self) -> list[Path]:
        return [p for p in self.paths if self.is_taken(p)]

    def error_stats(self) -> dict:
        e = self.errors
        if e.size == 0:
            return {'count': 0, 'median': None, 'mean': None, 'p95': None,
                    'within_0_2m': None}
        return {'count': int(e.size), 'median': float(np.median(e)), 'mean': float(e.mean()),
                'p95': float(np.percentile(e, 95)), 'max': float(e.max()),
                'within_0_2m': float((e <= 0.2).mean())}

    def as_dict(self) -> dict:
        taken = self.paths_taken
        lengths = [f.frames for f in self.false_detections]
        return {
            'frames': self.frames,
            'tracks_scored': self.tracks_scored,
            'clear_mot': self.clear_mot,
            'paths_taken': len(taken),
            'paths_detected': sum(p.detected for p in taken),
            'paths': [{'object': p.obj_id, 'kind': p.kind, 'start': round(p.start, 3),
                       'end': round(p.end, 3), 'frames': p.last_frame - p.first_frame + 1,
                       'speed': round(p.speed, 3), 'heading_deg': round(p.heading_deg, 1),
                       'taken': self.is_taken(p), 'detected': p.detected} for p in self.paths],
            'false_detections': len(self.false_detections),
            'false_detection_frames': lengths,
            'false_detection_max_frames': max(lengths, default=0),
            'false_detections_after_match': sum(f.after_match for f in self.false_detections),
            'false_detection_list': [{'track': f.track_id, 'start': round(f.start, 3),
                                      'frames': f.frames, 'after_match': f.after_match}
                                     for f in self.false_detections],
            'incorrect_hypotheses': len(self.incorrect_tracks),
            'incorrect_hypothesis_ids': self.incorrect_tracks,
            'incorrect_rows': self.incorrect_rows,
            'incorrect_hypotheses_steady': len(self.incorrect_steady),
            'incorrect_list': self.incorrect_list[:200],
            'objects_passing': self.objects_passing,
            'objects_detected': self.objects_detected,
            'position_error': self.error_stats(),
            'unlabelled_estimate': self.unlabelled,
        }


MOT_METRICS = ['mota', 'motp', 'num_switches', 'num_false_positives', 'num_misses',
               'num_matches', 'num_objects', 'precision', 'recall']


def _assign(d: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """Minimum-distance one-to-one pairs within the threshold."""
    if d.size == 0:
        return []
    cost = np.where(d <= threshold, d, 1e6)
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols) if d[r, c] <= threshold]


def _group(frame: np.ndarray, n: int) -> list[np.ndarray]:
    order = np.argsort(frame, kind='stable')
    bounds = np.searchsorted(frame[order], np.arange(n + 1))
    return [order[bounds[i]:bounds[i + 1]] for i in range(n)]


def _mot_summary(acc, name: str) -> dict:
    import motmetrics as mm

    summary = mm.metrics.create().compute(acc, metrics=MOT_METRICS, name=name)
    row = summary.loc[name]
    out = {}
    for k in MOT_METRICS:
        v = float(row[k])  # MOTA is -inf, precision/recall nan, with nothing to count
        out[k] = int(v) if k.startswith('num_') else (v if math.isfinite(v) else None)
    return out


@dataclass
class FrameVerdicts:
    """CLEAR MOT's verdicts frame by frame, as motmetrics logged them: one row per ``kind``
    ``MATCH``, ``SWITCH`` (a match whose track changed object), ``MISS`` or ``FP``, with its
    ``frame``, ``obj_id`` and ``track_id`` (-1 where none) and the positions ``obj_xy`` and
    ``track_xy`` (K, 2; NaN where none) in the frame the matching was done in."""

    frame: np.ndarray
    kind: np.ndarray
    obj_id: np.ndarray
    track_id: np.ndarray
    obj_xy: np.ndarray
    track_xy: np.ndarray

    def __len__(self) -> int:
        return int(self.frame.size)


VERDICT_KINDS = ('MATCH', 'SWITCH', 'MISS', 'FP')


def frame_verdicts(acc, objects, tracks) -> FrameVerdicts:
    """The verdicts of a motmetrics accumulator; ``objects`` and ``tracks`` are the rows it
    was fed, ``(frame (N,), id (N,), xy (N, 2))``, to look the positions up."""
    ev = acc.mot_events
    ev = ev[ev['Type'].isin(VERDICT_KINDS)]
    frame = ev.index.get_level_values(0).to_numpy(np.int64)
    ids = [np.nan_to_num(ev[c].to_numpy(float), nan=-1).astype(np.int64)
           for c in ('OId', 'HId')]

    def positions(rows, wanted):
        row_frame, row_id, xy = (np.asarray(v) for v in rows)
        at = {(int(f), int(i)): k for k, (f, i) in enumerate(zip(row_frame, row_id))}
        out = np.full((frame.size, 2), np.nan)
        for k, (f, i) in enumerate(zip(frame, wanted)):
            r = at.get((int(f), int(i)))
            if r is not None:
                out[k] = xy[r]
        return out

    return FrameVerdicts(frame, ev['Type'].to_numpy(str), ids[0], ids[1],
                         positions(objects, ids[0]), positions(tracks, ids[1]))


def _runs(frames: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of consecutive integers in sorted ``frames``: (first, length)."""
    if frames.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(frames) != 1) + 1
    starts = np.concatenate(([0], breaks))
    ends = np.concatenate((breaks, [frames.size]))
    return [(int(frames[s]), int(e - s)) for s, e in zip(starts, ends)]


def _regimes(truth: TruthTable, config: EvaluationConfig):
    """Yield ``(object id, truth rows, moving)``: each object's trajectory cut into paths
    (moving) and standing runs; a frame without the object ends either."""
    turn = math.radians(config.turn_deg)
    for oid in np.unique(truth.obj_id):
        rows = np.flatnonzero(truth.obj_id == oid)
        rows = rows[np.argsort(truth.frame[rows], kind='stable')]
        frames = truth.frame[rows]
        speed = np.hypot(truth.vx[rows], truth.vy[rows])
        heading = np.arctan2(truth.vy[rows], truth.vx[rows])
        moving = speed >= config.min_speed
        i = 0
        while i < rows.size:
            j = i + 1
            while j < rows.size and frames[j] == frames[j - 1] + 1 and moving[j] == moving[i]:
                if moving[i] and (abs(speed[j] - speed[i]) > config.speed_change
                                  or abs(float(wrap_angle(heading[j] - heading[i]))) > turn):
                    break
                j += 1
            yield int(oid), rows[i:j], bool(moving[i])
            i = j


def segment_paths(truth: TruthTable, config: EvaluationConfig) -> list[Path]:
    """Cut every object's trajectory into constant-velocity paths (module docstring)."""
    paths = []
    for oid, seg, moving in _regimes(truth, config):
        if not moving:
            continue
        speed = np.hypot(truth.vx[seg], truth.vy[seg])
        paths.append(Path(
            obj_id=oid, kind=str(truth.kind[seg[0]]),
            first_frame=int(truth.frame[seg[0]]), last_frame=int(truth.frame[seg[-1]]),
            start=float(truth.stamps[truth.frame[seg[0]]]),
            end=float(truth.stamps[truth.frame[seg[-1]]]),
            speed=float(speed.mean()),
            heading_deg=math.degrees(math.atan2(truth.vy[seg].mean(), truth.vx[seg].mean())),
            visible=bool(truth.visible[seg].any())))
    return paths


def regime_start(truth: TruthTable, config: EvaluationConfig) -> np.ndarray:
    """Per truth row, the stamp at which the object's current path or standing run began."""
    start = np.zeros(truth.obj_id.size)
    for _, seg, _ in _regimes(truth, config):
        start[seg] = truth.stamps[truth.frame[seg[0]]]
    return start


def score(truth: TruthTable, tracks: TrackTable,
          config: EvaluationConfig = EvaluationConfig()) -> Scores:
    """Score ``tracks`` (already in the truth's frame) against ``truth``, frame by frame.

    Each track row is assigned to the ground-truth frame with the nearest stamp (within
    ``stamp_tolerance`` of the median scan period); rows with none are dropped with a warning.
    A frame with no track rows is a frame in which nothing was reported.
    """
    import motmetrics as mm

    n = truth.stamps.size
    tol = config.stamp_tolerance * median_period(truth.stamps)
    scored = tracks.select(tracks.confirmed) if config.confirmed_only else tracks
    tframe = match_stamps(scored.stamp, truth.stamps, tol)
    if (tframe < 0).any():
        log.warning('%d track row(s) match no ground-truth frame (stamp off by more than '
                    '%.3f s) and are ignored', int((tframe < 0).sum()), tol)
    scored = scored.select(tframe >= 0)
    tframe = tframe[tframe >= 0]

    thr = config.threshold
    detectable = truth.visible & (np.hypot(truth.vx, truth.vy) >= config.min_speed)
    acc_det = mm.MOTAccumulator(auto_id=False)
    acc_all = mm.MOTAccumulator(auto_id=False)
    obj_groups, trk_groups = _group(truth.frame, n), _group(tframe, n)

    near_obj = np.full(len(scored), -1, np.int64)  # truth row nearest each track row (in thr)
    detected_in = set()  # (obj_id, frame)
    for f in range(n):
        orows, trows = obj_groups[f], trk_groups[f]
        oxy = np.column_stack((truth.x[orows], truth.y[orows]))
        txy = np.column_stack((scored.x[trows], scored.y[trows]))
        d = pairwise_distances(oxy, txy)
        oids, tids = truth.obj_id[orows], scored.track_id[trows]
        dm = np.where(d <= thr, d, np.nan)
        acc_all.update(oids.tolist(), tids.tolist(), dm, frameid=f)
        care = detectable[orows]
        drop = np.zeros(trows.size, bool)
        for r, c in _assign(d, thr):
            if not care[r]:
                drop[c] = True
        acc_det.update(oids[care].tolist(), tids[~drop].tolist(), dm[care][:, ~drop],
                       frameid=f)
        if d.size:
            k = np.argmin(d, axis=0)
            ok = d[k, np.arange(trows.size)] <= thr
            near_obj[trows[ok]] = orows[k[ok]]
            detected_in.update((int(o), f) for o in oids[k[ok]])

    clear_mot = {'detectable': _mot_summary(acc_det, 'detectable'),
                 'present': _mot_summary(acc_all, 'present')}
    verdicts = frame_verdicts(acc_det,
                              (truth.frame, truth.obj_id, np.column_stack((truth.x, truth.y))),
                              (tframe, scored.track_id, np.column_stack((scored.x, scored.y))))
    ev = acc_det.mot_events
    errors = ev.loc[ev['Type'].isin(['MATCH', 'SWITCH']), 'D'].to_numpy(float)

    paths = segment_paths(truth, config)
    for p in paths:
        p.detected = any((p.obj_id, f) in detected_in
                         for f in range(p.first_frame, p.last_frame + 1))

    false = []
    unmatched = near_obj < 0
    for tid in np.unique(scored.track_id):
        mine = scored.track_id == tid
        matched_frames = set(tframe[mine & ~unmatched].tolist())
        frames = np.sort(tframe[mine & unmatched])
        for first, length in _runs(frames):
            false.append(FalseDetection(int(tid), float(truth.stamps[first]), length,
                                        after_match=(first - 1) in matched_frames))
    false.sort(key=lambda f: (f.start, f.track_id))

    m = near_obj >= 0
    o = near_obj[m]
    tv = np.column_stack((scored.vx[m], scored.vy[m]))
    ov = np.column_stack((truth.vx[o], truth.vy[o]))
    ts, os_ = np.linalg.norm(tv, axis=1), np.linalg.norm(ov, axis=1)
    angle = np.abs(wrap_angle(np.arctan2(tv[:, 1], tv[:, 0]) - np.arctan2(ov[:, 1], ov[:, 0])))
    wrong = (np.abs(ts - os_) > config.wrong_speed) | (
        (ts >= config.min_speed) & (os_ >= config.min_speed)
        & (angle > math.radians(config.wrong_angle_deg)))
    incorrect = sorted({int(t) for t in scored.track_id[m][wrong]})
    since_change = truth.stamps[truth.frame[o]] - regime_start(truth, config)[o]
    steady = since_change >= config.settle_time - 1e-9
    incorrect_steady = sorted({int(t) for t in scored.track_id[m][wrong & steady]})
    incorrect_list = []
    rows_m = np.flatnonzero(m)
    for k in np.flatnonzero(wrong):  # the offending rows, for the reader to check
        r = rows_m[k]
        incorrect_list.append({
            'track': int(scored.track_id[r]), 'stamp': round(float(scored.stamp[r]), 3),
            'object': int(truth.obj_id[o[k]]),
            'track_velocity': [round(float(tv[k, 0]), 3), round(float(tv[k, 1]), 3)],
            'object_velocity': [round(float(ov[k, 0]), 3), round(float(ov[k, 1]), 3)],
            'angle_deg': round(math.degrees(float(angle[k])), 1),
            'since_velocity_change_s': round(float(since_change[k]), 3)})

    passing = {int(i) for i in truth.obj_id[detectable]}
    detected = {o for o, _ in detected_in} & passing

    return Scores(config=config, frames=n, clear_mot=clear_mot, paths=paths,
                  false_detections=false, incorrect_tracks=incorrect,
                  incorrect_rows=int(wrong.sum()), incorrect_list=incorrect_list,
                  incorrect_steady=incorrect_steady,
                  objects_passing=len(passing),
                  objects_detected=len(detected),
                  tracks_scored=int(np.unique(scored.track_id).size), errors=errors,
                  verdicts=verdicts)


# --------------------------------------------------------------------------- unlabelled


def confirmed_track_lives(tracks: TrackTable) -> list[dict]:
    """Per confirmed track: first stamp, confirmed rows, displacement over its confirmed life."""
    conf = tracks.select(tracks.confirmed)
    lives = []
    for tid in np.unique(conf.track_id):
        rows = np.flatnonzero(conf.track_id == tid)
        rows = rows[np.argsort(conf.stamp[rows], kind='stable')]
        dx, dy = conf.x[rows] - conf.x[rows[0]], conf.y[rows] - conf.y[rows[0]]
        lives.append({'track': int(tid), 'start': float(conf.stamp[rows[0]]),
                      'end': float(conf.stamp[rows[-1]]), 'frames': int(rows.size),
                      'displacement': float(np.hypot(dx, dy).max()),
                      'mean_speed': float(np.hypot(conf.vx[rows], conf.vy[rows]).mean())})
    return lives


def score_unlabelled(tracks: TrackTable, scan_stamps: np.ndarray,
                     config: EvaluationConfig = EvaluationConfig()) -> dict:
    """Confirmed tracks per minute and the estimated false detections per minute.

    The estimate counts confirmed tracks whose displacement over their confirmed life is below
    ``config.min_displacement`` or whose mean speed is below ``config.min_track_speed`` (a
    walker goes somewhere at walking pace; clutter that flickers into a track mostly does
    not). The duration is that of the scans, one median period added for the last.
    """
    scan_stamps = np.unique(np.asarray(scan_stamps, float))
    duration = (float(scan_stamps[-1] - scan_stamps[0]) + median_period(scan_stamps)
                if scan_stamps.size else 0.0)
    minutes = duration / 60.0
    lives = confirmed_track_lives(tracks)
    for life in lives:
        life['estimated_false'] = bool(life['displacement'] < config.min_displacement
                                       or life['mean_speed'] < config.min_track_speed)
    false = [life for life in lives if life['estimated_false']]
    frames = np.array([life['frames'] for life in lives], float)

    def per_minute(k):
        return k / minutes if minutes > 0 else None

    return {
        'scans': int(scan_stamps.size),
        'duration_s': duration,
        'hypotheses': int(np.unique(tracks.track_id).size),
        'confirmed_tracks': len(lives),
        'confirmed_per_minute': per_minute(len(lives)),
        'estimated_false': len(false),
        'estimated_false_per_minute': per_minute(len(false)),
        'min_displacement': config.min_displacement,
        'min_track_speed': config.min_track_speed,
        'confirmed_frames_histogram': {
            label: int(((frames >= lo) & (frames <= hi)).sum())
            for label, lo, hi in (('1', 1, 1), ('2', 2, 2), ('3-5', 3, 5), ('6-10', 6, 10),
                                  ('11-30', 11, 30), ('>30', 31, np.inf))},
        'confirmed_frames_median': float(np.median(frames)) if frames.size else None,
        'confirmed_frames_max': int(frames.max()) if frames.size else None,
        'tracks': lives,
    }
