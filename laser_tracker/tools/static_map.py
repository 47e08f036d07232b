"""Static structure seen by a recording, and the confirmed tracks that lie on it.

A track of a laser tracker that sits on a wall, a pillar or a cupboard is a false detection:
the object never moved. With scans placed at good poses, static structure is what the scans
keep hitting. Definitions (:class:`StaticMapConfig` holds every number):

Static cells
    The scans are placed at their poses on a grid of ``resolution`` metres. A scan *observes*
    the cells its beams cross (up to one cell short of the return, or ``max_range`` for a beam
    without return) and the cell of each return (returns beyond ``max_range`` are left out),
    and *hits* the cells of its returns. A cell is static when at least ``min_observations``
    scans observed it and at least ``static_share`` (30 %) of them hit it: the floor a person
    walked over is hit by a few of the many scans that see it. Why not "most" (50 %): a wall
    seen at a grazing angle is crossed by many beams that end further along it, so its 0.1 m
    cells are hit by fewer than half of the scans observing them; on freiburg-079 part 1, 9 %
    of all returns (nearly all on walls) fall off a 50 % map, 1.3 % off the 30 % map.

Reference poses (``mode='reference'``, a log whose poses were corrected by SLAM)
    The scans are placed at the reference poses (``/ground_truth/platform``) and all of the
    recording counts. A track position (odometry frame of the replay, scan ``s``) is brought
    into the reference frame as ``T_ref(s) (+) inverse(T_ego(s)) (+) p``: the replay's
    ego-motion frame may start anywhere and drift; this places the track where the replay saw
    it relative to the scanner, so ego-motion errors do not move tracks off the structure.

Ego poses (``mode='ego'``, a raw log without reference)
    The scans are placed at the replay's own ego-motion poses, and only the scans within
    ``window`` seconds before the track's first or after its last confirmed scan count (the
    ego-motion drifts over long times; in a short window it is locally consistent). Time is
    cut where the ego-motion restarted (:func:`ego_segments`), and a window never crosses a
    cut.

False tracks
    A confirmed track is false when at least ``false_share`` of its confirmed positions lie
    on a static cell or within ``near`` metres of one (the centroid of a blob on a corner lies
    off both walls). Of the others, a track is *unsupported* when at least ``false_share`` of
    its confirmed positions have no return of their own scan within ``support`` metres
    (judged in the scan's frame, no poses needed): a ghost in free space (a person always
    returns points); the rest are *moving*, plausibly real. Only the static ones are counted
    as false per minute; the unsupported are reported beside them.

A person who stands still during all the time a place is observed is static structure by
this rule; with reference poses the place is also observed when the robot passes before or
after, which makes a briefly standing person free space again. A track on someone standing
still is not what a moving-object tracker should report anyway, so counting it as false is
the intended reading; the list of false tracks gives the time and place to check.
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param

log = logging.getLogger(__name__)

_SHIFT = np.int64(1 << 24)   # cell indices within +-2^24 (1,677 km at 0.1 m): keys < 2^50


@dataclass(frozen=True)
class StaticMapConfig:
    """Definitions of static structure and of a false track on it."""

    resolution: float = param(0.1, 'cell size of the static map (m)', min=0.02, max=1.0)
    max_range: float = param(20.0, 'beams are used up to this range for the map (m)',
                             min=1.0, max=100.0)
    min_observations: int = param(3, 'a cell needs this many observing scans to be judged',
                                  min=1, max=1000)
    static_share: float = param(0.3, 'a cell is static when hit by at least this share of '
                                'the scans that observed it', min=0.05, max=1.0)
    near: float = param(0.15, 'a position within this distance of a static cell is on '
                        'structure (m)', min=0.0, max=2.0)
    false_share: float = param(0.5, 'a confirmed track is false when at least this share of '
                               'its confirmed positions is on structure', min=0.01, max=1.0)
    support: float = param(0.3, 'a confirmed position is supported when a return of its own '
                           'scan lies within this distance (m)', min=0.01, max=5.0)
    window: float = param(30.0, 'ego poses: scans within this time before and after a track '
                          'build its map (s)', min=1.0, max=3600.0)
    block: float = param(5.0, 'scans are accumulated in blocks of this duration (s)',
                         min=0.5, max=600.0)


@dataclass
class _Block:
    segment: int
    start: float
    end: float
    keys: np.ndarray      # sorted cell keys
    hits: np.ndarray
    observed: np.ndarray


def _keys(ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    return (ix.astype(np.int64) + _SHIFT) * (2 * _SHIFT) + (iy.astype(np.int64) + _SHIFT)


def scan_cells(pose, angles: np.ndarray, ranges: np.ndarray, range_max: float,
               config: StaticMapConfig) -> tuple[np.ndarray, np.ndarray]:
    """(hit keys, observed keys) of one scan at ``pose``, each unique."""
    res, cap = config.resolution, config.max_range
    r = np.asarray(ranges, float)
    with np.errstate(invalid='ignore'):
        ret = np.isfinite(r) & (r > 1e-6) & (r < range_max) & (r <= cap)
        no_return = np.isposinf(r) | (np.isfinite(r) & (r >= range_max))
    free = np.zeros_like(r)
    free[ret] = r[ret] - res
    free[no_return] = cap
    with np.errstate(invalid='ignore'):
        far = np.isfinite(r) & (r > cap) & (r < range_max)   # a return beyond the cap
    free[far] = cap
    x, y, t = pose
    a = np.asarray(angles, float) + t
    c, s = np.cos(a), np.sin(a)
    steps = np.arange(res / 2.0, cap, res)
    m = steps[None, :] < free[:, None]
    d = np.broadcast_to(steps, m.shape)[m]
    cc = np.broadcast_to(c[:, None], m.shape)[m]
    ss = np.broadcast_to(s[:, None], m.shape)[m]
    fx = np.floor((x + d * cc) / res)
    fy = np.floor((y + d * ss) / res)
    hx = np.floor((x + r[ret] * c[ret]) / res)
    hy = np.floor((y + r[ret] * s[ret]) / res)
    hits = np.unique(_keys(hx, hy))
    observed = np.unique(np.concatenate((_keys(fx, fy), hits)))
    return hits, observed


class StaticMap:
    """Hit and observation counts of scans in time blocks; static cells by query."""

    def __init__(self, config: StaticMapConfig = StaticMapConfig()):
        self.config = config
        self.blocks: list[_Block] = []
        self.scans = 0

    @classmethod
    def build(cls, scans: Iterable, poses: np.ndarray, segments: np.ndarray | None = None,
              config: StaticMapConfig = StaticMapConfig()) -> StaticMap:
        """From ``scans`` (core Scan objects, in time order) at ``poses`` (N, 3, map frame);
        a scan whose pose is NaN is left out. ``segments`` (N,) cuts time (ego jumps)."""
        self = cls(config)
        poses = np.asarray(poses, float).reshape(-1, 3)
        seg = np.zeros(len(poses), np.int64) if segments is None else np.asarray(segments)
        pending: list[tuple[np.ndarray, np.ndarray]] = []
        current = None   # (segment, block start, last stamp)
        for k, scan in enumerate(scans):
            if k >= len(poses):
                break
            pose = poses[k]
            if not np.all(np.isfinite(pose)):
                continue
            t = float(scan.stamp)
            if current is None or seg[k] != current[0] or t - current[1] >= config.block:
                self._flush(pending, current)
                pending, current = [], [int(seg[k]), t, t]
            hits, observed = scan_cells(pose, scan.angles, scan.ranges, scan.range_max,
                                        config)
            pending.append((hits, observed))
            current[2] = t
            self.scans += 1
        self._flush(pending, current)
        return self

    def _flush(self, pending, current) -> None:
        if not pending:
            return
        hits = np.concatenate([h for h, _ in pending])
        observed = np.concatenate([o for _, o in pending])
        keys, obs = np.unique(observed, return_counts=True)
        hk, hc = np.unique(hits, return_counts=True)
        h = np.zeros(keys.size, np.int64)
        h[np.searchsorted(keys, hk)] = hc
        self.blocks.append(_Block(current[0], current[1], current[2], keys, h,
                                  obs.astype(np.int64)))

    def counts(self, keys: np.ndarray, start: float = -np.inf, end: float = np.inf,
               segment: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(hits, observed) of cells ``keys`` over the blocks overlapping [start, end]."""
        hits = np.zeros(keys.size, np.int64)
        observed = np.zeros(keys.size, np.int64)
        for b in self.blocks:
            if b.end < start or b.start > end or (segment is not None and b.segment != segment):
                continue
            i = np.clip(np.searchsorted(b.keys, keys), 0, b.keys.size - 1)
            found = b.keys[i] == keys
            hits[found] += b.hits[i[found]]
            observed[found] += b.observed[i[found]]
        return hits, observed

    def on_structure(self, xy: np.ndarray, start: float = -np.inf, end: float = np.inf,
                     segment: int | None = None) -> np.ndarray:
        """(P,) bool: positions ``xy`` (P, 2) on a static cell or within ``near`` of one."""
        c = self.config
        xy = np.asarray(xy, float).reshape(-1, 2)
        if xy.shape[0] == 0:
            return np.zeros(0, bool)
        reach = int(np.ceil(c.near / c.resolution))
        off = np.arange(-reach, reach + 1)
        ox, oy = np.meshgrid(off, off, indexing='ij')
        # cells whose nearest point is within `near` of the position's cell centre
        gap = np.maximum(np.abs(ox) - 0.5, 0) ** 2 + np.maximum(np.abs(oy) - 0.5, 0) ** 2
        sel = gap * c.resolution ** 2 <= c.near ** 2 + 1e-12
        ox, oy = ox[sel], oy[sel]
        cx = np.floor(xy[:, 0] / c.resolution).astype(np.int64)
        cy = np.floor(xy[:, 1] / c.resolution).astype(np.int64)
        keys = _keys(cx[:, None] + ox[None, :], cy[:, None] + oy[None, :])
        uniq, inverse = np.unique(keys, return_inverse=True)
        hits, observed = self.counts(uniq, start, end, segment)
        static = (observed >= c.min_observations) & (hits >= c.static_share * observed)
        return static[inverse.reshape(keys.shape)].any(axis=1)

    def static_cells(self, start: float = -np.inf, end: float = np.inf,
                     segment: int | None = None) -> np.ndarray:
        """(K, 2) centres of the static cells over the blocks in [start, end] (figures)."""
        c = self.config
        blocks = [b for b in self.blocks if not (b.end < start or b.start > end or (
            segment is not None and b.segment != segment))]
        if not blocks:
            return np.zeros((0, 2))
        keys = np.concatenate([b.keys for b in blocks])
        hits = np.concatenate([b.hits for b in blocks])
        obs = np.concatenate([b.observed for b in blocks])
        uniq, inverse = np.unique(keys, return_inverse=True)
        h = np.bincount(inverse, hits, uniq.size)
        o = np.bincount(inverse, obs, uniq.size)
        static = uniq[(o >= c.min_observations) & (h >= c.static_share * o)]
        ix = static // (2 * _SHIFT) - _SHIFT
        iy = static % (2 * _SHIFT) - _SHIFT
        return np.column_stack(((ix + 0.5) * c.resolution, (iy + 0.5) * c.resolution))


