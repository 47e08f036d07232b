"""What detection tells tracking about one scan: :class:`Detections` (the ``blobs`` topic).

Three kinds of measurement, each its own plain-array structure in the odometry frame:

* :class:`Blobs`: the motion blobs of the difference map (paper Sec. 6), what the paper
  tracks;
* :class:`People`: people found by the shape of their legs (``core.person_detector``), when
  the person detector runs;
* :class:`Segments`: the scan's compact segments (jump-distance clusters at most a metre
  wide), occupied space that keeps a stopped object's track alive;
* :class:`View`: what each beam of the scan saw, so the tracker can tell a place the scan
  sees empty from one it cannot see.

``conversions.detections_to_marker_array`` / ``detections_from_marker_array`` carry it as a
MarkerArray (schema in README.md, "Topics and schemas").
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class Rows:
    """``count`` and ``len()``: how many rows ``xy`` holds (one per measurement)."""

    @property
    def count(self) -> int:
        return int(np.shape(self.xy)[0])

    def __len__(self) -> int:
        return self.count


@dataclass
class Blobs(Rows):
    """The motion blobs of one scan (paper Sec. 6; ``core.blobs.segment``)."""

    xy: np.ndarray                        # (b, 2) positions, odometry frame, metres
    cells: np.ndarray                     # (b,) int: changed cells in the blob
    extent: np.ndarray                    # (b,) metres: the larger side of its bounding box
    structure: np.ndarray                 # (b,) radians (odometry frame, mod pi) or NaN
    dropped: int = 0                      # blobs dropped by blobs.max_blobs

    @classmethod
    def empty(cls) -> Blobs:
        return cls(xy=np.zeros((0, 2)), cells=np.zeros(0, dtype=np.int64), extent=np.zeros(0),
                   structure=np.zeros(0))


@dataclass
class People(Rows):
    """People found by the shape of their legs.

    ``free``: where all its legs stand was seen free before (someone who walked in);
    ``spread``: the distance between its two legs, NaN for a lone leg; ``static``: all its
    legs stand on static background (where something has long stood)."""

    xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    confidence: np.ndarray = field(default_factory=lambda: np.zeros(0))
    free: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    spread: np.ndarray = field(default_factory=lambda: np.zeros(0))
    static: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


@dataclass
class Segments(Rows):
    """The scan's compact segments: centroids ``xy`` and ``leg``, each one's leg probability
    when the person detector runs (else 0); ``occupied``: per segment, how long (s, decayed
    as the static background is, ``difference.static_time``) the scans have seen its
    centroid's cells occupied before this scan; empty: not known."""

    xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    leg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    occupied: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class View:
    """What each beam of the scan saw, in the scanner's frame (the pose ``origin`` of the
    :class:`Detections`): its ``bearing`` (radians) and ``reach``: the range of its return,
    +inf where it returned nothing (REP 117: +inf, NaN, a no-return code below
    ``range_min``, a reading at ``range_max``; a dark or grazed surface may lie anywhere
    along it), -inf where something was too close to measure. Empty: not known (an older
    message). ``background``: per beam, its return lies on static background (where
    something has long stood); empty: not known."""

    bearing: np.ndarray = field(default_factory=lambda: np.zeros(0))
    reach: np.ndarray = field(default_factory=lambda: np.zeros(0))
    background: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __len__(self) -> int:
        return int(np.shape(self.bearing)[0])

    @classmethod
    def of_scan(cls, scan) -> View:
        """The view of a ``core.scan.Scan`` (its returns, silent and too-close beams)."""
        reach = np.where(scan.valid(), scan.ranges, np.inf)
        reach[scan.ranges == -np.inf] = -np.inf
        return cls(bearing=np.array(scan.angles, dtype=float), reach=reach)


@dataclass
class Detections:
    """Everything detection found in one scan, in the odometry frame of ``origin`` (the
    scanner pose x, y, theta; ``view``: what the scan's beams saw, in its frame).
    ``restarted``: the ego-motion pose chain restarted at this scan (positions before it
    are unrelated: tracks are void); ``stamp_ns``: the scan's exact stamp (integer ns),
    when known."""

    stamp: float
    origin: np.ndarray
    blobs: Blobs = field(default_factory=Blobs.empty)
    people: People = field(default_factory=People)
    segments: Segments = field(default_factory=Segments)
    view: View = field(default_factory=View)
    frame_id: str = 'odom'
    restarted: bool = False
    stamp_ns: int | None = None
