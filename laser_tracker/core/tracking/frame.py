"""One frame's measurements as the tracker uses them, and the scanner's pose and motion.

:class:`Measurements` reads a :class:`~laser_tracker.core.detections.Detections` into a
:class:`Frame`: only finite measurements, motion blobs within ``max_blob_range`` of the
scanner and at most ``max_blobs`` of them (the largest; both with a warning), and without
the motion blobs that ride along with the scanner (``ride_along_reach``: the robot's own
body, before the self-mask has learnt it). A field of the wrong length (a malformed
message) takes its neutral value.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.core import jit
from laser_tracker.core.detections import Detections, People, Segments, View
from laser_tracker.core.tracking.role import Role

log = logging.getLogger('laser_tracker.core.hypotheses')   # the tracker's one log, all roles

#: A measurement rides along with the scanner (``ride_along_reach``) when it moved at least
#: this far (m) in the world since the previous frame (more than range noise), and less than
#: half as far in the scanner's frame.
RIDE_MIN_TRAVEL = 0.05


class Scanner:
    """The scanner's pose (x, y, theta; odometry frame) at this frame, and at the previous
    frame (``previous``, None at the first) with that frame's stamp."""

    __slots__ = ('pose', 'previous', 'previous_stamp', '_place', '_cos', '_sin')

    def __init__(self, pose: np.ndarray, previous: np.ndarray | None,
                 previous_stamp: float | None):
        self.pose, self.previous, self.previous_stamp = pose, previous, previous_stamp
        x, y, th = pose.tolist() if pose.size == 3 else (0.0, 0.0, 0.0)
        finite = math.isfinite(x) and math.isfinite(y) and math.isfinite(th)
        self._place = (x, y) if finite else None
        self._cos, self._sin = (math.cos(th), math.sin(th)) if finite else (0.0, 0.0)

    def to_scanner(self, xy: np.ndarray) -> np.ndarray:
        """Odometry-frame points (k, 2) in the current scanner frame (NaN without a finite
        pose)."""
        if self._place is None:
            return np.full_like(xy, np.nan)
        x, y = self._place
        return _into_frame(xy, x, y, self._cos, self._sin)

    def motion(self, t: float):
        """(velocity (2,), turn rate, speed) of the scanner over the last frame, or None."""
        prev, pose = self.previous, self.pose
        if prev is None or self.previous_stamp is None or t <= self.previous_stamp or \
                pose.size != 3 or prev.size != 3 or \
                not (np.isfinite(pose).all() and np.isfinite(prev).all()):
            return None
        dt = t - self.previous_stamp
        velocity = (pose[:2] - prev[:2]) / dt
        turn = math.remainder(pose[2] - prev[2], 2.0 * math.pi) / dt
        return velocity, turn, float(np.hypot(*velocity))


@dataclass
class Frame:
    """The measurements of one frame, odometry frame: motion blobs (``xy``, ``structure``),
    person detections (``persons``, ``confidence``, ``free``, ``spread``: NaN where the legs
    stand on static background, whose "legs" do not swing), compact segments
    (``segments``, ``leg``, ``segment_occupied``: for how long the scans have seen their
    place occupied) and what the scan's beams saw (``view``, scanner frame)."""

    stamp: float
    scanner: Scanner
    xy: np.ndarray
    structure: np.ndarray
    persons: np.ndarray
    confidence: np.ndarray
    free: np.ndarray
    spread: np.ndarray
    segments: np.ndarray
    leg: np.ndarray
    segment_occupied: np.ndarray
    view: View

    @property
    def dt(self) -> float:
        """Time since the previous frame (0 at the first)."""
        before = self.scanner.previous_stamp
        return self.stamp - before if before is not None else 0.0

    def without_blobs(self, mask: np.ndarray) -> None:
        """Drop the motion blobs where ``mask`` is set."""
        keep = ~mask
        self.xy, self.structure = self.xy[keep], self.structure[keep]


