"""Movement hypotheses: creation (paper Sec. 7) and management (Sec. 8), vectorised.

A hypothesis is a possible moving object: position, velocity (its Kalman filter,
``laser_tracker.core.kalman``), a weight 0..100 and the number of samples that support it.
All hypotheses live in one structured array (``core.tracking.state.Hypotheses``); one frame
of detections (``core.detections.Detections``: motion blobs, people, segments) updates them
all at once. Distances in Equations 2 and 3 are in ``distance_unit`` (the 10 cm grid cell:
METHOD.md Sec. 4), positions in the odometry frame.

Per frame (``HypothesisTracker.update(detections)``; the stream rules, such as time going
backwards, belong to the ``core.stages.Tracker`` stage around it), each step done by one of
the tracker's roles (``core.tracking``: association, sustaining, initiation, identity,
deletion, confirmation):

1. **Prediction** ``H_est`` of every hypothesis at the blobs' stamp.
2. **Blob weights**, Equation 2: ``B_weight = 100 - sum_i max(50 - dist(H_est_i, B_pos), 0)``
   clipped to 0..100; a blob above ``new_blob_threshold`` is *new*.
3. **Gating and splitting**: every blob within ``gate`` metres of a prediction supports that
   hypothesis; with several, the hypothesis splits, one copy per blob, each updated on its
   own (this follows both legs of a walker).
4. **Support**, Equation 3: ``H_weight += W_inc - W_dec * dist(B_pos, H_est)``, clipped to
   0..100, and the blob goes to the Kalman filter; the samples count grows by one.
5. **Wall penalty**: a hypothesis whose supporting (or creating) blob lies on a wall
   (``blobs.structure``: the blob's visible surface is a straight line running past it on
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
    measurement), each supporting blob adds one. Further rules (``core.tracking
    .confirmation``), each off at 0: ``person_min_travel`` / ``person_confirm_samples``,
    ``person_confirm_pairs`` (whatever started the hypothesis), ``view_travel_ratio``,
    ``ride_along_speed``, ``confirm_time``, ``confirm_min_speed``, ``confirm_min_travel``,
    ``duplicate_radius``, ``confirm_when_measured``.

Beyond the paper, person detections are measurements of their own kind (``person_*``), a
confirmed track without support is held on a scan segment (``segment_gate``,
``stop_radius``) instead of coasting, and a coasting track whose place the scan sees empty
(``seen_empty_radius``) or hidden behind something nearer (``report_hidden``) is not
reported (``core.tracking.visibility``).

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
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core import jit, kalman as kalman_kernels
from laser_tracker.core.detections import Detections
from laser_tracker.core.kalman import KalmanConfig, TrackFilter
from laser_tracker.core.tracking import association, frame as frame_kernels, identity, \
    initiation, sustaining, visibility
from laser_tracker.core.tracking.association import BlobAssociation, PersonAssociation
from laser_tracker.core.tracking.confirmation import Confirmation
from laser_tracker.core.tracking.deletion import Deletion
from laser_tracker.core.tracking.frame import Measurements
from laser_tracker.core.tracking.identity import Identity
from laser_tracker.core.tracking.initiation import Initiation
from laser_tracker.core.tracking.state import Hypotheses, Tracks
from laser_tracker.core.tracking.sustaining import Sustaining
from laser_tracker.core.tracking.visibility import Visibility

log = logging.getLogger(__name__)

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
    person_initial_weight: float = param(
        40.0, 'Weight of a hypothesis a person detection starts: a leg-shaped measurement of '
        'the object itself, not a pair of changed cells, so it survives the one missed '
        'detection of a scanner at 7.5 Hz or faster (coasting costs coast_rate x dt, 27 at '
        '7.5 Hz, and below remove_below it is gone). 0 = initial_weight (paper).',
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
        True, 'A blob that no hypothesis gates (none predicted within gate) is new, whatever '
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
    confirm_min_travel: float = param(0.3, 'A hypothesis started by motion blobs is confirmed '
                                      'only once it is this far (m, odometry frame) from '
                                      'where it was created: a moving object goes somewhere, '
                                      'while static clutter that seems to move (its blob '
                                      'shifting by a cell as cells flip at its edges, or by a '
                                      'scan-match error at range) stays within a few cells '
                                      '(people have their own rules). 0 = paper.', min=0.0,
                                      max=100.0)
    confirm_when_measured: bool = param(
        True, 'A hypothesis is confirmed only in a frame where a blob or a person detection '
        'supports it: the further rules (time, travel) are judged on a measured position, '
        'not on one extrapolated along a velocity while it coasts. false = paper (whose 4 '
        'samples are reached on a measurement anyway).')
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
        0.6, 'A hypothesis is confirmed only once it has lived this long (s) since it was '
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
    view_travel_ratio: float = param(
        0.5, 'A hypothesis started by motion blobs or by a person who walked in is confirmed '
        'only once it has moved, in the world, at least this fraction of the displacement '
        'the scanner\'s own motion since its start causes at the place where it started (how '
        'far a static object there has moved in the scanner\'s frame): from a moving robot, '
        'a static object also seems to change and to stand in space seen free before '
        '(parallax, resampling, registration error growing with the turn), while a mover '
        'goes on moving. The same fraction as difference.motion_depth. A stationary scanner '
        'is not affected. 0 = off (paper).', min=0.0, max=10.0)
    person_confirm_samples: int = param(
        0, 'A hypothesis started by a person detection is also confirmed once this many '
        'person detections of any kind (one leg or two) have supported it, though it was '
        'never seen walking. 0 = off: a person who stands in view from the start is '
        'confirmed by person_confirm_pairs (both legs seen), since a chair that a robot '
        'drives around stays detected as long as a standing person (30: such a person seen '
        'as one leg is confirmed after 4 s at 7.5 Hz, and so is the chair).',
        min=0, max=100000)
    person_confirm_time: float = param(
        0.3, 'A hypothesis a person detection started is confirmed once it has lived this '
        'long (s), instead of confirm_time: each of its samples was a leg shape, and it '
        'still waits for evidence that it walked or for both legs seen again and again; '
        'confirm_time guards against motion blobs that flicker. At 7.5 Hz the 4 samples '
        'take longer. 0 = confirm_time; with confirm_time 0 no time applies.', min=0.0,
        max=10.0)
    person_confirm_pairs: int = param(
        8, 'A hypothesis is also confirmed once this many detections of two legs (a pair '
        'within person_detector.pair_distance) off static background supported it, however '
        'it started (a person standing where the robot passes may first show as motion '
        'blobs): a person in view shows both legs from most sides, a post or a single leg of '
        'furniture one, and legs that have long stood in one place (a chair, a table) are '
        'static background and do not count. 0 = off.', min=0, max=100000)
    gait_spread: float = param(
        0.0, 'A person whose two legs\' separation has varied by this much (m), off static '
        'background, is walking (the legs swing; chair or table legs keep their distance): '
        'it may be confirmed without having moved person_min_travel. Off by default: on '
        'the real recordings it confirmed more false tracks (pose errors make legs seem to '
        'swing) and no more people. 0 = off.', min=0.0, max=2.0)
    person_kind_samples: int = param(
        2, 'Supports by person detections after which a track is of kind person.', min=1,
        max=1000)
    report_unseen: bool = param(
        True, 'Report a confirmed track that nothing measured in this scan (no blob, person '
        'detection or segment: it coasts on its velocity, hidden behind something or missed '
        'by the detector), as leg_tracker\'s publish_occluded does. false: such a track is '
        'reported as not confirmed until it is measured again (it lives on with its id): '
        'fewer false positives against annotations of the people in view, but a person '
        'hidden for a moment leaves tracks and the head.')
    report_hidden: bool = param(
        False, 'Report a confirmed track that nothing measured in this scan while the scan '
        'shows its position hidden: the beam towards it does not pass beyond the disc of '
        'seen_empty_radius around it, a beam through that disc returns from in front of it '
        'by more than that radius (farther than the object could have strayed off its '
        'prediction: not the object itself), and none from the disc or just in front of '
        'it. false: such a track is left out of tracks (reported as not confirmed; it lives '
        'on with its id and comes back when it is measured again): annotated recordings '
        'count the people in view, and it is no one in view. A track the detector missed, '
        'whose place the scan sees something at, stays reported. Off with '
        'seen_empty_radius 0. true: every coasting track is reported unless its place is '
        'seen empty (as leg_tracker\'s publish_occluded; paper).')
    background_hides: bool = param(
        True, 'With report_hidden false: a return from static background (where the scans '
        'had long seen something before this scan: the wall a person walked behind) nearer '
        'than a coasting track\'s position is not the object, which cannot have stood '
        'there that long, but something that hides it. false: a return within '
        'seen_empty_radius in front of the position may be the object. Off with '
        'report_hidden true.')
    silent_is_empty: bool = param(
        True, 'A coasting track whose disc of seen_empty_radius every beam crosses without '
        'a return (REP 117 +inf, or no measurement) is seen empty, as long as the scan '
        'returns from farther than the disc elsewhere (the place lies within the '
        'scanner\'s reach): an object there would have returned some beam; a leg is '
        'round, so some of it always faces the scanner, never all at grazing incidence. '
        'false: such a disc is no evidence (something dark may stand there). Off with '
        'seen_empty_radius 0.')
    seen_empty_radius: float = param(
        0.5, 'A confirmed track that nothing measured in this scan is left out of tracks '
        '(reported as not confirmed; it lives on with its id) while every beam through the '
        'disc of this radius (m) around it passes beyond the disc or returns nothing, and '
        'one at least passes beyond (or none returns: silent_is_empty): the scan sees that '
        'place empty, so the object is not '
        'there (it turned, or the track followed something that never was). A track hidden '
        'behind something nearer stays reported. Where a person may stand off a coasting '
        'prediction: the person_gate and segment_gate that would take them back. 0 = off '
        '(paper).', min=0.0, max=5.0)
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
    walker_time: float = param(
        0.0, 'A segment whose place the scans have seen occupied for at least this long (s; '
        'decayed as the static background is) does not hold a hypothesis that has not been '
        'measured standing (held where it stands, or slower than moving_speed) since before '
        'that place was first seen occupied: someone who has been walking all that time is '
        'not what has stood there, but may be hidden behind it (the edge of what they walked '
        'behind), so the track coasts. 1.5 s is how long a walking leg can hold one cell of '
        'the grid: a stance (under a second) plus crossing the 0.1 m cell at moving_speed '
        '(0.5 s). A track measured standing is still held there, however long it has stood. '
        '0 = off (any segment within reach holds it): on the real recordings it trades a '
        'few people for fewer tracks left on walls.', min=0.0, max=60.0)
    resume_time: float = param(
        4.0, 'A hypothesis confirmed within this time (s) of the loss of a confirmed track of '
        'the same kind, within resume_radius of that track\'s way since (from where it was '
        'last measured, on along its velocity then: it walked on or stopped), takes its id: a '
        'target lost for a moment (missed, hidden) keeps its identity. 0 = off.',
        min=0.0, max=60.0)
    resume_radius: float = param(
        1.0, 'Largest distance (m) between a lost track\'s way since it was lost and a '
        'newly confirmed hypothesis that resumes it (resume_time).', min=0.0, max=10.0)
    resume_confirms: bool = param(
        True, 'A person\'s hypothesis measured now within resume_radius of the way of a '
        'confirmed person\'s track lost within resume_time (from where that track was last '
        'measured, on along its velocity then) takes it over: the rules that ask for '
        'evidence of a walking person (person_min_travel, ride_along_speed) do not hold it '
        'back. A person whose track slipped off them for a scan is not a new person.')
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


@dataclass
class FrameResult:
    """What one tracker update reports."""

    stamp: float
    hypotheses: Hypotheses
    newly_confirmed: np.ndarray   # (j,) indices into hypotheses: confirmed this frame
    created: int                  # hypotheses created this frame
    bounded: bool                 # the max_hypotheses bound was hit


class HypothesisTracker:
    """Hypothesis creation and management over frames of detections (paper Sec. 7-9), by
    its roles (``core.tracking``)."""

    def __init__(self, config: HypothesisConfig | None = None,
                 kalman: KalmanConfig | None = None):
        self.config = config or HypothesisConfig()
        self.filter = TrackFilter(kalman or KalmanConfig())
        self.stats = {'created': 0, 'confirmed': 0, 'splits': 0, 'merged': 0,
                      'bound_hits': 0, 'resets': 0, 'blobs_dropped': 0, 'resumed': 0}
        role = (self.config, self.filter, self.stats)
        self.measurements = Measurements(*role)
        self.identity = Identity(*role)
        self.people = PersonAssociation(*role)
        self.blobs = BlobAssociation(*role, self.identity)
        self.sustaining = Sustaining(*role)
        self.initiation = Initiation(*role, self.identity)
        self.deletion = Deletion(*role)
        self.confirmation = Confirmation(*role)
        self.visibility = Visibility(*role)
        self.roles = (self.measurements, self.identity, self.people, self.blobs,
                      self.sustaining, self.initiation, self.deletion, self.confirmation,
                      self.visibility)
        self.reset()
        jit.compiled('tracking kernels', _exercise_kernels)

    def reset(self, reason: str | None = None) -> None:
        """Forget every hypothesis and the earlier frames (ids keep counting up)."""
        if reason:
            log.warning('tracker reset: %s', reason)
            self.stats['resets'] += 1
        self.hyp = Hypotheses.empty(self.filter.dim)
        self.left_out = (math.nan, np.zeros(0, bool))   # (stamp, mask over hyp)
        self.measurements.reset()
        self.initiation.reset()
        self.identity.reset()

    def reconfigure(self, config: HypothesisConfig, kalman: KalmanConfig) -> bool:
        """Use new parameters from the next frame. Returns True when the hypotheses must be
        reset (a new filter mode: their state vectors differ)."""
        reset = False
        if kalman != self.filter.config:
            new = TrackFilter(kalman)
            reset = new.dim != self.filter.dim
            self.filter = new
        self.config = config
        for role in self.roles:
            role.config, role.filter = config, self.filter
        return reset

    def update(self, detections: Detections) -> FrameResult:
        """One frame: the detections of one scan (odometry frame) -> updated hypotheses."""
        with np.errstate(invalid='ignore'):      # NaN marks what is absent (no structure)
            frame = self.measurements.read(detections)
            hyp, t = self.hyp, frame.stamp
            pred = self.filter.predict(hyp.state, hyp.t_state, t)    # H_est (Sec. 9)
            people = self.people.associate(hyp, pred, frame)         # and their legs' blobs
            blobs = self.blobs.associate(hyp, pred, frame, people)   # Eq. 2, gating
            updated = [self.people.support(hyp, pred, frame, people),
                       self.blobs.support(hyp, frame, blobs),        # Eq. 3, Kalman, splits
                       *self.sustaining.sustain(hyp, pred, frame, blobs.unsupported)]
            born = [self.initiation.from_blobs(frame, blobs.new, blobs.weight),   # Sec. 7
                    self.initiation.from_people(frame, people.fresh)]
            hyp = self.identity.merge(Hypotheses.concat(updated + born, self.filter.dim))
            self._note_standing(hyp, t)
            hyp, removed, bounded = self.deletion.delete(hyp, t)
            if removed is not None:
                self.identity.remember_lost(removed, t)
            newly = self.confirmation.confirm(hyp, frame, self.identity.continuing(hyp, t))
            self.identity.resume(hyp, newly, t)
            self.left_out = (t, self.visibility.left_out(hyp, frame))
        self.hyp = hyp
        self.initiation.remember(frame)
        self.measurements.remember(frame)
        return FrameResult(stamp=t, hypotheses=hyp, newly_confirmed=newly,
                           created=sum(map(len, born)), bounded=bounded)

    def _note_standing(self, hyp: Hypotheses, t: float) -> None:
        """``t_still``: now for the hypotheses measured standing this frame (held where they
        stand, or measured slower than ``moving_speed``)."""
        speed2 = (hyp.velocity ** 2).sum(axis=1)
        measured = hyp.t_state >= t
        standing = hyp.stopped | (measured & (speed2 < self.config.moving_speed ** 2))
        if standing.any():
            hyp.t_still = np.where(standing, t, hyp.t_still)

    def _left_out(self, stamp: float) -> np.ndarray:
        """The last frame's left-out mask (``tracking.visibility``) when ``stamp`` is that
        frame's, else none."""
        stamp_then, mask = self.left_out
        if stamp == stamp_then and mask.shape[0] == len(self.hyp):
            return mask
        return np.zeros(len(self.hyp), bool)

    def report(self, stamp: float) -> Tracks:
        """The hypotheses as :class:`Tracks` at ``stamp`` (the frame just updated); with
        ``report_unseen`` false a confirmed track that nothing measured at ``stamp`` (its
        filter's ``t_state`` is older) is reported as not confirmed, and so is one whose
        place the scan sees empty (``seen_empty_radius``) or, with ``report_hidden`` false,
        sees hidden (``tracking.visibility``)."""
        h, c = self.hyp, self.config
        speed2 = (h.velocity ** 2).sum(axis=1)
        return Tracks(stamp=float(stamp), track_id=h.track_id.copy(),
                      position=h.position.copy(), velocity=h.velocity.copy(),
                      covariance=self.filter.position_covariance(h.P, h.t_state, stamp),
                      weight=h.weight.copy(), samples=h.samples.copy(),
                      confirmed=h.confirmed & (c.report_unseen | (h.t_state >= stamp))
                      & ~self._left_out(stamp),
                      moving=(speed2 >= c.moving_speed ** 2) & ~h.stopped,
                      kind=np.where(h.is_person(c.person_kind_samples),
                                    'person', 'object').astype(object))


