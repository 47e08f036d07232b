"""The pipeline's stages: each owns its input stream (``core.stream``) and its algorithm.

=============  ==========================================  =================================
stage          input -> output                             algorithm (paper section)
=============  ==========================================  =================================
``EgoMotion``  scans + odometry -> :class:`StampedPose`     ``egomotion`` (Sec. 4)
``Detector``   scan + its pose -> :class:`Detection`        ``grid``, ``difference``,
                                                           ``blobs`` (Sec. 5-6),
                                                           ``person_detector``
``Tracker``    detections -> ``hypotheses.FrameResult``     ``hypotheses``, ``kalman``
                                                           (Sec. 7-9)
``Head``       tracks + pose -> ``head.HeadCommand``        ``head`` (Sec. 10.3)
=============  ==========================================  =================================

Each has ``reset()``, ``update(...)`` (None when the item is skipped) and ``reconfigure(...)``
(new parameters applied from the next item; whatever the change makes stale is rebuilt), and
answers its stream's misbehaviour itself (``core.stream``: time going backwards restarts the
stage, a duplicate stamp is skipped, a gap drops what it makes stale, an invalid stamp is
skipped), counting every case in its ``events`` (an ``EventLog``). Offline replay
(``core.pipeline.Pipeline``) and the ROS nodes (convert -> stage -> convert) therefore
behave the same.

The ego-motion stage also holds scans until the odometry that covers them has arrived
(``stream.OdometryWait``; ``add_scan`` / ``add_odometry`` / ``poll`` with arrival times),
and says when its pose chain restarted (``StampedPose.quality.restarted``): downstream
stages then forget their odometry-frame history, as positions before and after are
unrelated.
"""
from __future__ import annotations

import logging
import math
import re
import time
from dataclasses import dataclass, field

import numpy as np

from laser_tracker.core import jit
from laser_tracker.core.blobs import BlobConfig, segment
from laser_tracker.core.detections import Blobs, Detections, People, Segments, View
from laser_tracker.core.difference import (DifferenceConfig, PoseQuality, StaticBackground,
                                           changed_with_history, difference_map,
                                           people_in_odometry, pose_quality, pose_trusted,
                                           without_lone_returns)
from laser_tracker.core.egomotion import EgoMotionConfig, EgoMotionEstimate, EgoMotionEstimator
from laser_tracker.core.grid import (GridBuilder, GridConfig, GridHistory, relative_motion,
                                     transform_grid)
from laser_tracker.core.head import HeadCommand, HeadConfig, HeadPointer
from laser_tracker.core.hypotheses import FrameResult, HypothesisConfig, HypothesisTracker
from laser_tracker.core.kalman import KalmanConfig
from laser_tracker.core.person_detector import (DetectorModelError, LegClassifier,
                                                PersonDetections, PersonDetector,
                                                PersonDetectorConfig)
from laser_tracker.core.scan import Scan
from laser_tracker.core.segmentation import SegmentConfig, segments_of
from laser_tracker.core.self_mask import SelfMask, SelfMaskConfig, without_body
from laser_tracker.core.stream import (BACKWARDS, FIRST, GAP, SKIPPED, ClockOffset, EventLog,
                                       OdometryWait, ScanThinning, StreamRules)

log = logging.getLogger(__name__)

#: Why detection leaves out a scan of a fast scanner (``Detector.skipped``).
THINNED = 'thinned to difference.max_scan_rate'

#: Scan points this close (m) to a motion blob do not join the static background.
MOVER_RADIUS = 0.4
#: Odometry and scans whose stamps, against their arrival, differ by more than this (s: the
#: range of ``ego_motion.odom_latency``) are of different clocks.
CLOCK_TOLERANCE = 2.0
#: A scanner silent this long (s of scan time) has stopped: a scan of another frame then
#: starts the pipeline afresh on that scanner (a driver restarted under another frame name).
#: The default ``difference.max_gap``: after such a gap nothing of the old history is used.
SCANNER_SILENCE = 2.0


# ------------------------------------------------------------------------------ ego-motion


@dataclass
class StampedPose:
    """The scanner pose of one scan (the ego-motion stage's output; the ``ego_motion`` topic).

    ``pose``: scanner pose (x, y, theta) in the odometry frame; ``motion``: motion since the
    previous posed scan in the previous scanner frame, over ``dt`` seconds, with covariance
    ``motion_covariance``; ``pose_covariance``: the pose's covariance in the odometry frame
    (motion covariances accumulated); ``quality``: what the detection gate reads.
    ``stamp_ns``: the scan's exact stamp when known (messages are restamped with it).
    ``body``: per beam of the scan, the farthest range of the robot's own body (NaN: none;
    ``core.self_mask``): detection masks those returns as ego-motion did. ``mirrored``: the
    pose is that of the scan turned over (``ego_motion.mount_upside_down``, ``Scan.mirrored``),
    and detection turns the scan over too. ``range_noise``: the scanner's range noise near the
    robot as the self-mask measures it (m, one sigma; None: not measured yet).
    """

    stamp: float
    pose: np.ndarray
    motion: np.ndarray
    motion_covariance: np.ndarray
    pose_covariance: np.ndarray
    quality: PoseQuality
    source: str = ''
    reason: str = ''
    dt: float = 0.0
    frame_id: str = 'odom'
    child_frame_id: str = 'laser'
    stamp_ns: int | None = None
    estimate: EgoMotionEstimate | None = field(default=None, repr=False)
    body: np.ndarray | None = field(default=None, repr=False)
    mirrored: bool = False
    range_noise: float | None = None


