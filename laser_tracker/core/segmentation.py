"""Split one scan into segments by jump distance and describe each segment's shape.

A segment (a cluster) is a run of consecutive valid end points (beam order, beams without a
return skipped) in which each point lies within ``jump_distance`` of the previous one; on a
scan that closes the circle (a 360 deg scanner) the run goes on from the last beam to the
first, and the beams beside a cluster's ends are taken around it too. The
scan's segments (:class:`SegmentConfig`, ``segments.*``) are what the person detector
classifies and, when it does not run, the compact segments that keep a stopped object's
track alive: one segmentation, one kernel call per scan (:func:`segment`). The features
are meant to classify a cluster as a leg on scanners the classifier has never seen (0.25 to
1 degree between beams), so none of them is a raw point count: every feature is a length, an
angle or a ratio of the cluster's shape, or a count normalised by what the beam spacing at
that range predicts.

The features, in the order of :data:`FEATURE_NAMES` (``n`` points ``p_0 .. p_{n-1}`` in beam
order, ``c`` their centroid, ``r = |c|``, ``da`` the angle between beams):

* ``n_rel``: points relative to those a 0.12 m wide object facing the scanner returns at
  range ``r``: ``n * r * da / 0.12``.
* ``width``: distance between the first and the last point (m).
* ``line_rms``: RMS distance of the points to their total-least-squares line (m).
* ``circle_radius``: radius of the least-squares (Kasa) circle through the points (m,
  clipped to 2 m; collinear points give 2).
* ``circle_rms``: RMS distance of the points to that circle (m; to first order: the fit's
  algebraic residual over twice the radius; ``line_rms`` when the radius is clipped).
* ``boundary_ratio``: length of the polyline through the points over ``width`` (1 = straight).
* ``boundary_cv``: regularity of the boundary: standard deviation over mean of the distances
  between consecutive points.
* ``bulge``: mean curvature as the sagitta: mean signed distance of the boundary from the
  chord ``p_0 p_{n-1}`` (trapezoidal: the sum over the points over ``n - 1``; the ends lie on
  the chord) over ``width``, positive when the cluster bulges towards the scanner (the front
  of a leg: about 0.2; a flat surface 0; a concave corner negative).
* ``distance``: range of the centroid ``r`` (m).
* ``occluded_ends``: how many of the two ends (0, 1, 2) are occluded: a return nearer than
  the end among the beams within 0.15 m beside it (at the end's range), so that something
  in front may hide part of the cluster.
* ``clear_min``, ``clear_max``: at each end, the nearest return among those beams minus the
  end's range, the smaller and the larger of the two (m, clipped to [-0.5, 0.5]; 0.5 when
  nothing returns there): how freely the cluster stands out from its surroundings (a leg in
  the open: 0.5; clutter: small; occluded: negative). The clip makes a background 0.5 m or
  more behind the same as none: the leg_tracker training recordings have no return beside
  most legs (the people walked in open space), and without the clip a classifier learns
  that a wall far behind a leg makes it no leg.

:data:`FEATURE_SET` names this definition; a model file trained on another one is refused.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core import jit
from laser_tracker.core.jit import pairwise_sum
from laser_tracker.core.detections import Rows
from laser_tracker.core.scan import Scan, beam_table

FEATURE_SET = 'leg-shape-1'
# Column order of Clusters.features (``_features`` writes the columns by index).
FEATURE_NAMES = ('n_rel', 'width', 'line_rms', 'circle_radius', 'circle_rms',
                 'boundary_ratio', 'boundary_cv', 'bulge', 'distance', 'occluded_ends',
                 'clear_min', 'clear_max')
LEG_WIDTH = 0.12            # m, the object size that n_rel is relative to
MAX_RADIUS = 2.0            # m, circle radius clip (collinear points)
CLEARANCE = 0.15            # m beside each end searched for the nearest return
MAX_WINDOW_ANGLE = np.pi / 4   # rad, the widest such search (for very near clusters)
MAX_CLEAR = 0.5             # m, clearance clip (see clear_min)
_EPS = 1e-9


@dataclass(frozen=True)
class SegmentConfig:
    """The scan's segments (node ``detection``, ``segments.*``): what the person detector
    classifies and, when it does not run, the compact segments that keep a stopped object's
    track alive."""

    jump_distance: float = param(0.13, 'Consecutive scan points further apart than this (m) '
                                 'end a segment; for the person detector keep the value its '
                                 'model was trained with.', min=0.01, max=2.0)
    min_points: int = param(3, 'Fewest points of a segment.', min=3, max=1000)
    max_width: float = param(1.0, 'Segments wider than this (m, end to end) are structure '
                             '(walls; two legs side by side are about 0.4 m), not an '
                             'object.', min=0.05, max=10.0)


@dataclass
class Clusters(Rows):
    """The clusters of one scan that passed the size filters: plain arrays, one row each.

    ``first`` / ``last`` are beam indices into the scan; ``xy`` the centroid in the scanner
    frame; ``features`` (k, len(FEATURE_NAMES)) float64; ``occluded`` (k, 2) bool: a nearer
    return beside the first / last end (see ``occluded_ends``).
    """

    xy: np.ndarray
    first: np.ndarray
    last: np.ndarray
    n_points: np.ndarray
    features: np.ndarray
    occluded: np.ndarray
    total: int = 0              # clusters found before the filters (0: too few points)

    @classmethod
    def empty(cls, total: int = 0) -> Clusters:
        return cls(xy=np.zeros((0, 2)), first=np.zeros(0, dtype=np.intp),
                   last=np.zeros(0, dtype=np.intp), n_points=np.zeros(0, dtype=np.intp),
                   features=np.zeros((0, len(FEATURE_NAMES))),
                   occluded=np.zeros((0, 2), dtype=bool), total=total)

    def feature(self, name: str) -> np.ndarray:
        return self.features[:, FEATURE_NAMES.index(name)]


def segment(scan: Scan, jump_distance: float = 0.13, min_points: int = 3,
            max_width: float = 1.0, max_range: float | None = None) -> Clusters:
    """Clusters of ``scan`` with at least ``min_points`` (>= 3) points, at most ``max_width``
    metres between their ends and their centroid within ``max_range``, with their features:
    one kernel call."""
    args, seam = kernel_arguments(scan, jump_distance, min_points, max_width, max_range)
    return as_clusters(_clusters(*args), seam)


def segments_of(scan: Scan, config: SegmentConfig, max_range: float | None = None) -> Clusters:
    """:func:`segment` with the settings of ``config``."""
    return segment(scan, config.jump_distance, config.min_points, config.max_width, max_range)


def kernel_arguments(scan: Scan, jump_distance: float, min_points: int, max_width: float,
                     max_range: float | None) -> tuple[tuple, tuple[int, int]]:
    """The arguments of :func:`_clusters` for :func:`segment`'s, and the seam: ``(beam,
    beams)``, where a scan that closes the circle was made to start (:func:`seam_beam`; the
    kernel's beam indices count from there)."""
    _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment), scan.n_beams)
    ranges, valid_min, range_max = scan.ranges, max(scan.range_min, 1e-6), float(scan.range_max)
    start = seam_beam(ranges, cos, sin, valid_min, range_max, float(scan.angle_increment),
                      float(jump_distance))
    if start:
        ranges, cos, sin = (np.roll(a, -start) for a in (ranges, cos, sin))
        cos.setflags(write=False)           # as beam_table's: the kernels' compiled types
        sin.setflags(write=False)
    return (ranges, cos, sin, valid_min, range_max, abs(float(scan.angle_increment)),
            float(jump_distance), max(int(min_points), 3), float(max_width),
            np.inf if max_range is None else float(max_range),
            closes_circle(scan.n_beams, float(scan.angle_increment))), (start, scan.n_beams)


