"""Movement hypotheses: creation (paper Sec. 7) and management (Sec. 8), vectorised.

A hypothesis is a possible moving object: position, velocity (its Kalman filter,
``laser_tracker.core.kalman``), a weight 0..100 and the number of samples that support it.
All hypotheses live in stacked arrays (:class:`HypothesisArrays`); one frame of blobs updates
them all at once. Distances in Equations 2 and 3 are in ``distance_unit`` (the 10 cm grid
cell: METHOD.md Sec. 4), positions in the odometry frame.

Per frame (``HypothesisTracker.update(blobs)``; the stream rules, such as time going
backwards, belong to the ``core.stages.Tracker`` stage around it):

1. **Prediction** ``H_est`` of every hypothesis at the blobs' stamp.
2. **Blob weights**, Equation 2: ``B_weight = 100 - sum_i max(50 - dist(H_est_i, B_pos), 0)``
   clipped to 0..100; a blob above ``new_blob_threshold`` is *new*.
3. **Gating and splitting**: every blob within ``gate`` metres of a prediction supports that
   hypothesis; with several, the hypothesis splits, one copy per blob, each updated on its
   own (this follows both legs of a walker).
4. **Support**, Equation 3: ``H_weight += W_inc - W_dec * dist(B_pos, H_est)``, clipped to
   0..100, and the blob goes to the Kalman filter; the samples count grows by one.
5. **Wall penalty**: a hypothesis whose supporting (or creating) blob lies on a wall
   (``Blobs.structure``: the blob's visible surface is a straight line running past it on
   both sides, see ``blobs._Surfaces.measure``) and whose velocity (at least
   ``wall_min_speed``) is within ``wall_angle`` of that line's direction has its weight
   multiplied by ``wall_factor`` (paper: halved).
6. **Coasting**: a hypothesis without support moves on along its velocity and loses
   ``coast_rate`` weight per second (a short occlusion is bridged).
7. **Creation**: each new blob pairs with every previous-frame blob within ``max_speed * dt``
   (and at least ``min_displacement`` away: "seen in two separate locations"), creating a
   hypothesis with the pair's velocity and ``initial_weight``.
8. **Merging**: hypotheses within ``merge_distance`` of each other whose velocities differ by
   less than ``merge_speed`` are one target (chains included): the group keeps the state of
   its best-supported member and the identity of its oldest confirmed member.
9. **Removal** below ``remove_below``; a hard bound ``max_hypotheses`` (the strongest are
   kept, a warning is logged when the bound is hit).
10. **Confirmation**: reported as a moving object once ``samples >= confirm_samples``
    (paper: m = 4). A hypothesis' first sample is its creation pair (the first velocity
    measurement), each supporting blob adds one. Optional (off by default):
    ``confirm_min_speed``, ``confirm_min_travel``.

Identity. Each hypothesis has a ``track_id`` that is unique among the live hypotheses. On a
split, the copy supported by the blob nearest the prediction keeps the parent's id, samples
and confirmation; the other copies get new ids and restart at one sample (they carry the
parent's velocity and weight but must earn their own confirmation). On a merge the group
keeps the id of its oldest confirmed member (or of its oldest member if none is confirmed),
so a person whose leg hypotheses split and merge again keeps one id.
"""
from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core.blobs import Blobs
from laser_tracker.core.geometry import pairwise_distances
from laser_tracker.core.kalman import TrackFilter, KalmanConfig

log = logging.getLogger(__name__)

#: A measurement rides along with the scanner (``ride_along_reach``) when it moved at least
#: this far (m) in the world since the previous frame (more than range noise), and less than
#: half as far in the scanner's frame.
RIDE_MIN_TRAVEL = 0.05


