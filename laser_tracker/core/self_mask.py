"""The robot's own body in its scans: returns that are part of the platform, never objects.

A scanner with a wide field of view sees parts of the robot that carries it (the chassis, a
mast, a bumper, cables). Those returns keep their place in the scanner's frame while the
robot moves, so to the difference map they look like something that follows the robot, and
to the person detector a cable can look like a leg. Two sources say which returns are the
body; a masked return reads NaN ("no measurement", REP 117) for every later stage, so it
is neither matched, nor an obstacle, nor free space, nor a segment:

* **learnt online** (``learn``): a return within ``reach`` of the scanner, on a surface
  that lies entirely within reach (a wall the robot drives along runs out of reach; a body
  part does not), which keeps its range while the world moves past it by ``travel`` metres
  (the distance a static point there would have moved in the scanner's frame, summed over
  the scans) is the body. No per-robot tuning: it follows from the motion. A person beside
  a moving robot swings their legs and never keeps a range that long; a standing robot
  learns nothing.
* **a footprint** (``footprint``): a polygon in the platform's base frame, as laser_filters'
  box filter and nav2's ``footprint`` take it: returns inside it are the body.

Until then a return that has kept its range while the world moved past it by
``PROVISIONAL_TRAVEL`` is left out of the scan match (:meth:`SelfMask.unlearnt`): the body
matches itself and would pull the match towards standing still. The body is learnt from
measured motion only: the odometry increment when there is one (the
scan match is pulled towards standing still by the body it has not learnt yet: the body
matches itself), else an accepted match; a motion guessed while a standing robot's matches
are refused would make anything standing in front of it look like its body.

**The scanner's range noise** (:func:`range_noise`). "Keeps its range" and the mask's margin
beyond the body hold within ``tolerance``, or within ``noise_sigmas`` times the range noise
measured near the robot when that is larger: the body of a robot with a noisy scanner (a few
centimetres, as low-cost 360 deg scanners have) jitters by that much from scan to scan and
would otherwise never keep its range, nor stay within the mask once learnt.

The mask of a beam is a range: returns up to it (plus the tolerance) are the body; a return
beyond it is the world seen past the body, so a person standing next to the robot is never
hidden. A learnt range also masks the beams within ``EDGE_BEAMS`` of it (a body part's edge
shifts by a beam or two). A beam learnt as body that keeps seeing only farther returns while the world moves
past it by ``10 x travel`` is given up (what stood there was not the body).

**Mixed returns at a nearer edge** (``beam_width``, :func:`mixed_returns`). A laser beam
has a width (about a centimetre or a few where it leaves the scanner). A beam that passes
the edge of a nearer surface within that width is partly blocked: the scanner reports one
range from the mixture of the edge's echo and the weakened echo from behind, often well
off the surface behind (laser scanners' "mixed pixels" or veil). The number of beams an
edge blocks partly is the beam's width over the beam spacing at the edge's range, so it is
largest at the robot's own body: a body edge 0.7 m away blocks half a dozen beams of a
0.35 deg scanner partly, and their returns form a spur off the wall behind that keeps its
bearing while the robot moves, which the difference map reads as a mover. Those beams on
the far side of a range step (``EDGE_JUMP``) are masked like the body: a person standing
next to the robot is still seen by every other beam.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import ConfigError, param
from laser_tracker.core import jit
from laser_tracker.core.scan import Scan, beam_table, beams_jitter, geometry_of, nearest_beams

#: Points closer than this (m) along the scan are one surface (for "lies within reach").
SURFACE_JUMP = 0.15
#: A beam learnt as body is given up after seeing only the world beyond it while the world
#: moved past by this many times ``travel``.
FORGET_FACTOR = 10.0
#: The world travel (m) past a return that kept its range after which the scan match leaves
#: it out (``SelfMask.unlearnt``), long before it is learnt as the body.
PROVISIONAL_TRAVEL = 0.2
#: The edge of a body part shifts by a beam or two between scans (vibration, a cable, the
#: beam's footprint): a learnt body range also masks the beams this close to it.
EDGE_BEAMS = 3
#: A range step (m) between neighbouring returns that makes the nearer one an edge for
#: :func:`mixed_returns`: well above the range noise of these scanners (1-3 cm) and below
#: the gap between a person and the wall behind them.
EDGE_JUMP = 0.3
#: The weight of one scan's measurement of the range noise in its running mean.
NOISE_WEIGHT = 0.1
#: Triples of consecutive returns within reach that one scan needs to measure the noise.
NOISE_MIN_TRIPLES = 10


def range_noise(ranges: np.ndarray, range_min: float, reach: float) -> float | None:
    """The range noise (m, one sigma) of one scan's returns within ``reach``, or None with
    fewer than ``NOISE_MIN_TRIPLES`` triples of consecutive returns there.

    For three consecutive returns on one surface, r[i-1] - 2 r[i] + r[i+1] is the noise
    alone (the surface's own curvature over two beam spacings is far below it) with six
    times its variance; the median of its magnitude, which the edges between surfaces do
    not move, is 0.6745 sqrt(6) sigma."""
    noise = _range_noise(np.asarray(ranges, dtype=np.float64), float(range_min), float(reach),
                         NOISE_MIN_TRIPLES)
    return None if noise != noise else float(noise)


@jit.kernel
def _range_noise(r, range_min, reach, least):
    """:func:`range_noise` (NaN for None), one pass over the beams."""
    second = np.empty(max(r.size - 2, 0))
    n = 0
    for i in range(1, r.size - 1):
        a, b, c = r[i - 1], r[i], r[i + 1]
        if range_min <= a < reach and range_min <= b < reach and range_min <= c < reach:
            second[n] = abs(a - 2.0 * b + c)
            n += 1
    if n < least:
        return np.nan
    return np.median(second[:n]) / (0.6745 * math.sqrt(6.0))


@dataclass(frozen=True)
class SelfMaskConfig:
    """Section ``self_mask`` of node ``ego_motion``: the robot's own body in the scans."""

    learn: bool = param(
        True, 'Learn which returns are the robot\'s own body while it moves: returns within '
        'reach that keep their range while the world moves past them by travel metres. '
        'false = only the footprint (paper: nothing is masked).')
    reach: float = param(
        1.0, 'Largest range (m) of a return that can be the robot\'s body (how far the '
        'robot extends from the scanner).', min=0.05, max=10.0)
    travel: float = param(
        2.0, 'A return is the body once the world has moved past it by this much (m, in '
        'the scanner\'s frame, summed over scans) while its range stayed within tolerance.',
        min=0.1, max=100.0)
    tolerance: float = param(
        0.05, 'Range tolerance (m) of "keeps its range", and margin of the mask beyond the '
        'body\'s learnt range, at least (see noise_sigmas).', min=0.0, max=1.0)
    noise_sigmas: float = param(
        3.0, 'The tolerance is at least this many times the range noise measured near the '
        'robot (one sigma, from the second differences of consecutive returns within '
        'reach): the body of a robot with a noisy scanner jitters by that much from scan to '
        'scan (3: 99.7 % of its returns). 0 = the tolerance alone.', min=0.0, max=10.0)
    footprint: str = param(
        '', 'The robot\'s footprint in its base frame, as nav2 writes it: '
        '"[[x1, y1], [x2, y2], [x3, y3], ...]" (m, at least 3 corners); returns inside it '
        'are the body. \'\' = none.')
    beam_width: float = param(
        0.03, 'Width (m) of the laser beam where it leaves the scanner. Beams on the far side '
        'of a nearer surface\'s edge (a range step of 0.3 m or more) within this width of '
        'it are partly blocked and return a mixed range: they are masked like the body '
        '(the robot\'s own body, being nearest, blocks the most). 0 = none are (paper).',
        min=0.0, max=0.2)

    def __post_init__(self):
        footprint_polygon(self.footprint)     # a malformed polygon is refused here


def footprint_polygon(text: str) -> np.ndarray | None:
    """The footprint parameter as (k, 2) corners, None when empty; ConfigError if malformed."""
    if not text.strip():
        return None
    import yaml

    where = 'self_mask.footprint'
    try:
        value = yaml.safe_load(text)
        corners = np.asarray(value, dtype=float)
    except (yaml.YAMLError, TypeError, ValueError):
        raise ConfigError(f'{where}: not a list of [x, y] corners: {text!r} (example: '
                          f'"[[0.3, 0.25], [-0.3, 0.25], [-0.3, -0.25], [0.3, -0.25]]")') \
            from None
    if corners.ndim != 2 or corners.shape[1] != 2 or corners.shape[0] < 3:
        raise ConfigError(f'{where}: needs at least 3 corners [x, y], got {text!r}')
    if not np.isfinite(corners).all():
        raise ConfigError(f'{where}: corners must be finite, got {text!r}')
    x, y = corners[:, 0], corners[:, 1]
    if abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) < 1e-9:
        raise ConfigError(f'{where}: the corners enclose no area: {text!r}')
    return corners