class Measurements(Role):
    """Reads each frame's detections (see the module docstring); remembers the previous
    frame's scanner pose and stamp, and its motion blobs in the scanner's frame."""

    def __init__(self, config, filter, stats: dict):
        super().__init__(config, filter, stats)
        self.reset()

    def reset(self) -> None:
        self.previous_pose: np.ndarray | None = None
        self.previous_stamp: float | None = None
        self.ride_local = np.zeros((0, 2))    # last frame's blobs in its scanner frame

    def read(self, detections: Detections) -> Frame:
        scanner = Scanner(np.asarray(detections.origin, dtype=float).reshape(-1)[:3],
                          self.previous_pose, self.previous_stamp)
        frame = Frame(float(detections.stamp), scanner, *self._usable_blobs(detections),
                      *_people(detections.people), *_segments(detections.segments),
                      _view(detections.view))
        if self.config.ride_along_reach > 0:
            riding = self._riding_with_scanner(frame)
            if riding is not None:
                frame.without_blobs(riding)
        return frame

    def remember(self, frame: Frame) -> None:
        """The end of a frame: its scanner pose and stamp become the previous ones."""
        self.previous_pose = frame.scanner.pose
        self.previous_stamp = frame.stamp

    def _usable_blobs(self, detections: Detections) -> tuple[np.ndarray, np.ndarray]:
        """Motion blobs that are finite, within max_blob_range of the scanner, at most
        max_blobs (the largest): positions and structure."""
        c = self.config
        blobs = detections.blobs
        xy = np.asarray(blobs.xy, dtype=float).reshape(-1, 2)
        n = xy.shape[0]
        if not n:
            return xy, np.zeros(0)
        d = xy - np.asarray(detections.origin, dtype=float)[:2]
        ok = (d * d).sum(axis=1) <= c.max_blob_range ** 2   # NaN anywhere -> False
        if np.count_nonzero(ok) == n <= c.max_blobs:
            return xy, _aligned(blobs.structure, None, n, np.nan)
        if not ok.all():
            log.warning('t=%.3f: dropped %d blob(s) that are not finite or further than '
                        '%.1f m from the scanner', detections.stamp, int((~ok).sum()),
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
                        detections.stamp, kept.size, c.max_blobs)
            self.stats['blobs_dropped'] += int(kept.size - c.max_blobs)
        return xy[ok], _aligned(blobs.structure, ok, n, np.nan)

    def _riding_with_scanner(self, frame: Frame) -> np.ndarray | None:
        """Mask (None: none): motion blobs within ``ride_along_reach`` of the scanner that
        kept their place in its frame since the previous frame (a blob of then within half
        their world displacement of the same scanner-frame place) while they moved at least
        ``RIDE_MIN_TRAVEL`` in the world: the robot's own body, before the self-mask has
        learnt it. Remembers this frame's. (People are not filtered: someone walking beside
        the robot keeps their place in its frame too, and the body is learnt before a
        standing person is confirmed.)"""
        xy = frame.xy
        local = frame.scanner.to_scanner(xy)
        before, pose = self.ride_local, self.previous_pose
        self.ride_local = local
        if not xy.shape[0] or before.shape[0] == 0 or pose is None:
            return None
        x, y, th = pose.tolist() if pose.size == 3 else (math.nan,) * 3
        return _kept_place(xy, local, before, x, y, math.cos(th), math.sin(th),
                           self.config.ride_along_reach ** 2, RIDE_MIN_TRAVEL)


_NONE = np.zeros(0)


@jit.kernel
def _all_finite(xy, values):
    """Every value of ``xy`` (k, 2) and ``values`` is finite."""
    for i in range(xy.shape[0]):
        if not (math.isfinite(xy[i, 0]) and math.isfinite(xy[i, 1])):
            return False
    for i in range(values.size):
        if not math.isfinite(values[i]):
            return False
    return True


@jit.kernel
def _into_frame(xy, x, y, c, s):
    """The points ``xy`` (k, 2) in the frame at ``x, y`` whose heading has cosine ``c`` and
    sine ``s``: ``(c dx + s dy, c dy - s dx)``."""
    out = np.empty((xy.shape[0], 2))
    for i in range(xy.shape[0]):
        dx, dy = xy[i, 0] - x, xy[i, 1] - y
        out[i, 0] = dx * c + s * dy
        out[i, 1] = dy * c - s * dx
    return out