@dataclass(frozen=True)
class HypothesisConfig:
    """Hypothesis creation and management (node ``tracking``, ``hypotheses.*``)."""

    distance_unit: float = param(0.1, 'Unit (m) of dist in Equations 2 and 3: the 10 cm grid '
                                 'cell (METHOD.md Sec. 4).', min=0.001, max=10.0)
    blob_radius: float = param(50.0, 'Eq. 2: hypotheses closer than this many distance units '
                               "lower a blob's weight (the 50 of the equation).", min=0.0,
                               max=1000.0)
    new_blob_threshold: float = param(60.0, 'Eq. 2: a blob whose weight is above this is new '
                                      'and creates hypotheses.', min=0.0, max=100.0)
    max_speed: float = param(3.0, 'Largest target speed (m/s): a new blob pairs with previous '
                             'blobs within max_speed * dt.', min=0.01, max=100.0)
    min_displacement: float = param(0.1, 'A creation pair must be at least this far apart (m): '
                                    'the blob was seen in two separate locations.', min=0.0,
                                    max=10.0)
    initial_weight: float = param(20.0, 'Weight of a new hypothesis ("low", paper Sec. 8).',
                                  min=0.0, max=100.0)
    w_inc: float = param(60.0, 'Eq. 3 W_inc (paper: 60).', min=0.0, max=100.0)
    w_dec: float = param(15.0, 'Eq. 3 W_dec per distance unit (paper: 15).', min=0.0,
                         max=100.0)
    gate: float = param(0.7, 'Radius (m) around a prediction in which a blob supports the '
                        'hypothesis (the search box of Fig. 6).', min=0.01, max=10.0)
    coast_grace: float = param(
        0.0, 'A hypothesis without support loses no weight for this long (s) after its last '
        'support: a new one (weight 20) survives a missed scan or two of a fast scanner, '
        'where the paper\'s coasting costs more than its weight at once. 0 = paper.',
        min=0.0, max=5.0)
    new_when_ungated: bool = param(
        False, 'A blob that no hypothesis gates (none predicted within gate) is new, whatever '
        'the hypotheses farther away: Eq. 2 lowers its weight for every hypothesis within 5 m '
        'and refuses a new mover in a crowd. false = Eq. 2 alone (paper).')
    coast_rate: float = param(200.0, 'Weight lost per second without a supporting blob '
                              '(40 per frame at the paper\'s 5 Hz; per second so that a '
                              'faster scanner coasts as long).', min=0.0, max=10000.0)
    remove_below: float = param(10.0, 'A hypothesis whose weight falls below this is removed.',
                                min=0.0, max=100.0)
    wall_factor: float = param(0.5, 'Weight factor for a hypothesis moving along structure '
                               '(paper: halved).', min=0.0, max=1.0)
    wall_angle: float = param(30.0, 'A velocity within this many degrees of the structure '
                              'direction counts as moving along it.', min=0.0, max=90.0)
    wall_min_speed: float = param(0.1, 'Below this speed (m/s) a hypothesis has no direction '
                                  'and the wall test does not apply.', min=0.0, max=10.0)
    confirm_samples: int = param(4, 'm: samples before a hypothesis is reported as a moving '
                                 'object (paper: 4).', min=1, max=1000)
    confirm_min_speed: float = param(0.0, 'A hypothesis is confirmed only while its speed is at '
                                     'least this (m/s): a flicker in place (a thin chair leg '
                                     'seen in one scan and missed in the next) is not a '
                                     'moving object. 0 = paper.', min=0.0, max=10.0)
    confirm_min_travel: float = param(0.0, 'A hypothesis started by motion blobs is confirmed '
                                      'only once it is this far (m) from where it was '
                                      'created: a moving object goes somewhere; a thin static '
                                      'object flickering in and out of the scans does not '
                                      '(people have their own rules). 0 = paper.', min=0.0,
                                      max=100.0)
    merge_distance: float = param(0.3, 'Hypotheses closer than this (m) ...', min=0.0,
                                  max=10.0)
    merge_speed: float = param(0.5, '... whose velocities differ by less than this (m/s) are '
                               'duplicates of one target and merge.', min=0.0, max=100.0)
    max_hypotheses: int = param(100, 'Hard bound on live hypotheses (the strongest are kept, '
                                'with a warning).', min=1, max=100000)
    max_blobs: int = param(500, 'At most this many blobs per frame are considered (the '
                           'largest), bounding the work on a burst.', min=1, max=100000)
    max_blob_range: float = param(50.0, 'Blobs further than this (m) from the scanner are '
                                  'dropped with a warning (corrupt input).', min=0.1,
                                  max=100000.0)
    moving_speed: float = param(0.2, 'A track slower than this (m/s) is reported as not '
                                'moving (the "moving" flag of the tracks).', min=0.0,
                                max=10.0)
    creation_window: float = param(
        0.3, 'A new blob pairs with the blobs of the most recent earlier frame within this '
        'many seconds that has one in reach (max_speed x dt), not only the previous frame: '
        'a blob that flickers (seen in every other scan of a fast scanner) still creates '
        'its hypothesis. 0 = paper (the previous frame).', min=0.0, max=5.0)
    ride_along_speed: float = param(
        0.3, 'A hypothesis that is not a person and moves with the scanner (its velocity '
        'within this many m/s of the scanner\'s, while the scanner moves at least '
        'ride_along_min_speed) is not confirmed: a patch that travels with the scanner is '
        'almost always an artefact (glass or a mirror at normal incidence, the robot\'s '
        'own parts). 0 = paper (off).', min=0.0, max=5.0)
    ride_along_min_speed: float = param(
        0.2, 'The scanner speed (m/s) from which ride_along_speed applies.', min=0.0,
        max=10.0)
    ride_along_reach: float = param(
        1.0, 'A motion blob within this distance (m) of the scanner that keeps its place in '
        'the scanner\'s frame from one frame to the next while the scanner moves is '
        'ignored: the robot\'s own body, before the self-mask has learnt it. 0 = off '
        '(paper).', min=0.0, max=10.0)
    confirm_time: float = param(
        0.0, 'A hypothesis is confirmed only once it has lived this long (s) since it was '
        'created, whatever the scan rate: the paper\'s 4 samples span 0.8 s at its 5 Hz but '
        '0.4 s at 10 Hz. 0 = samples alone (paper).', min=0.0, max=10.0)
    person_gate: float = param(
        0.5, 'A person detection (legs) within this distance (m) of a prediction supports '
        'that hypothesis (each hypothesis takes its nearest). Wider keeps a person whose '
        'predictions are poor (no odometry) a little better, but lets leg-like clutter '
        'support hypotheses on static structure.', min=0.01, max=5.0)
    person_radius: float = param(
        0.45, 'Motion blobs within this distance (m) of a person detection are that '
        'person (their legs): they neither split nor create hypotheses.', min=0.0, max=5.0)
    person_tolerance: float = param(
        0.25, 'Eq. 3 for a person detection counts only its distance from the prediction '
        'beyond this (m): where a person stands between two swinging legs is less certain '
        'than a blob.', min=0.0, max=2.0)
    person_create_confidence: float = param(
        0.5, 'A person detection that no hypothesis claims creates one when its confidence '
        'is at least this.', min=0.0, max=1.0)
    person_min_travel: float = param(
        1.5, 'A hypothesis started by a person detection is confirmed only once a person '
        'detection supporting it stood in space seen free before (someone who walked in), '
        'or once it has moved this far (m) from where it started, both in the world and in '
        'the scanner\'s frame: clutter that looks like legs (chair and table legs) stands '
        'where the scans have always seen something, and a leg-like patch of a wall that '
        'rides along with a moving robot goes nowhere in its frame. 0 = no such '
        'condition.', min=0.0, max=10.0)
    person_confirm_samples: int = param(
        30, 'A hypothesis started by a person detection is also confirmed once this many '
        'person detections have supported it, though it was never seen walking: a person '
        'who stands in view from the start (in front of a robot that follows them). Chair '
        'and table legs rarely stay detected that long from a moving robot. 0 = off.',
        min=0, max=100000)
    gait_spread: float = param(
        0.0, 'A person whose two legs\' separation has varied by this much (m), off static '
        'background, is walking (the legs swing; chair or table legs keep their distance): '
        'it may be confirmed without having moved person_min_travel. Off by default: on '
        'the real recordings it confirmed more false tracks (pose errors make legs seem to '
        'swing) and no more people. 0 = off.', min=0.0, max=2.0)
    person_kind_samples: int = param(
        2, 'Supports by person detections after which a track is of kind person.', min=1,
        max=1000)
    segment_gate: float = param(
        0.5, 'A confirmed person\'s hypothesis with no supporting blob or person detection '
        'is supported by the nearest compact scan segment with a leg probability of at '
        'least segment_min_leg within this distance (m) of its prediction (another '
        'object\'s: by a segment within stop_radius of it), without gaining weight or '
        'samples: an object that stops stays tracked, with the same id, as long as it stays '
        'in the scans, and a person the detector misses for a few scans keeps the track. '
        '0 = paper (it coasts and fades).', min=0.0, max=2.0)
    segment_min_leg: float = param(
        0.02, 'Least leg probability of a segment that supports a person\'s track: low, '
        'since it only keeps a confirmed person (legs seen edge-on, merged with clutter or '
        'half hidden score low); 0 = any compact segment.', min=0.0, max=1.0)
    stop_radius: float = param(
        0.15, 'A supporting segment within this distance (m) of the track\'s position means '
        'the object stands: its velocity is measured as zero.', min=0.0, max=2.0)
    resume_time: float = param(
        2.0, 'A hypothesis confirmed within this time (s) of the loss of a confirmed track of '
        'the same kind, within resume_radius of where that track was last seen, takes its '
        'id: a target lost for a moment (missed, hidden) keeps its identity. 0 = off.',
        min=0.0, max=60.0)
    resume_radius: float = param(
        1.0, 'Largest distance (m) between a lost track\'s last position and a newly '
        'confirmed hypothesis that resumes it (resume_time).', min=0.0, max=10.0)
    duplicate_radius: float = param(
        0.3, 'A hypothesis within this distance (m) of a confirmed track is not confirmed: '
        'it duplicates that track (the two follow the same legs) and merges into it, so '
        'confirming it would show a new id for one frame. 0 = paper.', min=0.0, max=5.0)
    person_blob_gate: float = param(
        0.5, 'A person\'s track takes motion blobs only within this distance (m) of its '
        'prediction (its legs), not at the paper\'s gate: a blob farther away is someone '
        'or something else, and would pull the track off a person who stands. 0 = gate.',
        min=0.0, max=5.0)
    max_gap: float = param(2.0, 'A gap between frames longer than this (s) drops every '
                           'hypothesis (predictions are meaningless).', min=0.01, max=3600.0)