def inside_polygon(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Mask (k,): points (k, 2) inside the polygon (even-odd rule)."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = corners[:, 0], corners[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide='ignore', invalid='ignore'):
        at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.count_nonzero(crosses & (x < at), axis=1) % 2) == 1


#: Rows of a self-mask's per-beam state (:attr:`SelfMask.state`): the range each beam's
#: return keeps, the world travel past it while it kept it, the learnt body range, the world
#: travel seen only beyond it, the footprint's range, and the mask's range (the footprint's
#: and the learnt body's, what :attr:`SelfMask.ranges` says).
ANCHOR, KEPT, BODY, BEYOND, LIMITS, RANGES = range(6)
#: Layout of a self-mask's settings (:attr:`SelfMask.settings`): tolerance, the provisional
#: travel, the beam's width, the edge step, learning on, reach, travel, the travel that
#: forgets a body, the surface step, and whether the mask's range is stale (set when the
#: learnt body changed, cleared when it is recomputed).
_TOLERANCE, _PROVISIONAL, _WIDTH, _JUMP, _LEARN, _REACH, _TRAVEL, _FORGET, _SURFACE, \
    _STALE, _SETTINGS = range(11)


def _state_row(row: int, doc: str) -> property:
    """A row of :attr:`SelfMask.state` as an attribute (a view)."""
    return property(lambda self: self.state[row], doc=doc)


