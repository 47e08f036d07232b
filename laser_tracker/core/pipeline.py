"""The paper's pipeline (Fig. 3) as one class: ego-motion -> grid -> difference -> blobs ->
hypotheses.

``Pipeline(config).step(scan)`` runs everything for one scan (odometry is fed with
``add_odometry`` as it arrives) and returns a :class:`StepResult`: the scanner pose in the
odometry frame, the blobs, the hypotheses (id, position, velocity in the odometry frame,
weight, confirmed flag, samples) and, on request, the grid, the previous grid brought into the
current frame and the difference map.

Detection and tracking are separately callable, as two ROS nodes will run them:

* ``Detector.detect(scan, pose, quality=None) -> Detection`` (scan + scanner pose in the
  odometry frame -> blobs; keeps the previous grid). ``quality``: the pose's
  :class:`~laser_tracker.core.difference.PoseQuality` (``difference.pose_quality`` of the
  ego-motion estimate; the ``ego_motion`` node sends it in its message's pose covariance):
  a scan whose pose is not trusted reports no blobs (``difference.pose_gate``);
* ``Tracker.update(blobs) -> FrameResult`` (``laser_tracker.core.hypotheses``; keeps the
  hypotheses and the previous frame's blobs).

Interface between them: :class:`~laser_tracker.core.blobs.Blobs`, plain arrays only:
``stamp`` (s), ``frame_id`` (the odometry frame), ``origin`` (3,) the scanner pose
``x, y, theta`` in that frame, and per blob ``xy`` (b, 2) position (m), ``cells`` (b,)
size in cells, ``extent`` (b,) bounding-box side (m), ``structure`` (b,) direction of the
wall the blob lies on (rad mod pi, NaN = none). As a
``visualization_msgs/MarkerArray`` (topic ``blobs``, written by the nodes on top of this API):
a ``DELETEALL`` marker, then one ``CYLINDER`` marker per blob with ``ns = 'blobs'``,
``id`` = blob index, ``header`` = (stamp, odometry frame), ``pose.position`` = (x, y, 0),
``scale.x = scale.y = extent``, ``text`` = JSON ``{"cells": n, "structure": angle or null}``,
and one ``ARROW`` marker with ``ns = 'scanner'``, ``id = 0`` whose pose is the scanner pose
(``origin``; yaw in the orientation quaternion). Nothing else crosses the node boundary.

Configuration: :class:`PipelineConfig` aggregates the sections declared in the modules;
``config/laser_tracker.yaml`` holds them in ROS parameter form, node ``ego_motion``
(``ego_motion.*``), node ``detection`` (``grid.*``, ``difference.*``, ``blobs.*``), node
``tracking`` (``hypotheses.*``, ``kalman.*``).

Ego-motion: ``laser_tracker.core.egomotion.EgoMotionEstimator`` (odometry prior + ICP). Its
estimate's quality goes to the detector with the pose: a scan placed by odometry because ICP
was refused, or by a poor match, reports no blobs (its grid is still kept; counted in
``stats`` as ``gated: ego-motion not trusted``). A scan it cannot place (pose NaN, source
``none``) is skipped; when it restarts its pose chain (source ``init`` after the first scan)
detection and tracking restart too, since odometry-frame positions before and after are
unrelated.

Bad input: a scan stamped before the previous one resets detection, tracking and ego-motion
(logged, counted in ``stats``); a scan with the same stamp as the previous one is skipped.
A change of beam count needs nothing: the ray tables are per beam geometry.
"""
from __future__ import annotations

import dataclasses
import logging
import re
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from laser_tracker.config import ConfigError, describe, from_dict, read_ros_yaml, to_dict
from laser_tracker.core.blobs import BlobConfig, Blobs, segment
from laser_tracker.core.difference import (DifferenceConfig, PoseQuality, changed_cells,
                                           deep_free, difference_map, not_occupied_before,
                                           pose_quality, pose_trusted, relative_motion)
