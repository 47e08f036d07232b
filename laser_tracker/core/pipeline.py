"""The paper's pipeline (Fig. 3) as a composition of stages: ego-motion -> detection (grid,
difference map, blobs) -> tracking (hypotheses, Kalman).

``Pipeline(config)`` feeds each scan through the stages of ``core.stages`` and returns a
:class:`StepResult` per scan: the scanner pose in the odometry frame, the detections
(``core.detections.Detections``: motion blobs, people, segments), the hypotheses (id,
position, velocity in the odometry frame, weight, confirmed flag, samples) and, on request,
the grid, the previous grid brought into the current frame and the difference map.
``step(scan)`` runs one scan at once; ``add_scan(scan, arrival)`` and
``add_odometry(stamp, pose, arrival)`` let scans wait for their odometry as the
``ego_motion`` node does (``odom_wait``), and return the results that became ready.

The stages own their stream rules (time going backwards, duplicates, gaps, restarts); this
module only composes them, exactly as the node graph does over topics (``ego_motion`` ->
``detection`` -> ``tracking``).

Configuration: :class:`PipelineConfig` aggregates the sections declared in the modules;
``config/laser_tracker.yaml`` holds them in ROS parameter form, node ``ego_motion``
(``ego_motion.*``), node ``detection`` (``grid.*``, ``difference.*``, ``blobs.*``,
``segments.*``, ``person_detector.*``), node
``tracking`` (``hypotheses.*``, ``kalman.*``); ``laser_tracker.parameters.load`` reads it.
"""
from __future__ import annotations

import dataclasses
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from laser_tracker.config import describe, from_dict, to_dict
from laser_tracker.core.blobs import BlobConfig
from laser_tracker.core.detections import Detections
from laser_tracker.core.difference import DifferenceConfig
from laser_tracker.core.egomotion import EgoMotionConfig
from laser_tracker.core.grid import GridConfig
from laser_tracker.core.hypotheses import HypothesisConfig
from laser_tracker.core.kalman import KalmanConfig
from laser_tracker.core.person_detector import PersonDetectorConfig
from laser_tracker.core.scan import Scan
from laser_tracker.core.segmentation import SegmentConfig
from laser_tracker.core.self_mask import SelfMaskConfig
from laser_tracker.core.stages import (THINNED, Detection, Detector, EgoMotion, StampedPose,
                                      Tracker, warm_up_once, warm_up_scene)
from laser_tracker.core.tracking.state import Hypotheses


# ---------------------------------------------------------------------------- config

NODES: dict[str, tuple[str, ...]] = {
    'ego_motion': ('ego_motion', 'self_mask'),
    'detection': ('grid', 'difference', 'blobs', 'segments', 'person_detector'),
    'tracking': ('hypotheses', 'kalman'),
}