class SelfMask:
    """The body mask of one scan stream: ``apply(scan)`` masks, ``learn(scan, motion)`` learns.

    ``mount`` = (x, y, yaw) of the scanner on the platform (for the footprint). ``limits``
    (beams,) is the footprint's mask: the farthest range (m) of the body per beam, NaN where
    the beam does not see it. The per-beam state is one array (:attr:`state`, rows
    ``ANCHOR`` ... ``RANGES``) that the kernels update in place; the ego-motion estimator
    masks and learns in its own kernel call (``EgoMotionEstimator(self_mask=...)``).
    """

    def __init__(self, config: SelfMaskConfig | None = None, mount=(0.0, 0.0, 0.0)):
        self.config = c = config or SelfMaskConfig()
        self.mount = tuple(float(v) for v in mount)
        corners = footprint_polygon(c.footprint)
        if corners is not None:             # the footprint in the scanner frame
            x, y, yaw = self.mount
            cy, sy = math.cos(yaw), math.sin(yaw)
            d = corners - (x, y)
            corners = np.column_stack((cy * d[:, 0] + sy * d[:, 1],
                                       -sy * d[:, 0] + cy * d[:, 1]))
        self._footprint = corners
        self.settings = np.zeros(_SETTINGS)
        self.settings[[_TOLERANCE, _PROVISIONAL, _WIDTH, _JUMP, _LEARN, _REACH, _TRAVEL,
                       _FORGET, _SURFACE]] = (
            c.tolerance, PROVISIONAL_TRAVEL, c.beam_width, EDGE_JUMP, c.learn, c.reach,
            c.travel, FORGET_FACTOR * c.travel, SURFACE_JUMP)
        self.reset()
        #: the scanner's range noise near the robot (m, one sigma; running mean over scans,
        #: :meth:`follow_noise`), None until measured
        self.range_noise: float | None = None
        #: what :meth:`apply` and :meth:`left_out` (or the estimator) masked in the last scan:
        #: per beam, returns up to this range (NaN: none); ``applied`` is the same, None when
        #: it masked nothing
        self.masked_ranges = np.zeros(0)
        self.applied: np.ndarray | None = None
        jit.compiled('self-mask kernel', _exercise_learn)

    # ------------------------------------------------------------------ state
    def fit(self, scan: Scan) -> None:
        """Per-beam state for the scan's geometry. A new geometry starts afresh, unless it
        is the same scanner's beams jittering (``core.scan.beams_jitter``: a driver whose
        beam count changes from scan to scan), whose state each beam takes from the beam
        of the previous geometry nearest to it: the body is near, half a beam's width is
        millimetres there."""
        key = geometry_of(scan)
        if key == self._geometry:
            return
        old, before = self.state, self._geometry
        self._geometry = key
        n = scan.n_beams
        self.state = np.zeros((RANGES + 1, n))
        self.state[[ANCHOR, BODY]] = np.nan
        self.state[LIMITS] = self._footprint_limits(scan)
        if before is not None and beams_jitter(before, key):
            index, inside = nearest_beams(before, key)
            for row in (ANCHOR, KEPT, BODY, BEYOND):
                self.state[row, inside] = old[row, index[inside]]
        self.settings[_STALE] = 1.0

    anchor = _state_row(ANCHOR, 'The range each beam\'s return keeps.')
    kept = _state_row(KEPT, 'World travel past each return while it kept its range.')
    body = _state_row(BODY, 'The learnt body range per beam (NaN: none).')
    beyond = _state_row(BEYOND, 'World travel seen only beyond the learnt body.')
    limits = _state_row(LIMITS, 'The footprint\'s range per beam (NaN: none).')

    def _footprint_limits(self, scan: Scan) -> np.ndarray:
        """Per beam, the range at which it leaves the footprint (NaN: it does not cross it)."""
        n = scan.n_beams
        if self._footprint is None:
            return np.full(n, np.nan)
        _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment), n)
        # Sample each beam finely out to the footprint's farthest corner.
        far = float(np.hypot(*self._footprint.T).max())
        steps = np.arange(0.005, far + 0.01, 0.005)
        pts = np.stack((np.outer(cos, steps), np.outer(sin, steps)), axis=-1).reshape(-1, 2)
        inside = inside_polygon(pts, self._footprint).reshape(n, steps.size)
        last = np.where(inside.any(axis=1),
                        steps[inside.shape[1] - 1 - np.argmax(inside[:, ::-1], axis=1)],
                        np.nan)
        return last

    def reset(self) -> None:
        self._geometry = None
        self.state = np.zeros((RANGES + 1, 0))

    # ------------------------------------------------------------------ per scan
    def follow_noise(self, scan: Scan) -> None:
        """Measures the range noise of ``scan``'s returns within ``reach`` (the running mean
        :attr:`range_noise`) and sets the tolerance the kernels use: ``tolerance``, or
        ``noise_sigmas`` times the noise when that is larger."""
        c = self.config
        noise = range_noise(scan.ranges, max(scan.range_min, 1e-6), c.reach)
        if noise is not None:
            previous = self.range_noise
            self.range_noise = noise if previous is None else \
                previous + NOISE_WEIGHT * (noise - previous)
        tolerance = c.tolerance
        if self.range_noise is not None:
            tolerance = max(tolerance, c.noise_sigmas * self.range_noise)
        if tolerance != self.settings[_TOLERANCE]:
            self.settings[_TOLERANCE] = tolerance
            self.settings[_STALE] = 1.0               # the mask's margin changed

    def mask(self, scan: Scan) -> np.ndarray:
        """Beams of ``scan`` whose return is the body."""
        self.fit(scan)
        ranges = self.ranges
        with np.errstate(invalid='ignore'):
            return scan.ranges <= ranges          # NaN: False

    def apply(self, scan: Scan) -> tuple[Scan, np.ndarray]:
        """``scan`` with its body returns and its mixed returns at nearer edges as NaN (a
        copy when any), and the mask; ``masked_ranges`` is then the mask as per-beam
        ranges (returns up to them are masked; NaN: none), what detection applies."""
        masked = self.mask(scan)
        self.masked_ranges = self.ranges
        if self.config.beam_width > 0:
            mixed = mixed_returns(scan, self.config.beam_width)
            if mixed.any():
                masked |= mixed
                self.masked_ranges[mixed] = np.fmax(self.masked_ranges[mixed],
                                                    scan.ranges[mixed])
        if not masked.any():
            return scan, masked
        ranges = scan.ranges.copy()
        ranges[masked] = np.nan
        out = Scan(stamp=scan.stamp, ranges=ranges, angle_min=scan.angle_min,
                   angle_increment=scan.angle_increment, range_min=scan.range_min,
                   range_max=scan.range_max, time_increment=scan.time_increment,
                   scan_time=scan.scan_time, frame_id=scan.frame_id, stamp_ns=scan.stamp_ns)
        return out, masked

    def unlearnt(self, scan: Scan) -> np.ndarray:
        """Beams of ``scan`` whose return is probably the body but not learnt yet: it has kept
        its range while the world moved past it by ``PROVISIONAL_TRAVEL`` (a tenth of what
        learning takes). Not for the scan match: the body matches itself, and would pull
        the match towards standing still before it is learnt."""
        self.fit(scan)
        with np.errstate(invalid='ignore'):
            kept = np.abs(scan.ranges - self.anchor) <= self.settings[_TOLERANCE]
        return kept & (self.kept >= PROVISIONAL_TRAVEL) & np.isnan(self.body)

    def left_out(self, scan: Scan) -> np.ndarray:
        """Beams of ``scan`` the scan match leaves out: :meth:`mask`, :meth:`unlearnt` or
        a mixed return (one kernel call, :func:`mask_scan`); ``masked_ranges`` is then the
        mask as detection applies it (the body and the mixed returns)."""
        self.fit(scan)
        self.masked_ranges = np.empty(scan.n_beams)
        out = np.empty(scan.n_beams, np.bool_)
        any_masked = mask_scan(scan.ranges, max(scan.range_min, 1e-6), float(scan.range_max),
                                abs(float(scan.angle_increment)), self.settings, self.state,
                                self.masked_ranges, out)
        self.applied = self.masked_ranges if any_masked else None
        return out

    def learn(self, scan: Scan, motion) -> None:
        """Learn from ``scan`` (as received) and the scanner's motion since the previous
        scan (its pose in the previous scanner frame): one kernel call, :func:`learn_scan`."""
        self.fit(scan)
        self.follow_noise(scan)
        x, y, th = (float(v) for v in motion)
        _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment),
                                 scan.n_beams)
        learn_scan(scan.ranges, cos, sin, max(scan.range_min, 1e-6), float(scan.range_max),
                    x, y, th, self.settings, self.state)

    @property
    def ranges(self) -> np.ndarray:
        """Per beam, the farthest range of a return that is the body (NaN: none): the
        footprint's, and the learnt body's plus ``tolerance`` (a copy; empty before the first
        scan)."""
        if self._geometry is None:
            return np.zeros(0)
        _refresh(self.settings, self.state)
        return self.state[RANGES].copy()