def closes_circle(beams: int, increment: float) -> bool:
    """Whether a scan of ``beams`` beams ``increment`` apart closes the circle (its last beam
    beside its first: a 360 deg scanner)."""
    step = abs(increment)
    return beams >= 2 and beams * step >= 2.0 * math.pi - 0.5 * step


def seam_beam(ranges, cos, sin, valid_min: float, range_max: float, increment: float,
              jump: float) -> int:
    """Where to start a scan that closes the circle (a 360 deg scanner: its last beam beside
    its first) so that no segment straddles its two ends: the first return more than
    ``jump`` from the return before it, around the circle. When no two are (every return on
    one object: a person alone in the open), the return after the widest run of beams
    without one, where that object's two ends lie. 0 for a scan that does not close the
    circle, or whose two ends already lie apart."""
    if not closes_circle(ranges.size, increment):
        return 0
    beams = np.flatnonzero((ranges >= valid_min) & (ranges < range_max))
    if beams.size < 2:
        return 0
    x, y = ranges[beams] * cos[beams], ranges[beams] * sin[beams]
    apart = np.flatnonzero(np.hypot(x - np.roll(x, 1), y - np.roll(y, 1)) > jump)
    if not apart.size:
        skipped = np.diff(beams, append=beams[0] + ranges.size)   # to the next return
        return int(beams[(int(np.argmax(skipped)) + 1) % beams.size])
    if apart[0] == 0:
        return 0
    return int(beams[apart[0]])