class EgoMotion:
    """Stage: scans and odometry -> the scanner pose of each scan (paper Sec. 4).

    ``update(scan)`` estimates at once; ``add_scan(scan, arrival)`` first lets the scan wait
    (at most ``odom_wait`` seconds of the arrival clock) for odometry stamped at or after it,
    and returns every ``(scan, pose)`` that became ready; ``add_odometry`` and ``poll`` may
    release waiting scans too. A pose is None for a scan that was skipped or got no pose.
    Stream rules: an invalid or duplicate scan stamp is skipped; time going backwards
    restarts the estimator (the next pose says ``restarted``); non-finite odometry is skipped.
    The robot's own body (``core.self_mask``) is masked before the scan is matched, and
    learnt from every scan that got a pose.

    One scanner per pipeline: the stage follows the frame of the first scan, and a scan of
    another frame (a second scanner publishing on the same topic) is skipped with a warning,
    since matching one scanner's view against another's moves every wall. Once the followed
    scanner has been silent for ``SCANNER_SILENCE`` the stage restarts on the new frame.
    """

    def __init__(self, config: EgoMotionConfig | None = None, odom_wait: float = 0.0,
                 frame_id: str = 'odom', self_mask: SelfMaskConfig | None = None):
        self.config = config or EgoMotionConfig()
        self.self_mask = self._new_self_mask(self_mask or SelfMaskConfig())
        self.frame_id = frame_id
        self.events = EventLog(log, 'ego-motion: ')
        self.estimator = EgoMotionEstimator(self.config, self.self_mask)
        self.rules = StreamRules()
        self.wait: OdometryWait = OdometryWait(odom_wait)
        self.clocks = ClockOffset(CLOCK_TOLERANCE)
        self.sources: dict[str, int] = {}
        self._restart_pending = False
        self.skipped: str | None = None     # why the last update returned None
        self.scan_frame: str | None = None  # the followed scanner's frame
        self._scan_frame_last = -math.inf   # stamp of its latest scan
        warm_up_once('ego-motion stage', _warm_up_ego_motion)

    # ---------------------------------------------------------------- stream
    def add_odometry(self, stamp: float, pose, arrival: float | None = None) -> list:
        """Feed one odometry sample (platform pose in the odometry frame)."""
        xyt = _planar(pose)
        if xyt is None or not (math.isfinite(xyt[0]) and math.isfinite(xyt[1])
                               and math.isfinite(xyt[2]) and math.isfinite(stamp)):
            self.events.note('odometry skipped', f'not a finite planar pose: {stamp!r}, '
                             f'{list(xyt) if xyt else np.asarray(pose).tolist()!r}')
            return []
        stamp = float(stamp)
        if arrival is not None:
            if self.clocks.add_odometry(stamp, arrival):
                self._clock_changed()
            stamp += self.clocks.offset
        self.estimator.add_finite_odometry(stamp, *xyt)
        if arrival is None:
            return []
        return self._estimate_all(self.wait.add_odometry(arrival, stamp))

    def _clock_changed(self) -> None:
        """The odometry's clock is found to differ from the scans' (``ClockOffset``): its
        stamps are moved onto the scans' clock from now on, and the samples stored before are
        forgotten."""
        offset = self.clocks.offset
        self.estimator.odometry.clear()
        self.wait.forget_odometry()
        if offset:
            self.events.note('odometry clock', f'odometry stamps are {-offset:+.3f} s from '
                             "the scans' (against their arrival): another clock; read on the "
                             "scans' clock from now on")
        else:
            self.events.note('odometry clock', "odometry stamps agree with the scans' again")

    def add_scan(self, scan: Scan, arrival: float | None = None, tag=None) -> list:
        """Queue ``scan`` behind its odometry; returns ``(scan, tag, pose or None)`` of every
        scan that is ready (``tag`` travels with the scan, for the caller)."""
        if arrival is not None and math.isfinite(scan.stamp) \
                and self.clocks.add_scan(scan.stamp, arrival):
            self._clock_changed()
        if arrival is None or self.wait.max_wait <= 0.0:
            return [(scan, tag, self.update(scan))]
        return self._estimate_all(self.wait.add_scan(arrival, scan.stamp, (scan, tag)))

    def poll(self, now: float) -> list:
        """Scans whose wait is over at ``now`` (the arrival clock)."""
        return self._estimate_all(self.wait.release(now))

    def flush(self) -> list:
        """Every waiting scan (end of a recording)."""
        return self._estimate_all(self.wait.flush())

    def _estimate_all(self, items) -> list:
        return [(scan, tag, self.update(scan)) for scan, tag in items]

    def reset(self, reason: str = '') -> None:
        """Restart the pose chain (odometry history is kept)."""
        if reason:
            self.events.note('restart', reason)
        self.estimator.reset(reason or 'reset requested')
        self.rules.reset()
        self._restart_pending = True

    def _new_self_mask(self, config: SelfMaskConfig) -> SelfMask:
        c = self.config
        return SelfMask(config, (c.mount_x, c.mount_y, c.mount_yaw))

    def reconfigure(self, config: EgoMotionConfig, odom_wait: float | None = None,
                    self_mask: SelfMaskConfig | None = None) -> None:
        """New parameters from the next scan: the estimator is rebuilt (its map and pose chain
        restart, which downstream stages see as a restart), odometry history is kept; a new
        self-mask configuration (or mount) starts the learnt body afresh."""
        if odom_wait is not None:
            self.wait.max_wait = float(odom_wait)
        changed = config != self.config
        if self_mask is not None and (changed or self_mask != self.self_mask.config):
            self.config = config
            self.self_mask = self.estimator.self_mask = self._new_self_mask(self_mask)
        if not changed:
            return
        odometry = self.estimator.odometry
        self.config = config
        self.estimator = EgoMotionEstimator(config, self.self_mask)
        self.estimator.odometry = odometry
        odometry.config = config
        self.reset('parameters changed')

    # ---------------------------------------------------------------- one scan
    def _of_followed_scanner(self, scan: Scan) -> bool:
        """Whether ``scan`` comes from the followed scanner (adopting its frame when there is
        none yet, or when the followed one has fallen silent: the pipeline restarts)."""
        frame = scan.frame_id.lstrip('/')
        if frame == self.scan_frame:
            if math.isfinite(scan.stamp):
                self._scan_frame_last = scan.stamp
            return True
        silent = scan.stamp - self._scan_frame_last
        if self.scan_frame is not None and not silent > SCANNER_SILENCE:
            self.skipped = (f'a scan of frame {frame!r} (one scanner per pipeline: this one '
                            f'follows {self.scan_frame!r})')
            self.events.note('scan of another scanner skipped',
                             f'frame {frame!r} on the topic of {self.scan_frame!r}, which '
                             'this pipeline follows: give each scanner its own topic and '
                             'pipeline, or merge their scans into one first')
            return False
        if self.scan_frame is not None:
            self.events.note('scanner changed', f'scans of {self.scan_frame!r} stopped '
                             f'{silent:.1f} s ago; following {frame!r} from now on')
            self.reset(f'another scanner ({frame!r})')
            self.self_mask = self.estimator.self_mask = self._new_self_mask(
                self.self_mask.config)
        self.scan_frame = frame
        self._scan_frame_last = scan.stamp if math.isfinite(scan.stamp) else -math.inf
        return True

    def update(self, scan: Scan) -> StampedPose | None:
        """The pose of ``scan``, or None (``skipped`` says why)."""
        self.skipped = None
        if not self._of_followed_scanner(scan):
            return None
        verdict = self.rules.screen(scan.stamp, 'scan', self.events)
        if verdict in SKIPPED:
            self.skipped = f'{verdict} stamp'
            return None
        if verdict == BACKWARDS:
            self.reset(f'time went backwards ({self.rules.last:.3f} -> {scan.stamp:.3f} s)')
        mirrored = bool(self.config.mount_upside_down)
        if mirrored:
            scan = scan.mirrored()
        # the body is masked, the scan matched and the body learnt in one kernel call
        est = self.estimator.update(scan)
        source = str(est.source)
        self.sources[source] = self.sources.get(source, 0) + 1
        x, y, theta = est.pose.tolist()
        if not (est.ok and math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
            self.skipped = 'no pose: ' + _generic(est.reason)
            self.events.note('no pose', _generic(est.reason))
            return None
        self.rules.accept(scan.stamp)
        quality = pose_quality(est)
        if self._restart_pending:
            quality = PoseQuality(quality.variance, quality.unmatched, True)
            self._restart_pending = False
        return StampedPose(stamp=float(scan.stamp), pose=est.pose, motion=est.motion,
                           motion_covariance=est.covariance,
                           pose_covariance=est.pose_covariance, quality=quality,
                           source=source, reason=str(est.reason), dt=float(est.dt),
                           frame_id=self.frame_id, child_frame_id=scan.frame_id,
                           stamp_ns=scan.stamp_ns, estimate=est,
                           body=self.self_mask.applied, mirrored=mirrored,
                           range_noise=self.self_mask.range_noise)


# ------------------------------------------------------------------------------- detection


@dataclass
class Detection:
    """Detection output for one scan; grids only when requested."""

    detections: Detections
    changed: int                       # cells in the difference map
    grid: np.ndarray | None = None
    previous: np.ndarray | None = None     # previous grid in the current scanner frame
    difference: np.ndarray | None = None   # Equation 1 (bool)
    changed_cells: np.ndarray | None = None  # flat indices of the cells that made the blobs
    gated: bool = False                # pose not trusted: no changes reported
    persons: object | None = None      # person_detector.PersonDetections (scanner frame)
    scan: Scan | None = None           # the scan as detection used it (turned over: mirrored)


class Detector:
    """Stage: a scan and its pose -> what moved and who is there (paper Sec. 5-6: grid,
    Eq. 1, blobs; people by the shape of their legs; the scan's compact segments).

    Keeps the previous grids (in their own frames, with their poses). Stream rules: an
    invalid or duplicate stamp is skipped; time going backwards, a gap longer than
    ``difference.max_gap`` or a restarted pose chain drops the grid history (the next scan
    is a first scan). People and segments need no history and no trusted pose: they are
    reported on every scan (in the odometry frame of the scan's pose). A person-detector
    model that cannot be loaded leaves the motion method running, with a warning.
    """

    def __init__(self, grid: GridConfig | None = None,
                 difference: DifferenceConfig | None = None,
                 blobs: BlobConfig | None = None,
                 persons: PersonDetectorConfig | None = None, frame_id: str = 'odom',
                 times: dict | None = None, segments: SegmentConfig | None = None):
        self.times = times   # stage -> seconds, accumulated when given (profiling)
        self.events = EventLog(log, 'detection: ')
        self.frame_id = frame_id
        self.grid_config = grid or GridConfig()
        self.difference_config = difference or DifferenceConfig()
        self.blob_config = blobs or BlobConfig()
        self.segment_config = segments or SegmentConfig()
        self.rules = StreamRules(self.difference_config.max_gap)
        self.thinning = ScanThinning(self.difference_config.max_scan_rate)
        self.skipped: str | None = None
        self._load_person_detector(persons or PersonDetectorConfig())
        self._build()
        jit.compiled('detection kernels', _exercise_detection)
        warm_up_once('detection stage', _warm_up_detection)

    def _load_person_detector(self, config: PersonDetectorConfig) -> None:
        self.person_config = config
        self.person_detector = None
        if not config.enabled:
            return
        try:
            self.person_detector = PersonDetector(config, segments=self.segment_config)
        except DetectorModelError as exc:
            self.events.note('person detector off', f'{exc}; the motion method runs alone')

    def _build(self) -> None:
        d = self.difference_config
        self.depth = max(d.max_history, d.memory + 1)
        self.builder = GridBuilder(self.grid_config, keep=self.depth + 1,
                                   footprints=d.footprint)
        self.background: StaticBackground | None = None      # made anew for a new geometry
        self.reset()

    def reset(self) -> None:
        self.history = GridHistory(self.builder, self.depth)   # earlier grids, newest first
        d = self.difference_config
        if d.static_time <= 0:
            self.background = None
        elif self.background is not None:       # the same configuration: its memory reused
            self.background.clear()
        else:
            self.background = StaticBackground(self.grid_config.resolution, d)
        # People detected in the last difference.walked_out_window seconds: x, y, stamp and
        # the scanner pose (odometry frame).
        self.recent_people = np.zeros((0, 6))
        self.rules.reset()
        self.thinning.reset()

    @property
    def previous(self):
        return self.history[0] if len(self.history) else None

    def reconfigure(self, grid: GridConfig, difference: DifferenceConfig,
                    blobs: BlobConfig, persons: PersonDetectorConfig | None = None,
                    segments: SegmentConfig | None = None) -> None:
        """New parameters from the next scan; a new grid geometry or memory depth drops the
        grid history; a new person-detector or segment configuration reloads the person
        detector."""
        reload = segments is not None and segments != self.segment_config
        if segments is not None:
            self.segment_config = segments
        if persons is not None and (reload or persons != self.person_config):
            self._load_person_detector(persons)
        elif reload:
            self._load_person_detector(self.person_config)
        old = self.difference_config
        rebuild = (grid != self.grid_config or difference.memory != old.memory
                   or difference.max_history != old.max_history
                   or difference.footprint != old.footprint       # the ray tables' spans
                   or (difference.static_time, difference.static_occupied,
                       difference.static_max_step)
                   != (old.static_time, old.static_occupied, old.static_max_step))
        self.grid_config, self.difference_config, self.blob_config = grid, difference, blobs
        self.rules.max_gap = difference.max_gap
        self.thinning.max_rate = difference.max_scan_rate
        if rebuild:
            self.events.note('history dropped', 'grid parameters changed', logging.INFO)
            self._build()

    def update(self, scan: Scan, pose: StampedPose,
               want_grids: bool = False) -> Detection | None:
        """Grid of ``scan``, Eq. 1 against the previous grid, blobs (odometry frame).

        When ``difference.pose_gate`` does not trust the pose (``pose.quality``), the grid is
        built and kept as history as usual but no change is reported. A pose of the scan
        turned over (``pose.mirrored``) turns a scan that passed the stream's rules and the
        thinning over before its grid is built.
        """
        self.skipped = None
        verdict = self.rules.screen(scan.stamp, 'scan', self.events)
        if verdict in SKIPPED:
            self.skipped = f'{verdict} stamp'
            return None
        if verdict == BACKWARDS:
            self.events.note('restart', 'time went backwards')
            self.reset()
        elif verdict == GAP:
            self.events.note('history dropped', f'gap of {scan.stamp - self.rules.last:.2f} s '
                             f'> difference.max_gap')
            self.reset()
        elif pose.quality.restarted and verdict != FIRST:
            self.events.note('history dropped', 'the ego-motion pose chain restarted')
            self.reset()
        if not self.thinning.use(scan.stamp):
            self.skipped = THINNED
            self.events.note('scans thinned', f'a scanner at {1.0 / self.thinning.period:.1f} '
                             f'Hz: detection uses at most {self.thinning.max_rate:g} scans a '
                             'second (difference.max_scan_rate)', logging.INFO)
            return None
        self.rules.accept(scan.stamp)
        if pose.mirrored:
            scan = scan.mirrored()
        measured = scan
        view = View.of_scan(scan)           # the robot's body hides what lies behind it
        scan = _without_body(scan, pose.body)
        at = np.asarray(pose.pose, dtype=float)
        det = self._detect(scan, at, want_grids, pose.quality)
        det.scan = measured
        self._people_and_segments(scan, at, det)
        det.detections.view = self._on_background(view, at, float(scan.stamp))
        self._add_to_background(at, float(scan.stamp), det)
        det.detections.frame_id = pose.frame_id or self.frame_id
        det.detections.stamp_ns = scan.stamp_ns
        det.detections.restarted = bool(pose.quality.restarted)
        if det.gated:
            self.events.note('gated', 'ego-motion pose not trusted: no blobs', logging.DEBUG)
        return det

    def _people_and_segments(self, scan: Scan, pose: np.ndarray, det: Detection) -> None:
        """People (by leg shape) and compact segments of ``scan`` (without the returns the
        self-mask took out of ``det.scan``, which the person detector is told of: they still
        hide what lies behind them), odometry frame."""
        t0 = time.perf_counter() if self.times is not None else 0.0
        d = det.detections
        if self.person_detector is not None:
            masked = _masked_returns(det.scan, scan) if self.person_config.masked_edge \
                else None
            people = self.person_detector.detect(scan, masked)
            det.persons = people
            leg = people.leg_probability
        else:                                       # no people: the segments alone
            people = PersonDetections.empty()
            people.leg_xy = segments_of(scan, self.segment_config).xy
            leg = np.zeros(people.leg_xy.shape[0])
        c = self.difference_config
        stamp = float(scan.stamp)
        # walked out: only with people now and people before (the beams' silence is read then)
        ask = not det.gated and people.xy.shape[0] > 0 and self.recent_people.shape[0] > 0
        walked_out = (c.walked_out_window if ask else 0.0, c.walked_out_radius,
                      c.walked_out_speed)
        xy, free, static, spread, segments = \
            people_in_odometry(people, pose, stamp, self.history, self.background,
                               c.motion_depth, self.recent_people, walked_out,
                               scan.silent() if ask else _NO_BEAMS, c.footprint)
        if self.person_detector is not None:
            d.people = People(xy=xy, confidence=people.confidence, free=free, spread=spread,
                              static=static)
            self._remember_people(xy, stamp, pose)
        occupied = self.background.counts(segments, stamp) \
            if self.background is not None and segments.shape[0] else _NO_OCCUPANCY
        d.segments = Segments(xy=segments, leg=leg, occupied=occupied)
        if self.times is not None:
            self.times['persons'] += time.perf_counter() - t0

    def _on_background(self, view: View, pose: np.ndarray, stamp: float) -> View:
        """``view`` with the beams whose return lies on static background marked (before
        this scan joins it)."""
        if self.background is not None and len(view):
            view.background = self.background.on_returns(view.bearing, view.reach, pose, stamp)
        return view

    def _remember_people(self, xy: np.ndarray, stamp: float, pose: np.ndarray) -> None:
        """This scan's people join those of the last ``walked_out_window`` seconds."""
        window = self.difference_config.walked_out_window
        if window <= 0:
            return
        recent = self.recent_people
        keep = stamp - recent[:, 2] < window
        rows = np.empty((xy.shape[0], 6))
        rows[:, :2], rows[:, 2], rows[:, 3:] = xy, stamp, pose
        self.recent_people = np.concatenate((recent[keep], rows))

    def _add_to_background(self, pose: np.ndarray, stamp: float, det: Detection) -> None:
        """This scan's end points join the static background, except those of what moves
        (within ``MOVER_RADIUS`` of a motion blob): people who keep passing the same spot (a
        corridor) do not make it static."""
        if self.background is not None:
            self.background.add(self.history[0].points, stamp, pose, det.detections.blobs.xy,
                                MOVER_RADIUS)

    def _detect(self, scan: Scan, pose: np.ndarray, want_grids: bool,
                quality: PoseQuality) -> Detection:
        res = self.grid_config.resolution
        cells = self.builder.cells
        times = self.times
        t0 = time.perf_counter() if times is not None else 0.0
        stamp = float(scan.stamp)
        frame = self.builder.build(scan, pose)
        history = self.history
        previous = history[0] if len(history) else None
        gated = not pose_trusted(quality, self.difference_config)
        if previous is None or gated:
            det = Detection(Detections(stamp, pose, frame_id=self.frame_id), 0,
                            gated=gated and previous is not None)
            if want_grids:
                self._grids(det, frame, previous, pose)
            history.push(frame)
            if times is not None:
                times['grid'] += time.perf_counter() - t0
            return det
        t1 = time.perf_counter() if times is not None else 0.0
        d_cells = changed_with_history(frame, stamp, pose, history, self.difference_config,
                                       self.background)
        if self.difference_config.ignore_lone_returns:
            d_cells = without_lone_returns(d_cells, frame, scan,
                                           self.segment_config.jump_distance)
        t2 = time.perf_counter() if times is not None else 0.0
        if d_cells.size:
            blobs = segment(d_cells, cells, res, pose, scan.stamp, self.blob_config,
                            frame.points)
        else:
            blobs = Blobs.empty()
        if times is not None:
            t3 = time.perf_counter()
            times['grid'] += t1 - t0
            times['difference'] += t2 - t1
            times['blobs'] += t3 - t2
        det = Detection(Detections(stamp, pose, blobs, frame_id=self.frame_id),
                        int(d_cells.size))
        if want_grids:
            self._grids(det, frame, previous, pose)
            det.changed_cells = d_cells.copy()
        history.push(frame)
        return det

    def _grids(self, det: Detection, frame, previous, pose: np.ndarray) -> None:
        """The whole grids of ``det`` (on request): this scan's, the previous one in this
        scan's frame, and Eq. 1 between them."""
        det.grid = frame.grid.copy()
        if previous is not None:
            motion = relative_motion(self.builder.meta[previous.index], pose)
            det.previous = transform_grid(previous.grid, motion,
                                          self.grid_config.resolution)
            det.difference = difference_map(det.grid, det.previous)


# -------------------------------------------------------------------------------- tracking


class Tracker:
    """Stage: detections -> movement hypotheses (paper Sec. 7-9).

    Stream rules: an invalid or duplicate stamp is skipped (a second publisher on the blobs
    topic changes nothing); time going backwards, a gap longer than ``hypotheses.max_gap``
    or blobs of a restarted pose chain start the hypotheses afresh (ids keep counting up).
    """

    def __init__(self, hypotheses: HypothesisConfig | None = None,
                 kalman: KalmanConfig | None = None):
        self.events = EventLog(log, 'tracking: ')
        self.hypotheses = HypothesisTracker(hypotheses, kalman)
        self.rules = StreamRules(self.hypotheses.config.max_gap)
        self.last: FrameResult | None = None
        self.skipped: str | None = None
        warm_up_once('tracking stage', _warm_up_tracking)

    @property
    def config(self) -> HypothesisConfig:
        return self.hypotheses.config

    @property
    def stats(self) -> dict:
        return self.hypotheses.stats

    def reset(self, reason: str = '') -> None:
        if reason:
            self.events.note('restart', reason)
        self.hypotheses.reset()
        self.rules.reset()

    def reconfigure(self, hypotheses: HypothesisConfig, kalman: KalmanConfig) -> None:
        """New parameters from the next frame; a new filter mode restarts the hypotheses
        (their state vectors differ)."""
        self.rules.max_gap = hypotheses.max_gap
        if self.hypotheses.reconfigure(hypotheses, kalman):
            self.reset('the Kalman filter mode changed')

    def tracks(self):
        """The hypotheses after the last update as ``hypotheses.Tracks``."""
        stamp = self.last.stamp if self.last is not None else math.nan
        return self.hypotheses.report(stamp)

    def update(self, detections: Detections) -> FrameResult | None:
        self.skipped = None
        stamp = float(detections.stamp)
        verdict = self.rules.screen(stamp, 'blobs', self.events)
        if verdict in SKIPPED:
            self.skipped = f'{verdict} stamp'
            return None
        if verdict == BACKWARDS:
            self.reset(f'time went backwards ({self.rules.last:.3f} -> {stamp:.3f} s)')
        elif verdict == GAP:
            self.reset(f'gap of {stamp - self.rules.last:.2f} s > hypotheses.max_gap')
        elif detections.restarted and verdict != FIRST:
            self.reset('the ego-motion pose chain restarted')
        self.rules.accept(stamp)
        self.last = self.hypotheses.update(detections)
        if self.last.bounded:
            self.events.note('hypothesis bound reached', f't={stamp:.3f} s')
        return self.last


# ------------------------------------------------------------------------------ active head


class Head:
    """Stage: confirmed tracks and the platform pose -> a leading pan/tilt command (Sec. 10.3).

    Stream rules: poses and tracks with invalid stamps are skipped; tracks are aimed at only
    with a pose at most ``max_pose_age`` seconds from them; time going backwards (in either
    stream) restarts the pointer (target choice and capture counts).
    """

    def __init__(self, config: HeadConfig | None = None, max_pose_age: float = 1.0):
        self.events = EventLog(log, 'active head: ')
        self.pointer = HeadPointer(config)
        self.max_pose_age = float(max_pose_age)
        self.pose: StampedPose | None = None
        self.rules = StreamRules()

    def reset(self, reason: str = '') -> None:
        if reason:
            self.events.note('restart', reason)
        self.pointer = HeadPointer(self.pointer.config)
        self.pose = None
        self.rules.reset()

    def reconfigure(self, config: HeadConfig, max_pose_age: float) -> None:
        self.pointer.config = config
        self.max_pose_age = float(max_pose_age)

    def add_pose(self, pose: StampedPose) -> None:
        if not (math.isfinite(pose.stamp) and np.isfinite(pose.pose).all()):
            self.events.note('pose skipped', 'not finite')
            return
        if self.pose is not None and pose.stamp < self.pose.stamp:
            self.reset('pose time went backwards')
        self.pose = pose

    def update(self, stamp: float, tracks) -> HeadCommand | None:
        """``tracks``: (id, x, y, vx, vy, weight) rows of confirmed tracks, odometry frame."""
        verdict = self.rules.screen(stamp, 'tracks', self.events)
        if verdict in SKIPPED:
            return None
        if verdict == BACKWARDS:
            self.reset('time went backwards')
        self.rules.accept(stamp)
        if self.pose is None or abs(stamp - self.pose.stamp) > self.max_pose_age:
            self.events.note('not aiming', 'no ego-motion pose within max_pose_age of the '
                             'tracks')
            return None
        return self.pointer.update(stamp, self.pose.pose, tracks)


def _exercise_detection() -> None:
    """Detection on a few synthetic scans (a box moving in a room, beams without a return),
    so that every detection kernel is compiled (or loaded from the cache) for the argument
    types of real scans before the first one."""
    angles = np.linspace(-1.5, 1.5, 61)
    detector = Detector(persons=PersonDetectorConfig(enabled=False))
    pose = StampedPose(stamp=0.0, pose=np.zeros(3), motion=np.zeros(3),
                       motion_covariance=np.zeros((3, 3)), pose_covariance=np.zeros((3, 3)),
                       quality=PoseQuality())
    for k in range(3):
        ranges = np.where(np.abs(angles) < 1.2, 3.0 / np.cos(angles), np.inf)
        ranges[20 + 5 * k:24 + 5 * k] = 1.5
        ranges[0] = np.nan
        scan = Scan(stamp=0.1 * k, ranges=ranges, angle_min=-1.5, angle_increment=0.05,
                    range_min=0.05, range_max=8.0)
        pose.stamp = scan.stamp
        detector.update(scan, pose, want_grids=k == 2)
    _without_body(scan, np.full(scan.n_beams, 2.0))
    frame = detector.history[0]
    segment(np.unique(frame.flat), detector.builder.cells, detector.grid_config.resolution,
            pose.pose, pose.stamp, detector.blob_config, frame.points)
    without_lone_returns(np.unique(frame.flat), frame, scan, 0.13)
    one_leaf = LegClassifier(np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 2)), 0.0)
    people = PersonDetector(PersonDetectorConfig(), one_leaf).detect(
        scan, _masked_returns(scan, _without_body(scan, np.full(scan.n_beams, 3.5))))
    people.legs = np.array([[0, -1]])
    people_in_odometry(people, pose.pose, pose.stamp, detector.history, detector.background,
                       detector.difference_config.motion_depth,
                       np.array([[0.5, 0.5, 0.0, 0.0, 0.0, 0.0]]), (1.0, 0.3, 3.0),
                       scan.silent(), detector.difference_config.footprint)