_ID, _T, _WEIGHT, _SAMPLES, _CONFIRMED, _SUPPORTED, _BORN = 0, 5, 8, 9, 10, 11, 12
_STATE, _VEL, _POS, _START = slice(1, 5), slice(3, 5), slice(6, 8), slice(13, 15)
_PERSONS, _STOPPED, _ORIGIN = 15, 16, 17   # _ORIGIN: 0 motion, 1 person, 2 person walked
_SPREAD = slice(18, 20)                      # least and largest leg separation seen
_START_LOCAL = slice(20, 22)                 # where it started, in the scanner frame then
_P0 = 22


class HypothesisArrays:
    """All live hypotheses, one row each of a single float matrix.

    One gather moves every field of the selected hypotheses at once (a split, a removal, a
    merge), which keeps the per-frame cost independent of the number of fields. Fields are
    column views: ``track_id`` (int, unique), ``state`` (k, 4) ``px, py, vx, vy`` valid at
    ``t_state`` (the stamp of the last supporting blob, ``kalman.TrackFilter``), ``P``
    (k, d, d), ``position`` (k, 2) the estimate at the current frame, ``velocity`` (k, 2),
    ``weight`` 0..100, ``samples``, ``confirmed``, ``supported`` (a blob supported it this
    frame), ``born`` (creation stamp), ``start`` (k, 2) where it was created (the later
    blob of its creation pair), ``person_samples`` (supports by person detections),
    ``stopped`` (held by the occupancy of a stopped object this frame), ``origin`` (what
    created it: 0 motion, 1 a person detection, 2 a person detection in space seen free)
    and ``start_local`` (k, 2) where it was created in the scanner's frame of that moment.
    """

    __slots__ = ('data', 'dim')

    def __init__(self, data: np.ndarray, dim: int):
        self.data = data
        self.dim = dim

    @classmethod
    def empty(cls, dim: int, n: int = 0) -> HypothesisArrays:
        return cls(np.zeros((n, _P0 + dim * dim)), dim)

    def __len__(self) -> int:
        return int(self.data.shape[0])

    def take(self, index) -> HypothesisArrays:
        return HypothesisArrays(self.data[index], self.dim)

    @staticmethod
    def concat(parts: list[HypothesisArrays]) -> HypothesisArrays:
        parts = [p for p in parts if len(p)] or parts[:1]
        if len(parts) == 1:
            return parts[0]
        return HypothesisArrays(np.concatenate([p.data for p in parts]), parts[0].dim)

    # Fields (views where the type allows; flags and counts are stored as floats).
    track_id = property(lambda self: self.data[:, _ID].astype(np.int64),
                        lambda self, v: self.data.__setitem__((slice(None), _ID), v))
    state = property(lambda self: self.data[:, _STATE],
                     lambda self, v: self.data.__setitem__((slice(None), _STATE), v))
    velocity = property(lambda self: self.data[:, _VEL])
    t_state = property(lambda self: self.data[:, _T],
                       lambda self, v: self.data.__setitem__((slice(None), _T), v))
    position = property(lambda self: self.data[:, _POS],
                        lambda self, v: self.data.__setitem__((slice(None), _POS), v))
    weight = property(lambda self: self.data[:, _WEIGHT],
                      lambda self, v: self.data.__setitem__((slice(None), _WEIGHT), v))
    samples = property(lambda self: self.data[:, _SAMPLES].astype(np.int64),
                       lambda self, v: self.data.__setitem__((slice(None), _SAMPLES), v))
    confirmed = property(lambda self: self.data[:, _CONFIRMED] > 0.5,
                         lambda self, v: self.data.__setitem__((slice(None), _CONFIRMED), v))
    supported = property(lambda self: self.data[:, _SUPPORTED] > 0.5,
                         lambda self, v: self.data.__setitem__((slice(None), _SUPPORTED), v))
    born = property(lambda self: self.data[:, _BORN],
                    lambda self, v: self.data.__setitem__((slice(None), _BORN), v))

    start = property(lambda self: self.data[:, _START],
                     lambda self, v: self.data.__setitem__((slice(None), _START), v))
    start_local = property(lambda self: self.data[:, _START_LOCAL])
    person_samples = property(lambda self: self.data[:, _PERSONS].astype(np.int64))
    origin = property(lambda self: self.data[:, _ORIGIN].astype(np.int64))
    stopped = property(lambda self: self.data[:, _STOPPED] > 0.5)

    @property
    def P(self) -> np.ndarray:
        return self.data[:, _P0:].reshape(-1, self.dim, self.dim)

    @P.setter
    def P(self, value) -> None:
        self.data[:, _P0:] = np.asarray(value).reshape(self.data.shape[0], -1)


@dataclass
class Tracks:
    """What the tracker reports at one frame (the ``tracks`` topic): one row per hypothesis.

    ``covariance`` (k, 2, 2): of ``position``; ``moving``: speed at least
    ``hypotheses.moving_speed`` and not stopped; ``kind``: ``person`` once person detections
    supported it ``person_kind_samples`` times, else ``object`` (found by its motion).
    """

    stamp: float
    track_id: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray
    weight: np.ndarray
    samples: np.ndarray
    confirmed: np.ndarray
    moving: np.ndarray
    kind: np.ndarray

    def __len__(self) -> int:
        return int(self.track_id.size)

    def select(self, mask) -> Tracks:
        return Tracks(self.stamp, *(getattr(self, f)[mask] for f in (
            'track_id', 'position', 'velocity', 'covariance', 'weight', 'samples',
            'confirmed', 'moving', 'kind')))