@jit.kernel
def _kept_place(xy, local, before, x, y, c, s, reach2, min_travel):
    """Mask over the points ``xy`` (odometry frame; ``local`` in the scanner's frame) within
    ``sqrt(reach2)`` of the scanner: a point ``before`` (the previous scanner frame, whose
    pose is ``x, y`` and heading cosine and sine ``c, s``) within half their world distance
    of the same scanner-frame place, while that distance is at least ``min_travel``; None
    for none."""
    out = np.zeros(xy.shape[0], np.bool_)
    for i in range(xy.shape[0]):
        if local[i, 0] * local[i, 0] + local[i, 1] * local[i, 1] > reach2:
            continue
        for j in range(before.shape[0]):
            bx, by = before[j, 0], before[j, 1]
            dx, dy = local[i, 0] - bx, local[i, 1] - by
            in_scanner = np.sqrt(dx * dx + dy * dy)
            dx = xy[i, 0] - ((x + c * bx) - s * by)
            dy = xy[i, 1] - ((y + s * bx) + c * by)
            in_world = np.sqrt(dx * dx + dy * dy)
            if in_world >= min_travel and in_scanner < 0.5 * in_world:
                out[i] = True
                break
    return out if out.any() else None


def _people(people: People) -> tuple[np.ndarray, ...]:
    """The finite person detections: positions, confidence, free, spread (NaN where all
    legs stand on static background)."""
    xy = np.asarray(people.xy, dtype=float).reshape(-1, 2)
    n = xy.shape[0]
    if not n:
        return xy, np.zeros(0), np.zeros(0, bool), np.zeros(0)
    xy, ok = _finite_rows(xy, people.confidence)
    static = _aligned(people.static, ok, n, False, bool)
    return (xy, _aligned(people.confidence, ok, n, 1.0),
            _aligned(people.free, ok, n, False, bool),
            np.where(static, np.nan, _aligned(people.spread, ok, n, np.nan)))


def _segments(segments: Segments) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The finite segments: positions, leg probability and how long their place has been
    seen occupied (0 where not known)."""
    xy = np.asarray(segments.xy, dtype=float).reshape(-1, 2)
    if not xy.shape[0]:
        return xy, np.zeros(0), np.zeros(0)
    n = xy.shape[0]
    xy, ok = _finite_rows(xy, segments.leg)
    occupied = _aligned(segments.occupied, ok, n, 0.0)
    return xy, _aligned(segments.leg, ok, n, 1.0), np.where(occupied >= 0.0, occupied, 0.0)


def _view(view: View) -> View:
    """``view`` as arrays of one length (an empty view where bearing and reach differ: a
    malformed message; no beam on background where its flags do not match; NaN bearings
    are dropped)."""
    bearing = np.asarray(view.bearing, dtype=float).reshape(-1)
    reach = np.asarray(view.reach, dtype=float).reshape(-1)
    if bearing.shape[0] != reach.shape[0]:
        return View()
    background = np.asarray(view.background, dtype=bool).reshape(-1)
    if background.shape[0] != bearing.shape[0]:
        background = np.zeros(bearing.shape[0], bool)
    ok = ~np.isnan(bearing) & ~np.isnan(reach)
    return View(bearing, reach, background) if ok.all() else \
        View(bearing[ok], reach[ok], background[ok])


def _finite_rows(xy: np.ndarray, values) -> tuple[np.ndarray, np.ndarray | None]:
    """Rows of points ``xy`` (n, 2) that are finite, with a finite value in ``values`` (n,)
    when it has one per point: the points and the mask (None: all)."""
    values = np.asarray(values, dtype=float).reshape(-1)
    aligned = values.shape[0] == xy.shape[0]
    if _all_finite(xy, values if aligned else _NONE):
        return xy, None
    ok = np.isfinite(xy).all(axis=1)
    if aligned:
        ok &= np.isfinite(values)
    return (xy, None) if ok.all() else (xy[ok], ok)


def _aligned(values, ok: np.ndarray | None, n: int, neutral, dtype=float) -> np.ndarray:
    """``values``, one per measurement of ``n``, at the kept measurements ``ok`` (None:
    all); ``neutral`` for each when there is not one per measurement."""
    values = np.asarray(values, dtype=dtype).reshape(-1)
    if values.shape[0] != n:
        return np.full(n if ok is None else int(ok.sum()), neutral, dtype=dtype)
    return values if ok is None else values[ok]