# ------------------------------------------------------------------------------- warm-up
#
# A stage's first scans run at full speed only once Python has specialised its code (after
# several calls of each function) and the processor's caches hold it: each stage runs a few
# synthetic scans at its construction, once per process (its kernels are compiled or loaded
# by then: ``jit.compiled``). Loading the kernels of a stage made later undoes part of it:
# ``pipeline.Pipeline`` runs the stages together once more when all of them are made.

_warmed: set[str] = set()


def warm_up_once(what: str, call) -> None:
    """Run ``call`` once per process (and not again while it runs: it makes the stage)."""
    if what not in _warmed:
        _warmed.add(what)
        call()


def warm_up_scene(k: int) -> tuple[Scan, tuple[float, float, float], np.ndarray]:
    """Scan ``k`` (0.1 s apart) of a 6 x 5 m room seen by a scanner driving 5 cm per scan,
    its pose, and a person's two legs walking across the room (odometry frame)."""
    x = 0.05 * k
    legs = np.array([[1.5 + 0.1 * k, -1.0 + 0.12 * k], [1.5 + 0.1 * k, -0.75 + 0.12 * k]])
    angles = np.linspace(-math.pi / 2, math.pi / 2, 361)
    d = np.column_stack((np.cos(angles), np.sin(angles)))
    with np.errstate(divide='ignore', invalid='ignore'):
        wall_x = np.where(d[:, 0] > 0, (3.0 - x) / d[:, 0], np.inf)
        wall_y = np.where(d[:, 1] != 0, 2.5 / np.abs(d[:, 1]), np.inf)
    ranges = np.minimum(wall_x, wall_y)
    for cx, cy in legs - (x, 0.0):
        b = d @ (cx, cy)
        disc = b * b - (cx * cx + cy * cy - 0.06 ** 2)
        hit = (disc > 0) & (b > 0)
        ranges = np.where(hit, np.minimum(ranges, b - np.sqrt(np.maximum(disc, 0.0))), ranges)
    ranges[::37] = np.inf
    scan = Scan(stamp=0.1 * k, ranges=ranges, angle_min=-math.pi / 2,
                angle_increment=math.pi / 360, range_min=0.05, range_max=8.0)
    return scan, (x, 0.0, 0.0), legs