@dataclass(frozen=True)
class PipelineConfig:
    """Every section of the pipeline; ROS parameter form: see :data:`NODES`."""

    ego_motion: EgoMotionConfig = field(default_factory=EgoMotionConfig)
    self_mask: SelfMaskConfig = field(default_factory=SelfMaskConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    difference: DifferenceConfig = field(default_factory=DifferenceConfig)
    blobs: BlobConfig = field(default_factory=BlobConfig)
    segments: SegmentConfig = field(default_factory=SegmentConfig)
    person_detector: PersonDetectorConfig = field(default_factory=PersonDetectorConfig)
    hypotheses: HypothesisConfig = field(default_factory=HypothesisConfig)
    kalman: KalmanConfig = field(default_factory=KalmanConfig)

    @classmethod
    def section_types(cls) -> dict[str, type]:
        return {name: type(f.default_factory())
                for name, f in describe(cls)}

    @classmethod
    def load(cls, path: str | Path) -> PipelineConfig:
        """From a ROS parameter file, by the package's one loader (``parameters.load``)."""
        from laser_tracker import parameters

        return parameters.pipeline_config(parameters.load_files([path]))

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


# --------------------------------------------------------------------------- pipeline


@dataclass
class StepResult:
    """Everything one scan produced."""

    stamp: float
    pose: np.ndarray                  # scanner pose in the odometry frame
    motion: np.ndarray                # relative motion since the previous scan
    source: str                       # ego-motion source
    detections: Detections
    hypotheses: Hypotheses
    newly_confirmed: np.ndarray       # indices into hypotheses
    created: int
    detection: Detection
    skipped: str | None = None
    scan: Scan | None = field(default=None, repr=False)
    ego: StampedPose | None = field(default=None, repr=False)

    @property
    def thinned(self) -> bool:
        """Left out by detection as a scan of a fast scanner (``difference.max_scan_rate``):
        its pose was estimated, nothing else."""
        return self.skipped == f'detection: {THINNED}'


STAGES = ('ego_motion', 'grid', 'difference', 'blobs', 'persons', 'tracking')


class Pipeline:
    """Ego-motion, detection and tracking for a stream of scans and odometry."""

    def __init__(self, config: PipelineConfig | None = None, odom_wait: float = 0.0,
                 profile: bool = False):
        self.config = config or PipelineConfig()
        c = self.config
        self.profile = profile
        self.times = {s: 0.0 for s in STAGES}
        self.ego = EgoMotion(c.ego_motion, odom_wait, self_mask=c.self_mask)
        self.detector = Detector(c.grid, c.difference, c.blobs, c.person_detector,
                                 times=self.times if profile else None, segments=c.segments)
        self.tracker = Tracker(c.hypotheses, c.kalman)
        warm_up_once('pipeline', _warm_up_pipeline)

    # ------------------------------------------------------------------ streams
    def add_odometry(self, stamp: float, pose, arrival: float | None = None) -> list[StepResult]:
        """Feed one odometry sample; returns the results of scans it released."""
        released = self.ego.add_odometry(stamp, pose, arrival)
        return self._finish(released) if released else []

    def add_scan(self, scan: Scan, arrival: float | None = None,
                 want_grids: bool = False) -> list[StepResult]:
        """Feed one scan (waiting for its odometry when ``arrival`` is given)."""
        t0 = time.perf_counter() if self.profile else 0.0
        ready = self.ego.add_scan(scan, arrival, want_grids)
        if self.profile:
            self.times['ego_motion'] += time.perf_counter() - t0
        return self._finish(ready)

    def poll(self, now: float) -> list[StepResult]:
        return self._finish(self.ego.poll(now))

    def flush(self) -> list[StepResult]:
        return self._finish(self.ego.flush())

    def step(self, scan: Scan, want_grids: bool = False) -> StepResult:
        """One scan at once (no waiting for odometry)."""
        return self.add_scan(scan, None, want_grids)[0]

    def reset(self, reason: str = 'reset requested') -> None:
        """Start afresh (every stage; odometry history is kept)."""
        self.ego.reset(reason)
        self.detector.reset()
        self.tracker.reset(reason)

    # ------------------------------------------------------------------ composition
    def _finish(self, ready) -> list[StepResult]:
        return [self._detect_and_track(scan, pose, bool(want)) for scan, want, pose in ready]

    def _detect_and_track(self, scan: Scan, pose: StampedPose | None,
                          want_grids: bool) -> StepResult:
        if pose is None:
            return self._skipped(scan, f'ego-motion: {self.ego.skipped}')
        det = self.detector.update(scan, pose, want_grids)
        if det is None:
            return self._skipped(scan, f'detection: {self.detector.skipped}')
        t0 = time.perf_counter() if self.profile else 0.0
        frame = self.tracker.update(det.detections)
        if self.profile:
            self.times['tracking'] += time.perf_counter() - t0
        if frame is None:
            return self._skipped(scan, f'tracking: {self.tracker.skipped}')
        return StepResult(stamp=scan.stamp, pose=pose.pose, motion=pose.motion,
                          source=pose.source, detections=det.detections,
                          hypotheses=frame.hypotheses,
                          newly_confirmed=frame.newly_confirmed, created=frame.created,
                          detection=det, scan=det.scan, ego=pose)

    def _skipped(self, scan: Scan, reason: str) -> StepResult:
        empty = Detections(float(scan.stamp), np.full(3, np.nan))
        return StepResult(stamp=scan.stamp, pose=np.full(3, np.nan), motion=np.zeros(3),
                          source='skipped', detections=empty,
                          hypotheses=self.tracker.hypotheses.hyp,
                          newly_confirmed=np.zeros(0, np.intp), created=0,
                          detection=Detection(empty, 0), skipped=reason, scan=scan)

    # ------------------------------------------------------------------ reporting
    def events(self) -> dict[str, dict[str, int]]:
        """Every stage's counted events (stream rules, skips, restarts) for summaries."""
        ego = dict(self.ego.events.counts)
        ego.update({k: v for k, v in self.ego.estimator.stats.items()
                    if str(k).startswith('note: ')})
        return {'ego_motion': ego,
                'detection': dict(self.detector.events.counts),
                'tracking': dict(self.tracker.events.counts)}

    @property
    def sources(self) -> Counter:
        return Counter(self.ego.sources)


def _warm_up_pipeline() -> None:
    """The stages composed, as :meth:`Pipeline.step` runs them, on the synthetic scans of
    the stages' own warm-ups (with odometry), once per process, after every stage's kernels
    are loaded. Measured: a stage warmed up before the kernels of the stages made after it
    are loaded runs its first real scans as if it had not been (its second scan about 25 %
    slower than the later ones); warmed up once more here, the second scan runs at full
    speed. This pipeline's first scan also rehearses the process's first match
    (``egomotion._rehearse``), which the first real scan then need not do (measured: no
    faster second scan for it, 0.1 ms more for the first). Nothing else is kept: the
    pipeline is thrown away."""
    pipeline = Pipeline()
    for k in range(10):
        scan, pose, _ = warm_up_scene(k)
        pipeline.add_odometry(scan.stamp, pose)
        pipeline.step(scan)
