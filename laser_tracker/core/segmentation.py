"""Split one scan into clusters by jump distance and describe each cluster's shape.

A cluster is a run of consecutive valid end points (beam order, beams without a return
skipped) in which each point lies within ``jump_distance`` of the previous one. The features
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
* ``bulge``: mean curvature as the sagitta: mean signed distance of the points from the
  chord ``p_0 p_{n-1}`` over ``width``, positive when the cluster bulges towards the scanner
  (the front of a leg: about 0.1 to 0.2; a flat surface 0; a concave corner negative).
* ``distance``: range of the centroid ``r`` (m).
* ``occluded_ends``: how many of the two ends (0, 1, 2) are occluded: a return nearer than
  the end among the beams within 0.15 m beside it (at the end's range), so that something
  in front may hide part of the cluster.
* ``clear_min``, ``clear_max``: at each end, the nearest return among those beams minus the
  end's range, the smaller and the larger of the two (m, clipped to [-3, 3]; 3 when nothing
  returns there): how freely the cluster stands out from its surroundings (a leg in the
  open: large; clutter: small or negative; occluded: negative).

:data:`FEATURE_SET` names this definition; a model file trained on another one is refused.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_tracker.core.scan import Scan, beam_table

FEATURE_SET = 'leg-shape-1'
FEATURE_NAMES = ('n_rel', 'width', 'line_rms', 'circle_radius', 'circle_rms',
                 'boundary_ratio', 'boundary_cv', 'bulge', 'distance', 'occluded_ends',
                 'clear_min', 'clear_max')
LEG_WIDTH = 0.12            # m, the object size that n_rel is relative to
MAX_RADIUS = 2.0            # m, circle radius clip (collinear points)
CLEARANCE = 0.15            # m beside each end searched for the nearest return
MAX_WINDOW_ANGLE = np.pi / 4   # rad, the widest such search (for very near clusters)
MAX_CLEAR = 3.0             # m
_EPS = 1e-9


@dataclass
class Clusters:
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
    total: int = 0              # clusters found before the size filters

    @property
    def count(self) -> int:
        return int(self.xy.shape[0])

    def __len__(self) -> int:
        return self.count

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
    metres between their ends and their centroid within ``max_range``, with their features.

    The cost per scan is a fixed number of numpy calls (about a hundred): every quantity is
    computed for all clusters at once, per-cluster sums with one ``np.add.reduceat``, and the
    clusters that fail the size filters are dropped at the end.
    """
    min_points = max(int(min_points), 3)
    ranges = scan.ranges
    with np.errstate(all='ignore'):
        return _segment(scan, ranges, jump_distance, min_points, max_width, max_range)


def _segment(scan, ranges, jump_distance, min_points, max_width, max_range) -> Clusters:
    valid = (ranges >= max(scan.range_min, 1e-6)) & (ranges < scan.range_max)  # NaN: False
    beams = np.flatnonzero(valid)
    m = beams.size
    if m < min_points:
        return Clusters.empty(total=int(m > 0))
    _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment), scan.n_beams)
    r = ranges[beams]
    p = np.empty((m, 2))
    np.multiply(r, cos[beams], out=p[:, 0])
    np.multiply(r, sin[beams], out=p[:, 1])
    step = p[1:] - p[:-1]
    step_len = np.sqrt(np.einsum('ij,ij->i', step, step))
    cut = step_len > jump_distance
    start = np.empty(m, dtype=bool)
    start[0] = True
    start[1:] = cut
    starts = np.flatnonzero(start)
    k = starts.size
    counts = np.empty(k, dtype=np.intp)
    counts[:-1] = starts[1:]
    counts[-1] = m
    counts -= starts
    ends = starts + counts - 1
    features, centroid = _features(scan, valid, beams, r, p, step_len, cut, starts, ends, counts)
    keep = (counts >= min_points) & (features[:, 1] <= max_width)
    if max_range is not None:
        keep &= features[:, 8] <= max_range
    kept = np.flatnonzero(keep)
    if kept.size == 0:
        return Clusters.empty(total=k)
    features = features[kept]
    return Clusters(xy=centroid[kept], first=beams[starts[kept]], last=beams[ends[kept]],
                    n_points=counts[kept], features=features[:, :len(FEATURE_NAMES)],
                    occluded=features[:, len(FEATURE_NAMES):] < 0.0, total=k)