@jit.kernel
def _refresh(settings, state):
    """The mask's range (``state[RANGES]``) recomputed when stale: per beam the footprint's
    range and the learnt body's within ``EDGE_BEAMS`` beams plus the tolerance, the larger
    (NaN: none; as numpy's ``fmax``)."""
    if not settings[_STALE]:
        return
    settings[_STALE] = 0.0
    body, limits, out = state[BODY], state[LIMITS], state[RANGES]
    n = body.size
    tolerance = settings[_TOLERANCE]
    for k in range(n):
        far = np.nan
        for j in range(max(k - EDGE_BEAMS, 0), min(k + EDGE_BEAMS + 1, n)):
            if math.isnan(far) or body[j] > far:
                far = body[j]
        out[k] = _fmax(limits[k], far + tolerance)


@jit.inline
def _fmax(a, b):
    """numpy's ``fmax``: the larger, a NaN ignored."""
    if math.isnan(a):
        return b
    if math.isnan(b):
        return a
    return a if a >= b else b


@jit.kernel
def mask_scan(r, range_min, range_max, increment, settings, state, masked_ranges, out):
    """:meth:`SelfMask.left_out` into ``out`` (bool per beam) and ``masked_ranges``; True
    when any beam is masked."""
    _refresh(settings, state)
    ranges = state[RANGES]
    for k in range(r.size):
        masked_ranges[k] = ranges[k]
    _left_out(r, ranges, state[ANCHOR], state[KEPT], state[BODY], settings[_TOLERANCE],
              settings[_PROVISIONAL], range_min, range_max, increment, settings[_WIDTH],
              settings[_JUMP], masked_ranges, out)
    for k in range(r.size):
        if math.isfinite(masked_ranges[k]):
            return True
    return False