def _exercise_kernels() -> None:
    """Every kernel of the tracker's roles and of the paper's filter called once with each
    kind of argument a frame gives it (the fields of 0, 1 and more hypotheses are arrays of
    different layouts to numba), so that no frame compiles."""
    for n in (0, 1, 3):
        h = Hypotheses.empty(2, n)
        h.P, h.weight, h.samples, h.spread = 0.006 * np.eye(2), 50.0, 1, np.nan
        r, xy, mask = h.rows, np.zeros((n, 2)), np.zeros(n, bool)
        kalman_kernels._predict_positions(r['state'], r['t_state'], 1.0)
        kalman_kernels._correct_velocity(r['state'], r['P'], r['t_state'], xy, 1.0, 0.1, 0.1,
                                         mask, r['state'], r['P'])
        kalman_kernels._correct_velocity(r['state'], r['P'], r['t_state'], xy, 1.0, 0.1, 0.1,
                                         kalman_kernels._NOT_STILL, r['state'], r['P'])
        association._eq2_and_gates(xy, xy, r['stopped'], mask, mask, 50.0, 0.1, 60.0, True,
                                   0.7, 0.5)
        association._claims(xy, xy, np.ones(n), mask, xy, 0.5, 0.5, 0.45)
        association._equation_3(r['weight'], r['samples'], np.ones(n), 60.0, 150.0)
        association._person_measured(r['weight'], r['samples'], r['person_samples'],
                                     r['pair_samples'], r['spread'], r['origin'], xy, xy,
                                     mask, np.ones(n), 60.0, 150.0, 0.25, 0.1)
        frame_kernels._into_frame(r['position'], 0.0, 0.0, 1.0, 0.0)
        frame_kernels._into_frame(xy, 0.0, 0.0, 1.0, 0.0)
        frame_kernels._all_finite(xy, np.ones(n))
        frame_kernels._kept_place(xy, xy, xy, 0.0, 0.0, 1.0, 0.0, 1.0, 0.05)
        identity._duplicates(r['position'], r['state'], r['supported'], r['weight'],
                             r['samples'], r['track_id'], r['confirmed'], r['origin'], 0.09,
                             0.25)
        sustaining._holding_segments(np.arange(n), xy, r['position'], r['person_samples'],
                                     r['confirmed'], xy, np.ones(n), np.zeros(n), 2, 0.02,
                                     0.5, 0.15, r['t_still'], 1.0, 1.5)
        initiation._pairs(xy, np.ones(n, bool), xy, 0.6, 0.1)
        visibility._left_out(xy, np.linspace(-1.0, 1.0, 5), np.full(5, 3.0),
                              np.zeros(5, np.bool_), 0.5, True, 3.0)
    filter = TrackFilter(KalmanConfig())
    state, P = filter.initial(np.ones((1, 2)), np.zeros((1, 2)), np.ones(1))
    filter.correct(state, P, np.zeros(1), np.ones((1, 2)), 1.0)
    x, P = kalman_kernels.predict_velocity(state[:, 2:], P, 0.1)
    kalman_kernels.update_velocity(x, P, np.ones((1, 2)), 0.1)