def _features(scan, valid, beams, r, p, step_len, cut, starts, ends, counts):
    """The features of every cluster (rows of clusters under 3 points are garbage) followed
    by the clearances of its first and last end, and the centroids."""
    k, m = starts.size, p.shape[0]
    n = counts.astype(np.float64)
    out = np.empty((k, len(FEATURE_NAMES) + 2))      # + the two end clearances, unsorted
    centroid = np.add.reduceat(p, starts, axis=0)
    centroid /= n[:, None]
    # Per-point terms about the centroid summed per cluster in one reduceat: second moments,
    # the circle fit's third and fourth, and the boundary steps.
    u = p - centroid[np.repeat(np.arange(k), counts)]
    ux, uy = u[:, 0], u[:, 1]
    q = np.empty((m, 8))
    np.multiply(ux, ux, out=q[:, 0])
    np.multiply(uy, uy, out=q[:, 1])
    np.multiply(ux, uy, out=q[:, 2])
    z = q[:, 0] + q[:, 1]
    np.multiply(z, ux, out=q[:, 3])
    np.multiply(z, uy, out=q[:, 4])
    np.multiply(z, z, out=q[:, 5])
    q[:-1, 6] = step_len * ~cut                 # the step to the next point of the cluster
    q[-1, 6] = 0.0
    np.multiply(q[:, 6], q[:, 6], out=q[:, 7])
    suu, svv, suv, szu, szv, szz, length, length_sq = np.add.reduceat(q, starts, axis=0).T

    ends3 = p[np.concatenate((starts, ends))]
    first, last = ends3[:k], ends3[k:]
    chord = last - first
    width = np.sqrt(np.einsum('ij,ij->i', chord, chord), out=out[:, 1])
    distance = np.sqrt(np.einsum('ij,ij->i', centroid, centroid), out=out[:, 8])
    np.multiply(n * distance, abs(float(scan.angle_increment)) / LEG_WIDTH, out=out[:, 0])
    # Total least squares line: the smaller eigenvalue of the scatter matrix.
    half_trace = 0.5 * (suu + svv)
    root = np.sqrt(0.25 * (suu - svv) ** 2 + suv * suv)
    line_rms = np.sqrt(np.maximum(half_trace - root, 0.0) / n, out=out[:, 2])
    # Kasa circle in centred coordinates (minimises sum (|u - c|^2 - R^2)^2): a 2x2 linear
    # system per cluster. Its minimum over (2R)^2 is the squared geometric residual to first
    # order.
    det2 = 2.0 * (suu * svv - suv * suv)
    uc = (svv * szu - suv * szv) / det2
    vc = (suu * szv - suv * szu) / det2
    mean_z = 2.0 * half_trace / n
    radius = np.sqrt(uc * uc + vc * vc + mean_z)
    residual = szz - n * mean_z * mean_z - 2.0 * (uc * szu + vc * szv)
    circle_rms = np.sqrt(np.maximum(residual, 0.0) / n) / (2.0 * radius)
    round_ = radius <= MAX_RADIUS               # False also for NaN (collinear: det = 0)
    np.copyto(out[:, 3], MAX_RADIUS)
    np.copyto(out[:, 3], radius, where=round_)
    np.copyto(out[:, 4], line_rms)
    np.copyto(out[:, 4], circle_rms, where=round_)
    # Boundary length over the width, and the spread of the steps over their mean.
    safe_width = np.maximum(width, _EPS)
    mean_step = length / (n - 1.0)
    np.divide(length, safe_width, out=out[:, 5])
    np.divide(np.sqrt(np.maximum(length_sq / (n - 1.0) - mean_step * mean_step, 0.0)),
              np.maximum(mean_step, _EPS), out=out[:, 6])
    # Bulge: distance of the centroid from the chord (cross(chord, c - first) / width),
    # positive on the scanner's side of the chord, over the width.
    e = centroid - first
    side = chord[:, 0] * e[:, 1] - chord[:, 1] * e[:, 0]
    towards = chord[:, 1] * first[:, 0] - chord[:, 0] * first[:, 1]   # scanner's side
    np.copysign(side, side * towards, out=side)
    np.divide(side, safe_width * safe_width, out=out[:, 7])
    _context(scan, valid, beams, r, starts, ends, out[:, 9:])
    return out, centroid


def _context(scan, valid, beams, r, starts, ends, out) -> None:
    """Occlusion and clearance of both ends of every cluster into ``out`` (k, 5): occluded
    ends, clear_min, clear_max, the clearance of the first end and of the last end.

    An end's window is the beams within CLEARANCE beside it (at its range, at most
    MAX_WINDOW_ANGLE); all windows are reduced by one ``np.minimum.reduceat``.
    """
    k = starts.size
    n = scan.n_beams
    da = abs(float(scan.angle_increment))
    both = np.concatenate((starts, ends))
    b = beams[both]
    r_ends = r[both]
    span = np.minimum(np.ceil(CLEARANCE / (r_ends * da)), np.ceil(MAX_WINDOW_ANGLE / da))
    span = span.astype(np.intp)
    lo = b - span
    hi = b + span
    lo[k:] = b[k:] + 1                         # after the last end
    hi[:k] = b[:k] - 1                         # before the first end
    np.maximum(lo, 0, out=lo)
    np.minimum(hi, n - 1, out=hi)
    free = np.empty(n + 1)                     # ranges, inf where no return
    free[:n] = np.inf
    np.copyto(free[:n], scan.ranges, where=valid)
    free[n] = np.inf
    nearest = _window_min(free, lo, hi)
    nearest -= r_ends
    np.clip(nearest, -MAX_CLEAR, MAX_CLEAR, out=nearest)   # inf (nothing there) -> MAX_CLEAR
    c0, c1 = nearest[:k], nearest[k:]
    np.add(c0 < 0.0, c1 < 0.0, out=out[:, 0], dtype=np.float64)
    np.minimum(c0, c1, out=out[:, 1])
    np.maximum(c0, c1, out=out[:, 2])
    out[:, 3] = c0
    out[:, 4] = c1


def window_min(values: np.ndarray, lo, hi) -> np.ndarray:
    """``min(values[lo[i]:hi[i] + 1])`` for each i (``0 <= lo <= values.size``,
    ``-1 <= hi < values.size``), inf where the window is empty (hi < lo)."""
    lo = np.asarray(lo, dtype=np.intp)
    hi = np.asarray(hi, dtype=np.intp)
    padded = np.empty(values.size + 1)
    padded[:-1] = values
    padded[-1] = np.inf
    return _window_min(padded, lo, hi)


def _window_min(padded: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """:func:`window_min` on values whose last element is an inf sentinel: one
    ``np.minimum.reduceat`` over the interleaved window bounds."""
    if lo.size == 0:
        return np.zeros(0)
    bounds = np.empty(2 * lo.size, dtype=np.intp)
    bounds[0::2] = lo
    bounds[1::2] = hi + 1
    out = np.minimum.reduceat(padded, bounds)[0::2]
    out[hi < lo] = np.inf
    return out