def ego_segments(stamps: np.ndarray, poses: np.ndarray, restart_speed: float = 3.0,
                 restart_gap: float = 1.0) -> np.ndarray:
    """(N,) run number of each ego-motion pose (sorted by stamp). Ego-motion restarts after
    losing track, at the odometry pose or, without odometry, at the origin: poses of
    different runs are in different frames. A new run starts at a pose exactly at the origin
    (a restart without odometry), where the step from the previous pose implies more than
    ``restart_speed`` (m/s, or rad/s of turning), or where no pose was given for
    ``restart_gap`` s."""
    from laser_tracker.core.geometry import wrap_angle

    stamps = np.asarray(stamps, float)
    poses = np.asarray(poses, float).reshape(-1, 3)
    if poses.shape[0] == 0:
        return np.zeros(0, np.int64)
    dt = np.diff(stamps)
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    turn = np.abs(wrap_angle(np.diff(poses[:, 2])))
    with np.errstate(divide='ignore', invalid='ignore'):
        cut = ~((dt <= restart_gap) & (step <= restart_speed * dt)
                & (turn <= restart_speed * dt))
    cut |= np.all(poses[1:] == 0.0, axis=1)
    return np.concatenate(([0], np.cumsum(cut))).astype(np.int64)


@dataclass
class TrackVerdict:
    """One confirmed track judged against the static map (``kind``: ``static`` = false,
    ``unsupported`` = mostly no return of its scans near it, ``moving`` = the rest)."""

    track: int
    start: float
    end: float
    positions: int
    on_structure: int
    supported: int
    x: float               # median confirmed position, map frame
    y: float
    kind: str

    @property
    def false(self) -> bool:
        return self.kind == 'static'

    def as_dict(self, t0: float) -> dict:
        return {'track': self.track, 'start': round(self.start, 3),
                'time_s': round(float(self.start - t0), 1), 'end': round(self.end, 3),
                'positions': self.positions, 'on_structure': self.on_structure,
                'supported': self.supported, 'x': round(self.x, 2), 'y': round(self.y, 2),
                'kind': self.kind}