@dataclass
class FrameResult:
    """What one tracker update reports."""

    stamp: float
    hypotheses: HypothesisArrays
    newly_confirmed: np.ndarray   # (j,) indices into hypotheses: confirmed this frame
    created: int                  # hypotheses created this frame
    bounded: bool                 # the max_hypotheses bound was hit


class HypothesisTracker:
    """Hypothesis creation and management over frames of blobs (paper Sec. 7-8)."""

    def __init__(self, config: HypothesisConfig | None = None,
                 kalman: KalmanConfig | None = None):
        self.config = config or HypothesisConfig()
        self.filter = TrackFilter(kalman or KalmanConfig())
        self.next_id = 1
        self.stats = {'created': 0, 'confirmed': 0, 'splits': 0, 'merged': 0,
                      'bound_hits': 0, 'resets': 0, 'blobs_dropped': 0, 'resumed': 0}
        self._bound_active = False
        self.reset()

    # ------------------------------------------------------------------ state handling
    def reset(self, reason: str | None = None) -> None:
        """Forget every hypothesis and the previous blobs (ids keep counting up)."""
        if reason:
            log.warning('tracker reset: %s', reason)
            self.stats['resets'] += 1
        self.hyp = HypothesisArrays.empty(self.filter.dim)
        self.prev_xy = np.zeros((0, 2))
        self.prev_stamp: float | None = None
        # Earlier frames for creation (newest last): (stamp, motion blobs, persons).
        self.recent: deque = deque(maxlen=64)
        self.prev_origin: np.ndarray | None = None
        self._scanner = np.zeros(3)
        self._ride_local = np.zeros((0, 2))     # last frame's blobs in its scanner frame
        # Confirmed tracks lost recently (resume_time): id, stamp, x, y, is a person.
        self.lost = np.zeros((0, 5))

    def report(self, stamp: float) -> Tracks:
        """The hypotheses as :class:`Tracks` at ``stamp`` (the frame just updated)."""
        h = self.hyp
        speed2 = (h.velocity ** 2).sum(axis=1)
        return Tracks(stamp=float(stamp), track_id=h.track_id, position=h.position.copy(),
                      velocity=h.velocity.copy(),
                      covariance=self.filter.position_covariance(h.P, h.t_state, stamp),
                      weight=h.weight.copy(), samples=h.samples, confirmed=h.confirmed,
                      moving=(speed2 >= self.config.moving_speed ** 2) & ~h.stopped,
                      kind=np.where(self._is_person(h),
                                    'person', 'object').astype(object))

    def reconfigure(self, config: HypothesisConfig, kalman: KalmanConfig) -> bool:
        """Use new parameters from the next frame. Returns True when the hypotheses must be
        reset (a new filter mode: their state vectors differ)."""
        self.config = config
        if kalman == self.filter.config:
            return False
        new = TrackFilter(kalman)
        reset = new.dim != self.filter.dim
        self.filter = new
        return reset

    def _new_ids(self, n: int) -> np.ndarray:
        ids = np.arange(self.next_id, self.next_id + n, dtype=np.int64)
        self.next_id += n
        return ids

    def _clean(self, blobs: Blobs) -> tuple[np.ndarray, np.ndarray]:
        """Usable blobs (finite, near the scanner, at most max_blobs): positions and mask."""
        c = self.config
        xy = np.asarray(blobs.xy, dtype=float).reshape(-1, 2)
        d = xy - np.asarray(blobs.origin, dtype=float)[:2]
        with np.errstate(invalid='ignore'):
            ok = (d * d).sum(axis=1) <= c.max_blob_range ** 2   # NaN anywhere -> False
        if ok.all() and xy.shape[0] <= c.max_blobs:
            return xy, ok
        if not ok.all():
            log.warning('t=%.3f: dropped %d blob(s) that are not finite or further than '
                        '%.1f m from the scanner', blobs.stamp, int((~ok).sum()),
                        c.max_blob_range)
            self.stats['blobs_dropped'] += int((~ok).sum())
        if ok.sum() > c.max_blobs:
            kept = np.flatnonzero(ok)
            cells = np.asarray(blobs.cells).reshape(-1)
            order = np.argsort(-cells[kept], kind='stable') if cells.size == ok.size else \
                np.arange(kept.size)
            ok = np.zeros_like(ok)
            ok[kept[order[:c.max_blobs]]] = True
            log.warning('t=%.3f: %d blobs, only the %d largest are tracked (max_blobs)',
                        blobs.stamp, kept.size, c.max_blobs)
            self.stats['blobs_dropped'] += int(kept.size - c.max_blobs)
        return xy[ok], ok

    # ------------------------------------------------------------------------ the frame
    def update(self, blobs: Blobs) -> FrameResult:
        """One frame: the measurements of one scan (odometry frame) -> updated hypotheses."""
        c = self.config
        t = float(blobs.stamp)
        self._scanner = np.asarray(blobs.origin, dtype=float).reshape(-1)[:3]
        xy, ok = self._clean(blobs)
        structure = np.asarray(blobs.structure, dtype=float).reshape(-1)
        if structure.shape[0] == ok.shape[0]:
            structure = structure[ok]
        if structure.shape[0] != xy.shape[0]:
            structure = np.full(xy.shape[0], np.nan)
        persons, confidence = _finite_rows(blobs.persons, blobs.person_confidence)
        person_free = np.asarray(blobs.person_free, dtype=bool).reshape(-1)
        if person_free.shape[0] != persons.shape[0]:
            person_free = np.zeros(persons.shape[0], bool)
        spread = np.asarray(blobs.person_spread, dtype=float).reshape(-1)
        if spread.shape[0] != persons.shape[0]:
            spread = np.full(persons.shape[0], np.nan)
        person_static = np.asarray(blobs.person_static, dtype=bool).reshape(-1)
        if person_static.shape[0] == persons.shape[0]:
            spread = np.where(person_static, np.nan, spread)   # clutter's "legs" do not swing
        segments, leg = _finite_rows(blobs.segments, blobs.segment_leg)
        if c.ride_along_reach > 0:
            riding = self._riding_with_scanner(xy)
            xy, structure = xy[~riding], structure[~riding]
        hyp = self.hyp
        k = len(hyp)
        pred = self.filter.predict(hyp.state, hyp.t_state, t) if k else np.zeros((0, 2))
        # People first: each hypothesis takes its nearest person detection within the gate;
        # an unclaimed, confident enough one starts a hypothesis; the motion blobs of the
        # people so used (their legs) are those people.
        person_of = np.full(k, -1, np.intp)
        fresh = np.zeros(persons.shape[0], bool)
        if persons.shape[0]:
            dp = pairwise_distances(pred, persons)
            if k:
                near = dp.argmin(axis=1)
                person_of = np.where(dp[np.arange(k), near] <= c.person_gate, near, -1)
            claimed = (dp <= c.person_gate).any(axis=0) if k else fresh.copy()
            fresh = ~claimed & (confidence >= c.person_create_confidence)
            # a person starting a hypothesis takes its legs' blobs only if seen walking in:
            # else the blobs may be a mover beside clutter and start their own
            used = fresh & person_free
            used[person_of[person_of >= 0]] = True
            if xy.shape[0] and c.person_radius > 0 and used.any():
                legs = pairwise_distances(xy, persons[used]).min(axis=1) <= c.person_radius
                xy, structure = xy[~legs], structure[~legs]
        b = xy.shape[0]
        dist = pairwise_distances(pred, xy)
        # Equation 2 on the predictions of the existing hypotheses.
        if b:
            # (A stopped object held by the scans does not make the motion near it old.)
            b_weight = 100.0 - np.maximum(c.blob_radius - dist[~hyp.stopped] /
                                          c.distance_unit, 0.0).sum(axis=0)
            b_weight = np.clip(b_weight, 0.0, 100.0)
            new_blob = b_weight > c.new_blob_threshold
            if c.new_when_ungated and k:
                new_blob |= ~(dist <= c.gate).any(axis=0)
        else:
            b_weight, new_blob = np.zeros(0), np.zeros(0, bool)

        parts = []
        by_person = person_of >= 0
        if by_person.any():
            rows = np.flatnonzero(by_person)
            parts.append(self._support_person(hyp.take(rows), pred[rows],
                                              persons[person_of[rows]],
                                              person_free[person_of[rows]],
                                              spread[person_of[rows]], t))
        # Gating, splitting and Equation 3 for the others.
        gate = (dist <= c.gate) & ~by_person[:, None]
        if c.person_blob_gate > 0 and k and b:
            person_kind = self._is_person(hyp)
            gate[person_kind] &= dist[person_kind] <= c.person_blob_gate
        hi, bi = np.nonzero(gate)
        if hi.size:
            parts.append(self._support(hyp, pred, dist, hi, bi, xy, structure, t))
        unsupported = ~gate.any(axis=1) & ~by_person if k else np.zeros(0, bool)
        if unsupported.any():
            dt_frame = t - self.prev_stamp if self.prev_stamp is not None else 0.0
            rest = np.flatnonzero(unsupported)
            segment = self._segment_of(hyp, rest, pred[rest], segments, leg)
            held = segment >= 0
            if held.any():
                parts.append(self._support_segment(hyp.take(rest[held]), pred[rest[held]],
                                                   segments[segment[held]], t))
            if (~held).any():
                moving_on = rest[~held]
                parts.append(self._coast(hyp.take(moving_on), pred[moving_on], t, dt_frame))

        created = 0
        if new_blob.any():
            born = self._create_from_blobs(xy[new_blob], structure[new_blob],
                                           b_weight[new_blob], t)
            created += len(born)
            parts.append(born)
        if fresh.any():
            born = self._create_from_persons(persons[fresh], person_free[fresh],
                                             spread[fresh], t)
            created += len(born)
            parts.append(born)

        hyp = HypothesisArrays.concat(parts) if parts else HypothesisArrays.empty(
            self.filter.dim)
        was_confirmed = hyp.confirmed.copy()
        hyp, was_confirmed = self._merge(hyp, was_confirmed)
        keep = hyp.weight >= c.remove_below
        if not keep.all():
            if c.resume_time > 0:
                self._remember_lost(hyp.take(~keep & hyp.confirmed), t)
            hyp, was_confirmed = hyp.take(keep), was_confirmed[keep]
        bounded = len(hyp) > c.max_hypotheses
        if bounded:
            order = np.lexsort((-hyp.samples, -hyp.weight, ~hyp.confirmed))
            top = np.sort(order[:c.max_hypotheses])
            self.stats['bound_hits'] += 1
            if not self._bound_active:
                log.warning('t=%.3f: %d hypotheses exceed max_hypotheses=%d: the %d strongest '
                            'are kept (further hits are counted, not logged, until it clears)',
                            t, len(hyp), c.max_hypotheses, c.max_hypotheses)
            hyp, was_confirmed = hyp.take(top), was_confirmed[top]
        self._bound_active = bounded
        ready = hyp.samples >= c.confirm_samples
        if c.person_min_travel > 0:
            # Far from where it started both in the world (not clutter the robot passes)
            # and in the scanner's frame (not something riding along with the robot).
            travel2 = np.minimum(((hyp.position - hyp.start) ** 2).sum(axis=1),
                                 ((self._to_scanner(hyp.position) - hyp.start_local) ** 2)
                                 .sum(axis=1))
            walked = (hyp.origin != 1) | (travel2 >= c.person_min_travel ** 2)
            if c.person_confirm_samples > 0:
                walked |= hyp.person_samples >= c.person_confirm_samples
            ready &= walked
        if c.ride_along_speed > 0:
            ready &= ~self._riding_along(hyp, blobs, t)
        if c.confirm_time > 0:
            ready &= t - hyp.born >= c.confirm_time
        if c.confirm_min_speed > 0:
            ready &= (hyp.velocity ** 2).sum(axis=1) >= c.confirm_min_speed ** 2
        if c.confirm_min_travel > 0:
            travelled = ((hyp.position - hyp.start) ** 2).sum(axis=1) >= c.confirm_min_travel ** 2
            ready &= travelled | (hyp.origin != 0)
        if c.duplicate_radius > 0 and ready.any() and hyp.confirmed.any():
            ready &= ~self._on_confirmed(hyp)
        hyp.confirmed = hyp.confirmed | ready
        newly = np.flatnonzero(hyp.confirmed & ~was_confirmed)
        if c.resume_time > 0 and newly.size and len(self.lost):
            self._resume(hyp, newly, t)
        self.stats['confirmed'] += int(newly.size)
        self.hyp = hyp
        self.prev_xy, self.prev_stamp = xy, t
        self.recent.append((t, xy, persons))
        self.prev_origin = self._scanner
        return self._result(t, newly, created, bounded)

    def _is_person(self, hyp: HypothesisArrays) -> np.ndarray:
        """Mask: hypotheses of kind person (supported by person_kind_samples detections)."""
        return hyp.person_samples >= self.config.person_kind_samples

    def _remember_lost(self, gone: HypothesisArrays, t: float) -> None:
        """Keep the confirmed tracks just removed for ``resume_time``."""
        c = self.config
        fresh = self.lost[self.lost[:, 1] >= t - c.resume_time]
        if len(gone):
            rows = np.column_stack((gone.track_id, np.full(len(gone), t), gone.position,
                                    self._is_person(gone)))
            fresh = np.vstack((fresh, rows))
        self.lost = fresh[-c.max_hypotheses:]

    def _on_confirmed(self, hyp: HypothesisArrays) -> np.ndarray:
        """Mask: unconfirmed hypotheses within duplicate_radius of a confirmed one."""
        confirmed = hyp.position[hyp.confirmed]
        near = (pairwise_distances(hyp.position, confirmed) <= self.config.duplicate_radius).any(axis=1)
        return near & ~hyp.confirmed

    def _resume(self, hyp: HypothesisArrays, newly: np.ndarray, t: float) -> None:
        """Newly confirmed hypotheses near a recently lost track of their kind take its id
        (nearest pairs first, each lost track once)."""
        c = self.config
        lost = self.lost[self.lost[:, 1] >= t - c.resume_time]
        if not len(lost):
            self.lost = lost
            return
        person = self._is_person(hyp)[newly]
        d = pairwise_distances(hyp.position[newly], lost[:, 2:4])
        d[person[:, None] != (lost[None, :, 4] > 0.5)] = np.inf
        taken = np.zeros(len(lost), bool)
        done = np.zeros(len(newly), bool)
        for flat in np.argsort(d, axis=None):
            i, j = divmod(int(flat), len(lost))
            if d[i, j] > c.resume_radius:
                break
            if taken[j] or done[i]:
                continue
            taken[j] = done[i] = True
            hyp.data[newly[i], _ID] = lost[j, 0]
            self.stats['resumed'] += 1
        self.lost = lost[~taken]

    def _scanner_motion(self, t: float):
        """(velocity (2,), turn rate, speed) of the scanner over the last frame, or None."""
        prev, origin = self.prev_origin, self._scanner
        if prev is None or self.prev_stamp is None or t <= self.prev_stamp or \
                origin.size != 3 or not (np.isfinite(origin).all() and np.isfinite(prev).all()):
            return None
        dt = t - self.prev_stamp
        velocity = (origin[:2] - prev[:2]) / dt
        turn = math.remainder(origin[2] - prev[2], 2.0 * math.pi) / dt
        return velocity, turn, float(np.hypot(*velocity))

    def _relative_speed(self, hyp: HypothesisArrays, motion) -> np.ndarray:
        """Each hypothesis' speed relative to the point of the scanner's rigid frame where it
        is (the scanner's velocity plus its turn rate times the lever arm)."""
        velocity, turn, _ = motion
        arm = hyp.position - self._scanner[:2]
        rigid = velocity + turn * np.column_stack((-arm[:, 1], arm[:, 0]))
        return np.hypot(*(hyp.velocity - rigid).T)

    def _riding_along(self, hyp: HypothesisArrays, blobs: Blobs, t: float) -> np.ndarray:
        """Mask: hypotheses (not persons) moving with the scanner (``ride_along_speed``),
        by their filtered velocity."""
        c = self.config
        motion = self._scanner_motion(t)
        if motion is None or motion[2] < c.ride_along_min_speed:
            return np.zeros(len(hyp), bool)
        return (self._relative_speed(hyp, motion) < c.ride_along_speed) & ~self._is_person(hyp)

    def _riding_with_scanner(self, xy: np.ndarray) -> np.ndarray:
        """Mask: motion blobs within ``ride_along_reach`` of the scanner that kept their place
        in its frame since the previous frame (a blob of then within half their world
        displacement of the same scanner-frame place) while they moved at least
        ``RIDE_MIN_TRAVEL`` in the world: the robot's own body, before the self-mask has
        learnt it. Remembers this frame's. (People are not filtered: someone walking beside
        the robot keeps their place in its frame too, and the body is learnt before a
        standing person is confirmed.)"""
        local = self._to_scanner(xy)
        before, pose = self._ride_local, self.prev_origin
        self._ride_local = local
        out = np.zeros(xy.shape[0], bool)
        if not xy.shape[0] or before.shape[0] == 0 or pose is None:
            return out
        near = (local ** 2).sum(axis=1) <= self.config.ride_along_reach ** 2
        if not near.any():
            return out
        in_scanner = pairwise_distances(local[near], before)
        in_world = pairwise_distances(xy[near], self._from_scanner(before, pose))
        with np.errstate(invalid='ignore'):
            out[near] = ((in_world >= RIDE_MIN_TRAVEL) & (in_scanner < 0.5 * in_world)).any(axis=1)
        return out

    @staticmethod
    def _from_scanner(local: np.ndarray, pose) -> np.ndarray:
        """Scanner-frame points (k, 2) of scanner ``pose`` in the odometry frame."""
        if pose is None or np.asarray(pose).size != 3:
            return np.full_like(local, np.nan)
        x, y, th = (float(v) for v in pose)
        c, s = math.cos(th), math.sin(th)
        return np.column_stack((x + c * local[:, 0] - s * local[:, 1],
                                y + s * local[:, 0] + c * local[:, 1]))

    def _to_scanner(self, xy: np.ndarray) -> np.ndarray:
        """Odometry-frame points (k, 2) in the current scanner frame."""
        x, y, th = self._scanner if self._scanner.size == 3 else (0.0, 0.0, 0.0)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
            return np.full_like(xy, np.nan)
        c, s = math.cos(th), math.sin(th)
        d = xy - (x, y)
        return np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]))

    def _result(self, t, newly, created, bounded) -> FrameResult:
        return FrameResult(stamp=t, hypotheses=self.hyp, newly_confirmed=newly,
                           created=created, bounded=bounded)

    # ------------------------------------------------------------------------ the steps
    def _support(self, hyp: HypothesisArrays, pred, dist, hi, bi, xy, structure,
                 t) -> HypothesisArrays:
        """One copy of hypothesis hi[j] per supporting blob bi[j]: Eq. 3, Kalman, wall test."""
        c = self.config
        out = hyp.take(hi)
        d = dist[hi, bi]
        state, P, position = self.filter.correct(out.state, out.P, out.t_state, xy[bi], t)
        data = out.data
        data[:, _STATE] = state
        out.P = P
        data[:, _POS] = position
        data[:, _T] = t
        weight = np.clip(data[:, _WEIGHT] + (c.w_inc - c.w_dec / c.distance_unit * d),
                         0.0, 100.0)
        data[:, _WEIGHT] = self._wall(weight, state[:, 2:], structure[bi])
        data[:, _SAMPLES] += 1.0
        data[:, _SUPPORTED] = 1.0
        data[:, _STOPPED] = 0.0
        # Identity on a split: the copy nearest its prediction continues the parent.
        if hi.size > 1 and np.any(hi[1:] == hi[:-1]):
            order = np.lexsort((d, hi))
            extra = np.zeros(hi.size, bool)
            extra[order[1:]] = hi[order][1:] == hi[order][:-1]
            n_extra = int(extra.sum())
            data[extra, _ID] = self._new_ids(n_extra)
            data[extra, _SAMPLES] = 1.0
            data[extra, _CONFIRMED] = 0.0
            self.stats['splits'] += n_extra
            self.stats['created'] += n_extra
        return out

    def _coast(self, hyp: HypothesisArrays, pred, t: float, dt: float) -> HypothesisArrays:
        """No supporting blob: continue along the velocity with a reduced weight (free for
        the first ``coast_grace`` seconds after the last support)."""
        c = self.config
        hyp.P = self.filter.coast(hyp.P)
        data = hyp.data
        data[:, _POS] = pred
        charged = np.clip(t - data[:, _T] - c.coast_grace, 0.0, dt) if c.coast_grace > 0 else dt
        data[:, _WEIGHT] = np.maximum(data[:, _WEIGHT] - c.coast_rate * charged, 0.0)
        data[:, _SUPPORTED] = 0.0
        data[:, _STOPPED] = 0.0
        return hyp

    def _earlier(self, t: float, which: int):
        """Earlier frames within reach for creation, newest first: (dt, positions); only the
        previous frame unless ``creation_window`` is set (paper)."""
        window = self.config.creation_window
        for k, frame in enumerate(reversed(self.recent)):
            dt = t - frame[0]
            if dt <= 0.0:
                continue
            if k > 0 and dt > window:
                break
            yield dt, frame[which]

    def _create_from_blobs(self, new_xy, structure, weight, t) -> HypothesisArrays:
        """Paper Sec. 7: a new blob creates a hypothesis with every blob of the previous frame
        (with ``creation_window``: of the most recent earlier frame that has one) within
        ``max_speed * dt`` and at least ``min_displacement`` away."""
        c = self.config
        todo = np.ones(new_xy.shape[0], bool)
        new, prev, dts, struct, order_key = [], [], [], [], []
        for dt, earlier in self._earlier(t, 1):
            if not todo.any():
                break
            if earlier.shape[0] == 0:
                continue
            idx = np.flatnonzero(todo)
            disp = pairwise_distances(new_xy[idx], earlier)
            pair = (disp <= c.max_speed * dt) & (disp >= c.min_displacement)
            ni, pi = np.nonzero(pair)
            if ni.size:
                new.append(new_xy[idx[ni]])
                prev.append(earlier[pi])
                dts.append(np.full(ni.size, dt))
                struct.append(structure[idx[ni]])
                order_key.append(np.column_stack((disp[ni, pi], -weight[idx[ni]])))
                todo[idx[ni]] = False
        if not new:
            return HypothesisArrays.empty(self.filter.dim)
        new_xy, prev_xy = np.concatenate(new), np.concatenate(prev)
        dt, structure, key = np.concatenate(dts), np.concatenate(struct), \
            np.concatenate(order_key)
        if new_xy.shape[0] > c.max_hypotheses:    # a burst: the pairs of the strongest blobs
            keep = np.lexsort((key[:, 0], key[:, 1]))[:c.max_hypotheses]
            new_xy, prev_xy, dt, structure = new_xy[keep], prev_xy[keep], dt[keep], \
                structure[keep]
        return self._create(new_xy, prev_xy, dt, t, structure)

    def _create_from_persons(self, persons, free, spread, t) -> HypothesisArrays:
        """A person detection that no hypothesis claims starts one: its velocity from the
        nearest person detection or motion blob of the most recent earlier frame within reach
        (``creation_window``), else zero."""
        c = self.config
        prev = persons.copy()
        dt = np.ones(persons.shape[0])
        todo = np.ones(persons.shape[0], bool)
        frames = zip(self._earlier(t, 1), self._earlier(t, 2))
        for (age, blobs_then), (_, persons_then) in frames:
            if not todo.any():
                break
            earlier = np.vstack((persons_then, blobs_then))
            if earlier.shape[0] == 0:
                continue
            idx = np.flatnonzero(todo)
            d = pairwise_distances(persons[idx], earlier)
            near = d.argmin(axis=1)
            ok = d[np.arange(idx.size), near] <= c.max_speed * age
            prev[idx[ok]] = earlier[near[ok]]
            dt[idx[ok]] = age
            todo[idx[ok]] = False
        out = self._create(persons, prev, dt, t, np.full(persons.shape[0], np.nan))
        out.data[:, _PERSONS] = 1.0
        out.data[:, _ORIGIN] = np.where(free, 2.0, 1.0)
        out.data[:, _SPREAD] = np.column_stack((spread, spread))
        return out

    def _support_person(self, hyp: HypothesisArrays, pred, persons, free, spread,
                        t) -> HypothesisArrays:
        """Support by a person detection: Eq. 3 with its distance, Kalman, one more sample;
        a person seen in space that was free before, or whose legs' separation has varied
        by ``gait_spread``, is walking (origin 2)."""
        c = self.config
        d = np.maximum(np.hypot(*(persons - pred).T) - c.person_tolerance, 0.0)
        state, P, position = self.filter.correct(hyp.state, hyp.P, hyp.t_state, persons, t)
        data = hyp.data
        data[:, _STATE] = state
        hyp.P = P
        data[:, _POS] = position
        data[:, _T] = t
        data[:, _WEIGHT] = np.clip(data[:, _WEIGHT] + c.w_inc - c.w_dec / c.distance_unit * d,
                                   0.0, 100.0)
        data[:, _SAMPLES] += 1.0
        data[:, _PERSONS] += 1.0
        data[:, _SUPPORTED] = 1.0
        data[:, _STOPPED] = 0.0
        lo, hi = data[:, _SPREAD.start], data[:, _SPREAD.start + 1]
        with np.errstate(invalid='ignore'):
            data[:, _SPREAD.start] = np.fmin(lo, spread)
            data[:, _SPREAD.start + 1] = np.fmax(hi, spread)
            walks = free | ((c.gait_spread > 0)
                            & (data[:, _SPREAD.start + 1] - data[:, _SPREAD.start]
                               >= c.gait_spread))
        data[:, _ORIGIN] = np.where(walks & (data[:, _ORIGIN] == 1.0), 2.0, data[:, _ORIGIN])
        return hyp

    def _segment_of(self, hyp: HypothesisArrays, rows, pred, segments, leg) -> np.ndarray:
        """Per row of ``rows`` (unsupported hypotheses): the index of the segment that
        supports it (``segment_gate``), -1 for none. Only confirmed hypotheses; a person's
        only by a leg-like segment."""
        c = self.config
        out = np.full(rows.size, -1, np.intp)
        if c.segment_gate <= 0 or segments.shape[0] == 0 or rows.size == 0:
            return out
        person = self._is_person(hyp)[rows]
        # A person (its legs are recognisable) is followed within segment_gate of its
        # prediction; another object only where it last was (it stopped there), not onto
        # clutter it passes.
        anchor = np.where(person[:, None], pred, hyp.position[rows])
        d = pairwise_distances(anchor, segments)
        d[person[:, None] & (leg[None, :] < c.segment_min_leg)] = np.inf
        near = d.argmin(axis=1)
        gate = np.where(person, c.segment_gate, min(c.segment_gate, c.stop_radius))
        ok = (d[np.arange(rows.size), near] <= gate) & hyp.confirmed[rows]
        out[ok] = near[ok]
        return out

    def _support_segment(self, hyp: HypothesisArrays, pred, at, t) -> HypothesisArrays:
        """Support by a scan segment: no weight or sample gained. Within ``stop_radius`` of
        the track's position the object stands (velocity measured as zero, it stays
        there); else the segment is a position measurement like a blob."""
        c = self.config
        still = np.hypot(*(at - hyp.position).T) <= c.stop_radius
        data = hyp.data
        if still.any():
            rows = np.flatnonzero(still)
            state, P = self.filter.hold(hyp.state[rows], hyp.P[rows], at[rows])
            data[rows, _STATE] = state
            hyp.P[rows] = P
            data[rows, _POS] = at[rows]
        if (~still).any():
            rows = np.flatnonzero(~still)
            state, P, position = self.filter.correct(hyp.state[rows], hyp.P[rows],
                                                     hyp.t_state[rows], at[rows], t)
            data[rows, _STATE] = state
            hyp.P[rows] = P
            data[rows, _POS] = position
        data[:, _T] = t
        data[:, _SUPPORTED] = 0.0
        data[:, _STOPPED] = still
        return hyp

    def _create(self, new_xy, prev_xy, dt, t, structure) -> HypothesisArrays:
        n = new_xy.shape[0]
        state, P = self.filter.initial(new_xy, prev_xy, np.full(n, dt))
        out = HypothesisArrays.empty(self.filter.dim, n)
        data = out.data
        data[:, _ID] = self._new_ids(n)
        data[:, _STATE] = state
        out.P = P
        data[:, _T] = t
        data[:, _POS] = new_xy
        data[:, _WEIGHT] = self._wall(np.full(n, self.config.initial_weight), state[:, 2:],
                                      structure)
        data[:, _SAMPLES] = 1.0
        data[:, _SUPPORTED] = 1.0
        data[:, _BORN] = t
        data[:, _START] = new_xy
        data[:, _START_LOCAL] = self._to_scanner(new_xy)
        data[:, _SPREAD] = np.nan
        self.stats['created'] += n
        return out

    def _wall(self, weight, velocity, structure) -> np.ndarray:
        """Multiply by wall_factor where the velocity runs along the blob's structure line."""
        c = self.config
        has = ~np.isnan(structure)
        if not has.any():
            return weight
        speed = np.hypot(velocity[:, 0], velocity[:, 1])
        heading = np.arctan2(velocity[:, 1], velocity[:, 0])
        diff = np.abs(np.mod(heading - np.where(has, structure, 0.0) + np.pi / 2, np.pi)
                      - np.pi / 2)
        along = has & (speed >= c.wall_min_speed) & (diff <= math.radians(c.wall_angle))
        return np.where(along, weight * c.wall_factor, weight)

    def _merge(self, hyp: HypothesisArrays, was_confirmed: np.ndarray):
        """Collapse groups of duplicates (close in position and velocity) into one row each."""
        c = self.config
        k = len(hyp)
        if k < 2 or c.merge_distance <= 0:
            return hyp, was_confirmed
        data = hyp.data
        pos, vel = data[:, _POS], data[:, _VEL]
        dp = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(axis=2)
        dv = ((vel[:, None, :] - vel[None, :, :]) ** 2).sum(axis=2)
        close = (dp <= c.merge_distance ** 2) & (dv <= c.merge_speed ** 2)
        if np.count_nonzero(close) == k:          # only the diagonal: nothing to merge
            return hyp, was_confirmed
        a, b = np.nonzero(np.triu(close, 1))
        group = _components(k, a, b)
        # State: the best-supported member (supported now, then weight, then samples).
        state_key = np.lexsort((-data[:, _SAMPLES], -data[:, _WEIGHT], -data[:, _SUPPORTED]))
        rank = np.empty(k, np.intp)
        rank[state_key] = np.arange(k)
        best = np.full(k, k, np.intp)
        np.minimum.at(best, group, rank)
        keep = rank == best[group]
        # Identity: the oldest confirmed member, else the oldest member (smallest id).
        ident_key = np.lexsort((data[:, _ID], -data[:, _CONFIRMED]))
        irank = np.empty(k, np.intp)
        irank[ident_key] = np.arange(k)
        ibest = np.full(k, k, np.intp)
        np.minimum.at(ibest, group, irank)
        donor = ident_key[ibest[group]]          # row whose identity each row's group keeps
        samples = np.zeros(k)
        np.maximum.at(samples, group, data[:, _SAMPLES])
        rows = np.flatnonzero(keep)
        out = hyp.take(rows)
        od = out.data
        src = donor[rows]
        od[:, _ID] = data[src, _ID]
        od[:, _CONFIRMED] = np.maximum(data[src, _CONFIRMED], od[:, _CONFIRMED])
        od[:, _SAMPLES] = samples[group[rows]]
        od[:, _BORN] = data[src, _BORN]
        od[:, _START] = data[src, _START]
        od[:, _START_LOCAL] = data[src, _START_LOCAL]

        # A group with any member not started by a person standing where something always
        # stood carries no such restriction.
        open_ = np.zeros(k, bool)
        np.logical_or.at(open_, group, data[:, _ORIGIN] != 1.0)
        od[:, _ORIGIN] = np.where(open_[group[rows]], 0.0, 1.0)
        self.stats['merged'] += int(k - rows.size)
        return out, was_confirmed[src]


def _components(k: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components (label = smallest member index) of k nodes with edges a-b."""
    label = np.arange(k)
    while True:
        m = np.minimum(label[a], label[b])
        new = label.copy()
        np.minimum.at(new, a, m)
        np.minimum.at(new, b, m)
        new = new[new]
        if np.array_equal(new, label):
            return label
        label = new


def _finite_rows(xy, values=None):
    """Rows of ``xy`` (n, 2) and ``values`` (n,) that are finite (others dropped)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    ok = np.isfinite(xy).all(axis=1)
    if values is None:
        return xy[ok], None
    values = np.asarray(values, dtype=float).reshape(-1)
    if values.shape[0] != xy.shape[0]:
        values = np.ones(xy.shape[0])
    ok &= np.isfinite(values)
    return xy[ok], values[ok]