def _warm_up_ego_motion() -> None:
    stage = EgoMotion()
    stage.estimator.rehearses = False          # synthetic scans: not a real first match
    for k in range(10):
        scan, pose, _ = warm_up_scene(k)
        stage.add_odometry(scan.stamp, pose)
        stage.update(scan)


def _warm_up_detection() -> None:
    detector = Detector()
    for k in range(10):
        scan, pose, _ = warm_up_scene(k)
        detector.update(scan, StampedPose(
            stamp=scan.stamp, pose=np.array(pose), motion=np.zeros(3),
            motion_covariance=np.zeros((3, 3)), pose_covariance=np.zeros((3, 3)),
            quality=PoseQuality(), body=np.full(scan.n_beams, 0.1)))


def _warm_up_tracking() -> None:
    tracker = Tracker()
    for k in range(10):
        _, pose, legs = warm_up_scene(k)
        person = legs.mean(axis=0, keepdims=True)
        blobs = Blobs(xy=legs, cells=np.array([3, 3]), extent=np.full(2, 0.1),
                      structure=np.full(2, np.nan))
        people = People(xy=person, confidence=np.ones(1), free=np.ones(1, bool),
                        spread=np.full(1, 0.25), static=np.zeros(1, bool))
        tracker.update(Detections(0.1 * k, np.array(pose), blobs, people,
                                  Segments(xy=legs, leg=np.ones(2))))