def as_clusters(raw: tuple, seam: tuple[int, int] = (0, 0)) -> Clusters:
    """:class:`Clusters` of :func:`_clusters`' result (``seam``: where the kernel's scan
    started, see :func:`kernel_arguments`)."""
    xy, ends, n_points, features, clear, total = raw
    if xy.shape[0] == 0:
        return Clusters.empty(total=total)
    start, beams = seam
    if start:
        ends = (ends + start) % beams
    return Clusters(xy=xy, first=ends[:, 0], last=ends[:, 1], n_points=n_points,
                    features=features, occluded=clear < 0.0, total=total)


# ------------------------------------------------------------------------------ kernels


@jit.kernel
def _clusters(ranges, cos, sin, valid_min, range_max, da, jump, min_points, max_width,
              max_range, closed):
    """The clusters of a scan (see :func:`segment`) that pass the filters: centroids, first
    and last beams, points, features, the clearances of the first and the last end; and how
    many clusters there were before the filters. Sums over a cluster's points are added as
    ``np.add.reduceat`` adds them (:func:`_reduceat`), so that the features stay those of
    the numpy formulation bit for bit. ``closed``: the scan closes the circle (its last beam
    beside its first), so the beams beside an end are taken around it."""
    n = ranges.size
    beams = np.empty(n, np.intp)
    m = 0
    for i in range(n):
        if ranges[i] >= valid_min and ranges[i] < range_max:           # NaN: False
            beams[m] = i
            m += 1
    n_feat = len(FEATURE_NAMES)
    if m < min_points:
        return (np.zeros((0, 2)), np.zeros((0, 2), np.intp), np.zeros(0, np.intp),
                np.zeros((0, n_feat)), np.zeros((0, 2)), 0)
    px = np.empty(m)
    py = np.empty(m)
    for k in range(m):
        px[k] = ranges[beams[k]] * cos[beams[k]]
        py[k] = ranges[beams[k]] * sin[beams[k]]
    step = np.empty(m)                   # to the next point of the cluster, 0 at its end
    starts = np.empty(m + 1, np.intp)
    total = 1
    starts[0] = 0
    for k in range(m - 1):
        dx, dy = px[k + 1] - px[k], py[k + 1] - py[k]
        step[k] = math.sqrt(dx * dx + dy * dy)
        if step[k] > jump:
            starts[total] = k + 1
            total += 1
            step[k] = 0.0
    step[m - 1] = 0.0
    starts[total] = m
    # A window of beams beside each end for the clearances: ranges, inf where no return.
    free = np.full(n + 1, np.inf)
    for k in range(m):
        free[beams[k]] = ranges[beams[k]]
    xy = np.empty((total, 2))
    ends = np.empty((total, 2), np.intp)
    counts = np.empty(total, np.intp)
    out = np.empty((total, n_feat))
    clear = np.empty((total, 2))
    kept = 0
    for c in range(total):
        a, b = starts[c], starts[c + 1] - 1
        count = b - a + 1
        if count < min_points:
            continue
        chx, chy = px[b] - px[a], py[b] - py[a]
        width = math.sqrt(chx * chx + chy * chy)
        if not width <= max_width:
            continue
        nf = float(count)
        cx, cy = _reduceat(px, a, b) / nf, _reduceat(py, a, b) / nf
        distance = math.sqrt(cx * cx + cy * cy)
        if not distance <= max_range:
            continue
        f = out[kept]
        _shape_features(px, py, step, a, b, cx, cy, nf, width, chx, chy, f)
        f[0] = nf * distance * (da / LEG_WIDTH)
        f[1], f[8] = width, distance
        for e in range(2):                      # the beams beside the first / last end
            beam = beams[a] if e == 0 else beams[b]
            r = ranges[beam]
            span = int(min(math.ceil(CLEARANCE / (r * da)), math.ceil(MAX_WINDOW_ANGLE / da)))
            lo, hi = (beam - span, beam - 1) if e == 0 else (beam + 1, beam + span)
            if not closed:
                lo, hi = max(lo, 0), min(hi, n - 1)
            near = _window_min(free, lo, hi, n)
            clear[kept, e] = min(max(near - r, -MAX_CLEAR), MAX_CLEAR)  # inf: nothing there
        c0, c1 = clear[kept, 0], clear[kept, 1]
        f[9] = (1.0 if c0 < 0.0 else 0.0) + (1.0 if c1 < 0.0 else 0.0)
        f[10], f[11] = min(c0, c1), max(c0, c1)
        xy[kept, 0], xy[kept, 1] = cx, cy
        ends[kept, 0], ends[kept, 1] = beams[a], beams[b]
        counts[kept] = count
        kept += 1
    return xy[:kept], ends[:kept], counts[:kept], out[:kept], clear[:kept], total