@jit.kernel
def learn_scan(r, cos, sin, range_min, range_max, x, y, th, settings, state):
    """:meth:`SelfMask.learn`: nothing when learning is off or the motion is not finite;
    marks the mask's range stale when the learnt body changed."""
    if not settings[_LEARN] or not (math.isfinite(x) and math.isfinite(y)
                                    and math.isfinite(th)):
        return
    if _learn(r, cos, sin, range_min, range_max, x, y, th, settings[_REACH],
              settings[_TOLERANCE], settings[_TRAVEL], settings[_FORGET], settings[_SURFACE],
              state[KEPT], state[ANCHOR], state[BODY], state[BEYOND]):
        settings[_STALE] = 1.0


@jit.kernel
def _left_out(r, body_ranges, anchor, kept, body, tolerance, provisional, range_min,
              range_max, increment, width, jump, masked_ranges, out):
    """Per beam: ``r <= body_ranges`` (the body; NaN: no), or it kept its ``anchor``
    within ``tolerance`` over ``provisional`` metres of world travel and is not learnt
    (``body`` NaN): :meth:`SelfMask.mask` or :meth:`SelfMask.unlearnt`; or a mixed return
    (:func:`_mark_mixed`), whose range then joins ``masked_ranges``; into ``out``."""
    for k in range(r.size):
        out[k] = r[k] <= body_ranges[k] or (abs(r[k] - anchor[k]) <= tolerance
                                             and kept[k] >= provisional
                                             and math.isnan(body[k]))
    if width > 0.0:
        mixed = np.zeros(r.size, np.bool_)
        _mark_mixed(r, range_min, range_max, increment, width, jump, mixed)
        for k in range(r.size):
            if mixed[k]:
                out[k] = True
                if not r[k] <= masked_ranges[k]:
                    masked_ranges[k] = r[k]