def judge_tracks(static: StaticMap, stamp: np.ndarray, track_id: np.ndarray, xy: np.ndarray,
                 segment: np.ndarray | None = None, windowed: bool = False,
                 supported: np.ndarray | None = None) -> list[TrackVerdict]:
    """Judge each track (rows ``stamp``, ``track_id``, ``xy`` in the map's frame, confirmed
    positions only). ``windowed``: only the scans within ``config.window`` of the track's
    confirmed life, in the ``segment`` of its first row, count. ``supported`` (R,): rows with
    a return of their scan nearby (default: all)."""
    c = static.config
    supported = np.ones(stamp.size, bool) if supported is None else np.asarray(supported, bool)
    out = []
    for tid in np.unique(track_id):
        rows = np.flatnonzero(track_id == tid)
        rows = rows[np.argsort(stamp[rows], kind='stable')]
        t0, t1 = float(stamp[rows[0]]), float(stamp[rows[-1]])
        if windowed:
            seg = None if segment is None else int(segment[rows[0]])
            on = static.on_structure(xy[rows], t0 - c.window, t1 + c.window, seg)
        else:
            on = static.on_structure(xy[rows])
        n_on, n_sup = int(on.sum()), int(supported[rows].sum())
        need = c.false_share * rows.size - 1e-9
        kind = ('static' if n_on >= need else
                'unsupported' if rows.size - n_sup >= need else 'moving')
        med = np.median(xy[rows], axis=0)
        out.append(TrackVerdict(int(tid), t0, t1, int(rows.size), n_on, n_sup, float(med[0]),
                                float(med[1]), kind))
    return out