#: An empty mask of beams (no walked-out test this scan).
_NO_BEAMS = np.zeros(0, bool)
#: The segments' occupancy not known (no segment, or no background kept).
_NO_OCCUPANCY = np.zeros(0)


def _without_body(scan: Scan, body: np.ndarray | None) -> Scan:
    """``scan`` with the returns of the robot's body (``StampedPose.body``) as NaN (no
    measurement; the same scan if none is)."""
    if body is None or body.size != scan.n_beams:
        return scan
    ranges = np.empty(scan.n_beams)
    if not without_body(scan.ranges, np.ascontiguousarray(body, dtype=float), ranges):
        return scan
    # a copy of the (validated) scan with its ranges replaced: dataclasses.replace would
    # validate it again, which costs more than the rest of this function
    out = object.__new__(Scan)
    out.__dict__.update(scan.__dict__)
    out.ranges = ranges
    return out


def _masked_returns(measured: Scan, scan: Scan) -> np.ndarray | None:
    """Per beam, the return of ``measured`` that ``scan`` (the same scan without the
    robot's body and the mixed returns, :func:`_without_body`) lacks (NaN: none; None when
    nothing was taken out)."""
    if scan is measured:
        return None
    return np.where(np.isnan(scan.ranges) & measured.valid(), measured.ranges, np.nan)


def _planar(pose) -> tuple[float, float, float] | None:
    """``(x, y, theta)`` as floats from any three numbers (a sequence, an array of any
    shape), None when ``pose`` is not three numbers."""
    if isinstance(pose, np.ndarray) and pose.ndim != 1:
        pose = pose.reshape(-1)
    if isinstance(pose, (tuple, list, np.ndarray)):
        try:
            x, y, theta = pose
            return float(x), float(y), float(theta)
        except (TypeError, ValueError):
            pass
    flat = np.asarray(pose, dtype=float).reshape(-1)
    return tuple(flat.tolist()) if flat.size == 3 else None


def _generic(reason: str) -> str:
    """A reason without its numbers, so that counts group alike cases."""
    return re.sub(r'-?\d+(\.\d+)?', '#', str(reason))[:100]