@jit.kernel
def without_body(ranges, body, out):
    """``ranges`` into ``out`` with the returns up to ``body`` (per beam; NaN: none) as NaN
    (detection's view of a scan, ``StampedPose.body``); True when any beam is masked."""
    masked = False
    for k in range(ranges.size):
        if ranges[k] <= body[k]:
            out[k] = np.nan
            masked = True
        else:
            out[k] = ranges[k]
    return masked


def mixed_returns(scan: Scan, beam_width: float) -> np.ndarray:
    """Beams of ``scan`` partly blocked by a nearer edge (see the module docstring)."""
    out = np.zeros(scan.n_beams, np.bool_)
    _mixed(scan.ranges, max(scan.range_min, 1e-6), float(scan.range_max),
           abs(float(scan.angle_increment)), float(beam_width), EDGE_JUMP, out)
    return out


@jit.kernel
def _mixed(r, range_min, range_max, increment, width, jump, out):
    """:func:`_mark_mixed` as a kernel of its own (:func:`mixed_returns`)."""
    _mark_mixed(r, range_min, range_max, increment, width, jump, out)


@jit.inline
def _mark_mixed(r, range_min, range_max, increment, width, jump, out):
    """Marks in ``out`` the returns beside each range step of at least ``jump`` between
    neighbouring returns, on its far side: as many beams as the beam's ``width`` spans at
    the nearer return's range (a mixed return may lie anywhere between the two ranges)."""
    n = r.size
    if increment <= 0.0:
        return
    for i in range(n - 1):
        a, b = r[i], r[i + 1]
        if not (a >= range_min and a < range_max and b >= range_min and b < range_max):
            continue
        if abs(a - b) < jump:
            continue
        near = min(a, b)
        span = int(width / (near * increment))
        if span <= 0:
            continue
        if a < b:                                   # the far side runs on after i + 1
            for k in range(i + 1, min(n, i + 1 + span)):
                if r[k] >= range_min and r[k] < range_max:
                    out[k] = True
        else:                                       # ... back from i
            for k in range(i, max(-1, i - span), -1):
                if r[k] >= range_min and r[k] < range_max:
                    out[k] = True


@jit.inline
def _within(dx, dy, limit):
    """``math.hypot(dx, dy) <= limit`` (hypot only where the squares leave it open: it
    costs more than the rest of a beam)."""
    side = jit.compare_length(dx, dy, limit)
    return side < 0 or (side == 0 and math.hypot(dx, dy) <= limit)