def supported_rows(scans: list, scan_of_row: np.ndarray, x: np.ndarray, y: np.ndarray,
                   distance: float) -> np.ndarray:
    """(R,) bool: a return of scan ``scans[scan_of_row[r]]`` lies within ``distance`` of the
    row's position ``x, y`` given in that scan's frame."""
    out = np.zeros(scan_of_row.size, bool)
    for k in np.unique(scan_of_row):
        rows = np.flatnonzero(scan_of_row == k)
        pts = scans[int(k)].points()
        if pts.shape[0] == 0:
            continue
        d = np.hypot(pts[None, :, 0] - x[rows, None], pts[None, :, 1] - y[rows, None])
        out[rows] = d.min(axis=1) <= distance
    return out


# ------------------------------------------------------------------------------ evaluation


@dataclass
class StaticEvaluation:
    """The result of :func:`evaluate_static`: JSON dict plus what the figure needs."""

    result: dict
    static: StaticMap
    track_xy: np.ndarray          # (R, 2) confirmed track rows in the map frame
    track_id: np.ndarray
    track_stamp: np.ndarray
    scanner: np.ndarray           # (S, 3) scanner poses in the map frame
    verdicts: list


def evaluate_static(replay, bag, mode: str = 'reference', scan_topic: str | None = None,
                    config: StaticMapConfig = StaticMapConfig(),
                    evaluation=None) -> StaticEvaluation:
    """False confirmed tracks on static structure (module docstring) of a replay
    (``evaluate.Replay``) of ``bag``; ``mode`` ``reference`` (poses from
    ``/ground_truth/platform``) or ``ego`` (the replay's own poses, local windows);
    ``evaluation``: ``scoring.EvaluationConfig`` (stamp tolerance, ego-motion restarts)."""
    from laser_tracker.core.geometry import interpolate_poses
    from laser_tracker.core.scan import ScanError
    from laser_tracker.errors import InputFileError
    from laser_tracker.tools.annotations import choose_scan_topic, from_frame, to_frame
    from laser_tracker.tools.bag import read_platform_truth, read_scans
    from laser_tracker.tools.scoring import EvaluationConfig, match_stamps, median_period

    evaluation = evaluation or EvaluationConfig()
    if mode not in ('reference', 'ego'):
        raise ValueError(f'mode must be reference or ego, got {mode!r}')
    topic = scan_topic or choose_scan_topic(bag, replay.ego_stamps).topic
    scans = [s for s in read_scans(bag, topic) if not isinstance(s, ScanError)]
    if not scans:
        raise InputFileError(bag, f'no usable scan on {topic}')
    stamps = np.array([s.stamp for s in scans], float)
    order = np.argsort(replay.ego_stamps, kind='stable')
    ego_stamps, ego_poses = replay.ego_stamps[order], replay.ego_poses[order]
    tol = evaluation.stamp_tolerance * median_period(stamps)
    ego_row = match_stamps(stamps, ego_stamps, tol)
    if not (ego_row >= 0).any():
        raise InputFileError(replay.folder, f'no scan of this replay has the header stamp of a '
                             f'scan of {bag} {topic}: was it replayed from that recording?')
    ego_segment = ego_segments(ego_stamps, ego_poses, evaluation.restart_speed,
                               evaluation.restart_gap)

    if mode == 'reference':
        ref = read_platform_truth(bag)
        if len(ref) == 0:
            raise InputFileError(bag, 'the reference pose topic holds no messages')
        k = np.argsort(ref.stamps, kind='stable')
        ref_stamps, ref_poses = ref.stamps[k], ref.poses[k]
        inside = (stamps >= ref_stamps[0] - tol) & (stamps <= ref_stamps[-1] + tol)
        scan_poses = np.full((stamps.size, 3), np.nan)
        scan_poses[inside] = interpolate_poses(ref_stamps, ref_poses, stamps[inside])
        if (~inside).any():
            log.warning('%d of %d scan(s) outside the reference poses [%.3f, %.3f] s: not '
                        'placed', int((~inside).sum()), stamps.size, ref_stamps[0],
                        ref_stamps[-1])
        static = StaticMap.build(scans, scan_poses, config=config)
    else:
        scan_poses = np.full((stamps.size, 3), np.nan)
        seg = np.full(stamps.size, -1, np.int64)
        ok = ego_row >= 0
        scan_poses[ok] = ego_poses[ego_row[ok]]
        seg[ok] = ego_segment[ego_row[ok]]
        static = StaticMap.build(scans, scan_poses, seg, config=config)

    t = replay.tracks.select(replay.tracks.confirmed)
    row = match_stamps(t.stamp, ego_stamps, tol)
    by_stamp = np.argsort(stamps, kind='stable')
    hit = match_stamps(t.stamp, stamps[by_stamp], tol)
    keep = (row >= 0) & (hit >= 0)
    if mode == 'reference':
        keep &= (t.stamp >= ref_stamps[0] - tol) & (t.stamp <= ref_stamps[-1] + tol)
    dropped = int((~keep).sum())
    t, row, scan_of = t.select(keep), row[keep], by_stamp[hit[keep]]
    sx, sy = from_frame(ego_poses[row], t.x, t.y)
    supported = supported_rows(scans, scan_of, sx, sy, config.support)
    if mode == 'reference':
        mx, my = to_frame(interpolate_poses(ref_stamps, ref_poses, t.stamp), sx, sy)
        xy = np.column_stack((mx, my))
        verdicts = judge_tracks(static, t.stamp, t.track_id, xy, supported=supported)
    else:
        xy = np.column_stack((t.x, t.y))
        verdicts = judge_tracks(static, t.stamp, t.track_id, xy, ego_segment[row],
                                windowed=True, supported=supported)
    if dropped:
        log.warning('%d confirmed track row(s) without a placed scan ignored', dropped)

    duration = float(ego_stamps[-1] - ego_stamps[0]) + median_period(ego_stamps)
    minutes = duration / 60.0
    false = [v for v in verdicts if v.false]
    unsupported = [v for v in verdicts if v.kind == 'unsupported']
    t0 = float(ego_stamps[0])
    result = {
        'mode': mode, 'scan_topic': topic, 'config': dataclasses.asdict(config),
        'scans_placed': static.scans, 'scans': len(scans),
        'ego_segments': int(ego_segment.max()) + 1 if ego_segment.size else 0,
        'duration_s': duration,
        'confirmed_tracks': len(verdicts),
        'confirmed_per_minute': len(verdicts) / minutes if minutes > 0 else None,
        'false_tracks': len(false),
        'false_per_minute': len(false) / minutes if minutes > 0 else None,
        'unsupported_tracks': len(unsupported),
        'unsupported_per_minute': len(unsupported) / minutes if minutes > 0 else None,
        'moving_tracks': len(verdicts) - len(false) - len(unsupported),
        'track_rows_ignored': dropped,
        'false_list': [v.as_dict(t0) for v in false],
        'tracks': [v.as_dict(t0) for v in verdicts],
    }
    return StaticEvaluation(result, static, xy, t.track_id, t.stamp, scan_poses, verdicts)