@jit.kernel
def _shape_features(px, py, step, a, b, cx, cy, n, width, chx, chy, f):
    """The shape features 2-7 of the cluster of points ``a..b`` into ``f`` (see the module
    docstring): line and circle fits in centred coordinates, boundary length and
    regularity, bulge."""
    terms = np.empty((8, b - a + 1))
    for k in range(a, b + 1):
        ux, uy = px[k] - cx, py[k] - cy
        uu, vv = ux * ux, uy * uy
        z = uu + vv
        t = (uu, vv, ux * uy, z * ux, z * uy, z * z, step[k], step[k] * step[k])
        for i in range(8):
            terms[i, k - a] = t[i]
    sums = np.empty(8)
    for i in range(8):
        sums[i] = _reduceat(terms[i], 0, b - a)
    suu, svv, suv, szu = sums[0], sums[1], sums[2], sums[3]
    szv, szz, length, length_sq = sums[4], sums[5], sums[6], sums[7]
    # Total least squares line: the smaller eigenvalue of the scatter matrix.
    half_trace = 0.5 * (suu + svv)
    root = math.sqrt(0.25 * (suu - svv) ** 2 + suv * suv)
    line_rms = math.sqrt(_at_least(half_trace - root, 0.0) / n)
    # Kasa circle in centred coordinates (minimises sum (|u - c|^2 - R^2)^2): a 2x2 linear
    # system. Its minimum over (2R)^2 is the squared geometric residual to first order.
    det2 = 2.0 * (suu * svv - suv * suv)
    uc = (svv * szu - suv * szv) / det2
    vc = (suu * szv - suv * szu) / det2
    mean_z = 2.0 * half_trace / n
    radius = math.sqrt(uc * uc + vc * vc + mean_z)
    residual = szz - n * mean_z * mean_z - 2.0 * (uc * szu + vc * szv)
    circle_rms = math.sqrt(_at_least(residual, 0.0) / n) / (2.0 * radius)
    f[2] = line_rms
    if radius <= MAX_RADIUS:                    # False also for NaN (collinear: det = 0)
        f[3], f[4] = radius, circle_rms
    else:
        f[3], f[4] = MAX_RADIUS, line_rms
    # Boundary length over the width, and the spread of the steps over their mean.
    safe_width = _at_least(width, _EPS)
    mean_step = length / (n - 1.0)
    f[5] = length / safe_width
    f[6] = math.sqrt(_at_least(length_sq / (n - 1.0) - mean_step * mean_step, 0.0)) / \
        _at_least(mean_step, _EPS)
    # Bulge: n / (n - 1) times the distance of the centroid from the chord (cross(chord,
    # c - first) / width), positive on the scanner's side of the chord, over the width.
    side = chx * (cy - py[a]) - chy * (cx - px[a])
    towards = chy * px[a] - chx * py[a]                          # the scanner's side
    f[7] = math.copysign(side, side * towards) * (n / (n - 1.0)) / (safe_width * safe_width)


@jit.kernel
def _reduceat(values, a, b):
    """``np.add.reduceat``'s sum of ``values[a:b + 1]``: the first value plus numpy's
    pairwise sum of the others."""
    return values[a] + pairwise_sum(values, a + 1, b - a)


@jit.kernel
def _at_least(x, low):
    """``np.maximum(x, low)`` (a NaN stays NaN)."""
    return low if x < low else x


@jit.kernel
def _window_min(values, lo, hi, n):
    """``min(values[lo:hi + 1])`` with the indices taken modulo ``n`` (around a scan that
    closes the circle), inf when the window is empty (hi < lo)."""
    out = np.inf
    for i in range(lo, hi + 1):
        out = min(out, values[i % n])
    return out


def window_min(values: np.ndarray, lo, hi) -> np.ndarray:
    """``min(values[lo[i]:hi[i] + 1])`` for each i (``0 <= lo <= values.size``,
    ``-1 <= hi < values.size``), inf where the window is empty (hi < lo)."""
    values = np.asarray(values, dtype=float)
    return np.array([_window_min(values, int(a), int(b), values.size) for a, b in zip(lo, hi)])