@jit.kernel
def _learn(r, cos, sin, range_min, range_max, x, y, th, reach, tolerance, travel,
           forget_travel, surface_jump, kept, anchor, body, beyond):
    """One scan's learning, in place on the per-beam state (``kept``, ``anchor``, ``body``,
    ``beyond``); returns whether the learnt body changed.

    A return within ``reach`` whose surface lies entirely within reach (its run of returns,
    beams without a return skipped, each within ``surface_jump`` of the previous one) and
    that keeps its ``anchor`` range within ``tolerance`` adds the distance a static point
    there moved in the scanner's frame over this step (the scanner's motion ``x, y, th``) to
    ``kept``; a return that moved, or lies on the world, starts afresh; a beam without a
    return keeps its evidence (a body part seen at grazing incidence flickers). At ``travel``
    the anchor is the body. A learnt beam that sees only the world beyond its body while the
    world moves past it by ``forget_travel`` is given up."""
    n = r.size
    hit = np.zeros(n, np.bool_)
    within = np.zeros(n, np.bool_)
    cth, sth = math.cos(th), math.sin(th)
    run_start = -1
    farthest = 0.0
    last = -1
    for k in range(n + 1):
        if k < n:
            rk = r[k]
            if not (math.isfinite(rk) and rk >= range_min and rk < range_max):
                continue
            hit[k] = True
            px, py = rk * cos[k], rk * sin[k]
            if last >= 0 and _within(px - r[last] * cos[last], py - r[last] * sin[last],
                                     surface_jump):
                farthest = max(farthest, rk)
                last = k
                continue
        if run_start >= 0:                       # a run ended: is all of it within reach?
            for j in range(run_start, last + 1):
                within[j] = hit[j] and farthest <= reach
        if k < n:
            run_start, last, farthest = k, k, r[k]
    changed = False
    for k in range(n):
        rk = r[k]
        near = hit[k] and rk <= reach and within[k]
        keeps = near and abs(rk - anchor[k]) <= tolerance
        if keeps:
            kept[k] += _moved(rk * cos[k], rk * sin[k], x, y, cth, sth)
        elif hit[k]:
            kept[k] = 0.0
        if near and not keeps:
            anchor[k] = rk
        elif hit[k] and not near:
            anchor[k] = np.nan
        if kept[k] >= travel:
            learnt = anchor[k] if math.isnan(body[k]) else \
                (body[k] if math.isnan(anchor[k]) else max(body[k], anchor[k]))
            if not (learnt == body[k] or (math.isnan(learnt) and math.isnan(body[k]))):
                body[k] = learnt
                changed = True
        if hit[k]:
            if rk > body[k] + tolerance:
                beyond[k] += _moved(rk * cos[k], rk * sin[k], x, y, cth, sth)
            elif rk <= body[k] + tolerance:
                beyond[k] = 0.0
        if beyond[k] >= forget_travel:
            if not math.isnan(body[k]):
                changed = True
            body[k] = np.nan
            beyond[k] = 0.0
    return changed


@jit.inline
def _moved(px, py, x, y, cth, sth):
    """How far the static point ``(px, py)`` of the scanner's frame moves in it when the
    scanner moves by ``x, y`` and turns by the angle of cosine ``cth`` and sine ``sth``;
    computed only for the returns that use it (a hypot costs more than the rest of a
    beam)."""
    qx, qy = px - x, py - y
    return math.hypot(cth * qx + sth * qy - px, -sth * qx + cth * qy - py)


def _exercise_learn() -> None:
    """The kernels compiled (or loaded) for the argument types of real scans."""
    _, cos, sin = beam_table(-1.5, 0.075, 41)
    ranges = np.full(41, 0.5)
    ranges[0] = np.nan
    settings = np.array([0.05, PROVISIONAL_TRAVEL, 0.03, EDGE_JUMP, 1.0, 1.0, 2.0, 20.0,
                         SURFACE_JUMP, 1.0])
    state = np.zeros((RANGES + 1, 41))
    state[[ANCHOR, BODY, LIMITS]] = np.nan
    learn_scan(ranges, cos, sin, 0.01, 10.0, 0.1, 0.0, 0.01, settings, state)
    mask_scan(ranges, 0.01, 10.0, 0.075, settings, state, np.empty(41),
               np.empty(41, np.bool_))
    ranges[20:] = 5.0
    _mixed(ranges, 0.01, 10.0, 0.075, 0.03, EDGE_JUMP, np.zeros(41, np.bool_))
    without_body(ranges, state[RANGES], np.empty(41))
    _range_noise(ranges, 0.01, 1.0, NOISE_MIN_TRIPLES)