from laser_tracker.core.egomotion import EgoMotionConfig, EgoMotionEstimator
from laser_tracker.core.grid import GridBuilder, GridConfig, GridFrame, transform_grid
from laser_tracker.core.hypotheses import FrameResult, HypothesisArrays, HypothesisConfig, \
    Tracker
from laser_tracker.core.kalman import KalmanConfig
from laser_tracker.core.scan import Scan

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------- config

NODES: dict[str, tuple[str, ...]] = {
    'ego_motion': ('ego_motion',),
    'detection': ('grid', 'difference', 'blobs'),
    'tracking': ('hypotheses', 'kalman'),
}


@dataclass(frozen=True)
class PipelineConfig:
    """Every section of the pipeline; ROS parameter form: see :data:`NODES`."""

    ego_motion: EgoMotionConfig = field(default_factory=EgoMotionConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    difference: DifferenceConfig = field(default_factory=DifferenceConfig)
    blobs: BlobConfig = field(default_factory=BlobConfig)
    hypotheses: HypothesisConfig = field(default_factory=HypothesisConfig)
    kalman: KalmanConfig = field(default_factory=KalmanConfig)

    @classmethod
    def section_types(cls) -> dict[str, type]:
        return {name: type(f.default_factory())
                for name, f in describe(cls)}

    @classmethod
    def from_ros_params(cls, nodes: dict[str, dict[str, Any]], source: str = '') -> \
            PipelineConfig:
        """From ``{node: {section.field: value}}`` (``config.read_ros_yaml``).

        Nodes other than those of :data:`NODES` are left alone (other parts of the package
        keep their parameters in the same file); an unknown section or field of ours is an
        error.
        """
        where = f'{source}: ' if source else ''
        types = cls.section_types()
        values: dict[str, dict[str, Any]] = {s: {} for s in types}
        for node, sections in NODES.items():
            for name, value in (nodes.get(node) or {}).items():
                section, _, key = name.partition('.')
                if not key:
                    continue    # a plain name: the node shell's own (laser_tracker.parameters)
                if section not in sections:
                    raise ConfigError(f'{where}node {node}: unknown parameter {name!r} '
                                      f'(sections here: {", ".join(sections)})')
                values[section][key] = value
        try:
            return cls(**{s: from_dict(types[s], v, s) for s, v in values.items()})
        except ConfigError as exc:
            raise ConfigError(f'{where}{exc}') from None

    @classmethod
    def load(cls, path: str | Path) -> PipelineConfig:
        return cls.from_ros_params(read_ros_yaml(path), str(path))

    def to_ros_params(self) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for node, sections in NODES.items():
            params: dict[str, Any] = {}
            for s in sections:
                for key, value in to_dict(getattr(self, s)).items():
                    params[f'{s}.{key}'] = value
            out[node] = params
        return out

    def replace(self, **sections) -> PipelineConfig:
        """A copy with ``section={field: value}`` changes (validated)."""
        types = self.section_types()
        new = {}
        for s, changes in sections.items():
            base = to_dict(getattr(self, s))
            base.update(changes)
            new[s] = from_dict(types[s], base, s)
        return dataclasses.replace(self, **new)


# -------------------------------------------------------------------------- detection


@dataclass
class Detection:
    """Detection output for one scan; grids only when requested."""

    blobs: Blobs
    changed: int                       # cells in the difference map
    grid: np.ndarray | None = None
    previous: np.ndarray | None = None     # previous grid in the current scanner frame
    difference: np.ndarray | None = None   # Equation 1 (bool)
    gated: bool = False                # pose not trusted: no changes reported


class Detector:
    """Scan + scanner pose -> blobs (the ``detection`` node's core)."""

    def __init__(self, grid: GridConfig | None = None,
                 difference: DifferenceConfig | None = None,
                 blobs: BlobConfig | None = None, frame_id: str = 'odom',
                 times: dict | None = None):
        self.times = times   # stage -> seconds, accumulated when given (profiling)
        self.grid_config = grid or GridConfig()
        self.difference_config = difference or DifferenceConfig()
        self.blob_config = blobs or BlobConfig()
        self.frame_id = frame_id
        self.builder = GridBuilder(self.grid_config, keep=self.difference_config.memory + 2)
        self.reset()

    def reset(self) -> None:
        self.previous: GridFrame | None = None
        self.previous_pose: np.ndarray | None = None
        self.earlier: deque = deque(maxlen=self.difference_config.memory + 1)

    def detect(self, scan: Scan, pose, want_grids: bool = False,
               quality: PoseQuality | None = None) -> Detection:
        """Grid of ``scan``, Eq. 1 against the previous grid, blobs (odometry frame).

        ``quality`` (None = trusted): when ``difference.pose_gate`` does not trust the pose,
        the grid is built and kept as history as usual but no change is reported.
        """
        pose = np.asarray(pose, dtype=float)
        res = self.grid_config.resolution
        cells = self.builder.cells
        times = self.times
        t0 = time.perf_counter() if times is not None else 0.0
        frame = self.builder.build(scan)
        previous, prev_pose = self.previous, self.previous_pose
        if previous is not None and self.difference_config.memory:
            self.earlier.append((previous.index, prev_pose))
        self.previous, self.previous_pose = frame, pose
        gated = not pose_trusted(quality, self.difference_config)
        if previous is None or gated:
            det = Detection(Blobs.empty(scan.stamp, pose, self.frame_id), 0,
                            gated=gated and previous is not None)
            if want_grids:
                det.grid = frame.grid.copy()
                if previous is not None:
                    det.previous = transform_grid(previous.grid,
                                                  relative_motion(prev_pose, pose), res)
                    det.difference = difference_map(det.grid, det.previous)  # not reported
            if times is not None:
                times['grid'] += time.perf_counter() - t0
            return det
        motion = relative_motion(prev_pose, pose)
        t1 = time.perf_counter() if times is not None else 0.0
        changed = changed_cells(frame.ij, previous.padded, motion, res,
                                self.difference_config)
        if len(self.earlier) > 1 and changed.any():
            # The grid just appended is `previous` itself; the memory is the ones before it.
            earlier = list(self.earlier)[:-1]
            changed[changed] = not_occupied_before(
                frame.ij[changed], self.builder.stack, [e[0] for e in earlier],
                [e[1] for e in earlier], pose, res)
        if self.difference_config.motion_depth > 0 and changed.any():
            changed[changed] = deep_free(frame.ij[changed], previous, motion, res, cells,
                                         self.difference_config)
        d_cells = np.unique(frame.flat[changed]) if changed.any() else frame.flat[:0]
        t2 = time.perf_counter() if times is not None else 0.0
        if d_cells.size:
            blobs = segment(d_cells, cells, res, pose, scan.stamp, self.blob_config,
                            frame.points)
            blobs.frame_id = self.frame_id
        else:
            blobs = Blobs.empty(scan.stamp, pose, self.frame_id)
        if times is not None:
            t3 = time.perf_counter()
            times['grid'] += t1 - t0
            times['difference'] += t2 - t1
            times['blobs'] += t3 - t2
        det = Detection(blobs, int(d_cells.size))
        if want_grids:
            det.grid = frame.grid.copy()
            det.previous = transform_grid(previous.grid, motion, res)
            det.difference = difference_map(det.grid, det.previous)
        return det


# --------------------------------------------------------------------------- pipeline


@dataclass
class StepResult:
    """Everything one scan produced."""

    stamp: float
    pose: np.ndarray                  # scanner pose in the odometry frame
    motion: np.ndarray                # relative motion since the previous scan
    source: str                       # ego-motion source
    blobs: Blobs
    hypotheses: HypothesisArrays
    newly_confirmed: np.ndarray       # indices into hypotheses
    created: int
    detection: Detection
    skipped: str | None = None


STAGES = ('ego_motion', 'grid', 'difference', 'blobs', 'tracking')


class Pipeline:
    """Ego-motion, detection and tracking for a stream of scans and odometry."""

    def __init__(self, config: PipelineConfig | None = None, profile: bool = False):
        self.config = config or PipelineConfig()
        c = self.config
        self.ego = EgoMotionEstimator(c.ego_motion)
        self.profile = profile
        self.times = {s: 0.0 for s in STAGES}
        self.detector = Detector(c.grid, c.difference, c.blobs,
                                 times=self.times if profile else None)
        self.tracker = Tracker(c.hypotheses, c.kalman)
        self.stats: Counter = Counter()
        self.sources: Counter = Counter()
        self.last_stamp: float | None = None
        self._fresh = True        # no scan since construction or reset

    def add_odometry(self, stamp: float, pose) -> None:
        self.ego.add_odometry(stamp, pose)

    def reset(self, reason: str) -> None:
        """Start afresh (detection, tracking, ego-motion); odometry history is kept."""
        log.warning('pipeline reset: %s', reason)
        self.stats[f'reset: {reason.split(" (")[0]}'] += 1
        self.detector.reset()
        self.tracker.reset()
        reset = getattr(self.ego, 'reset', None)
        if callable(reset):
            reset()
        else:
            self.ego = EgoMotionEstimator(self.config.ego_motion)
        self.last_stamp = None
        self._fresh = True

    def step(self, scan: Scan, want_grids: bool = False) -> StepResult:
        if self.last_stamp is not None:
            if scan.stamp < self.last_stamp:
                self.reset(f'time went backwards ({self.last_stamp:.3f} -> {scan.stamp:.3f} s)')
            elif scan.stamp == self.last_stamp:
                return self._skip(scan, 'duplicate stamp')
        prof = self.profile
        t0 = time.perf_counter() if prof else 0.0
        est = self.ego.update(scan)
        pose = np.asarray(est.pose, dtype=float)
        if not np.isfinite(pose).all():
            self.sources[str(est.source)] += 1
            return self._skip(scan, 'no ego-motion pose: ' + _generic(est.reason))
        self.sources[str(est.source)] += 1
        quality = pose_quality(est)
        if quality.restarted and self.stats['scans'] and not self._fresh:
            # The estimator restarted its pose chain: the odometry-frame history is void.
            log.warning('t=%.3f: ego-motion restarted (%s): detection and tracking restart',
                        scan.stamp, est.reason)
            self.stats['reset: ego-motion restarted'] += 1
            self.detector.reset()
            self.tracker.reset()
        t1 = time.perf_counter() if prof else 0.0
        det = self.detector.detect(scan, pose, want_grids, quality)
        if det.gated:
            log.debug('t=%.3f: ego-motion not trusted (%s, inlier ratio %.2f): no blobs',
                      scan.stamp, est.source, est.inlier_ratio)
            self.stats['gated: ego-motion not trusted'] += 1
        t2 = time.perf_counter() if prof else 0.0
        frame: FrameResult = self.tracker.update(det.blobs)
        if prof:
            t3 = time.perf_counter()
            self.times['ego_motion'] += t1 - t0
            self.times['tracking'] += t3 - t2
        self.last_stamp = scan.stamp
        self._fresh = False
        self.stats['scans'] += 1
        return StepResult(stamp=scan.stamp, pose=pose, motion=np.asarray(est.motion, float),
                          source=str(est.source), blobs=det.blobs,
                          hypotheses=frame.hypotheses, newly_confirmed=frame.newly_confirmed,
                          created=frame.created, detection=det)

    def _skip(self, scan: Scan, reason: str) -> StepResult:
        """A scan that produced nothing (counted under ``skipped: <reason>``)."""
        log.warning('scan at t=%.3f skipped: %s', scan.stamp, reason)
        self.stats[f'skipped: {reason}'] += 1
        empty = Blobs.empty(scan.stamp, np.full(3, np.nan))
        return StepResult(stamp=scan.stamp, pose=np.full(3, np.nan), motion=np.zeros(3),
                          source='skipped', blobs=empty, hypotheses=self.tracker.hyp,
                          newly_confirmed=np.zeros(0, np.intp), created=0,
                          detection=Detection(empty, 0), skipped=reason)


def _generic(reason: str) -> str:
    """A reason without its numbers, so that counts group alike cases."""
    return re.sub(r'-?\d+(\.\d+)?', '#', str(reason))[:100]
