"""Blob segmentation of the difference map (paper Sec. 6), as compiled kernels.

The changed cells are grouped into 4-connected components (the paper's two-pass labelling,
as ``scipy.ndimage.label`` with a cross-shaped structure numbers them: in raster order of
their first cell). The difference map is sparse (a few to a few tens of cells), so the
components are found among the changed cells alone (union-find over their sorted flat
indices; the tests compare with labelling the full map).

A laser sees only the surface facing it, so a blob's position is the centroid of its visible
cells, tracked as though it were the whole target. Each blob carries:

* ``xy``: centroid in the odometry frame (metres), from the scanner pose ``origin``;
* ``cells``: number of cells; ``extent``: the larger side of its bounding box (metres);
* ``structure``: direction (radians, odometry frame, modulo pi) of the wall-like structure
  it lies on, NaN when there is none (see :func:`_place`). The tracker halves the weight of
  a hypothesis moving along it (paper Sec. 8, the wall penalty).

Visible surfaces are runs of consecutive scan end points (beam order) closer than
``surface_gap``; a blob belongs to the surface of the end point nearest its centroid, and
only that run of beams is read for its position and its wall test.

The blobs are :class:`laser_tracker.core.detections.Blobs`, the motion part of what detection
tells tracking (``core.detections.Detections``).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core import jit
from laser_tracker.core.detections import Blobs

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BlobConfig:
    """Blob filtering and structure test (node ``detection``, ``blobs.*``)."""

    min_cells: int = param(1, 'Smallest blob kept, in cells (paper: every blob).', min=1,
                           max=10000)
    max_cells: int = param(0, 'Largest blob kept, in cells; 0 = no limit (paper). A blob much '
                           'larger than any target is usually a misregistered wall.', min=0,
                           max=1000000)
    max_blobs: int = param(200, 'At most this many blobs per scan (the largest are kept and a '
                           'warning is logged); bounds the work after an ego-motion failure.',
                           min=1, max=100000)
    position: str = param('surface', "Where a blob is: 'changed' = centroid of its changed "
                          "cells; 'surface' = centroid of the visible surface they belong to "
                          '(the scan points of the same range-continuous segment within '
                          "surface_radius), the paper's 'surface tracked as though it were "
                          "the entire target'.", choices=('changed', 'surface'))
    surface_gap: float = param(0.15, "Consecutive scan points further apart than this (m) "
                               "belong to different surfaces.", min=0.01, max=5.0)
    surface_radius: float = param(0.5, 'A surface extends at most this far (m) from the '
                                  'changed cells it is found from (for the position and the '
                                  'structure test).', min=0.05, max=5.0)
    centre_offset: float = param(0.3, "Move a blob away from the scanner by this fraction of "
                                 "its surface's width: the centre of a roughly round object "
                                 'lies about half its width behind the surface the laser sees. '
                                 '0 = the surface itself (paper).', min=0.0, max=2.0)
    structure_min_points: int = param(6, 'Fewest surface points that can form a wall.', min=3,
                                      max=1000)
    structure_elongation: float = param(3.0, 'Ratio of the principal standard deviations of '
                                        'those points above which they form a line (a wall) '
                                        'with a direction.', min=1.0, max=100.0)


# ------------------------------------------------------------------------------ kernels
#
# Settings of the blob kernels (a float array: one argument instead of many).
(_MIN_CELLS, _MAX_CELLS, _MAX_BLOBS, _SURFACE, _GAP, _RADIUS, _CENTRE_OFFSET, _MIN_POINTS,
 _ELONGATION) = range(9)
# Columns of a blob's surface shape: points, their mean (x, y) and covariance (xx, yy, xy),
# and the two arguments of the line direction's arctan2.
_COUNT, _MX, _MY, _CXX, _CYY, _CXY, _ATAN_Y, _ATAN_X = range(8)


def settings_of(config: BlobConfig) -> np.ndarray:
    """The blob kernels' settings array of ``config``."""
    return np.array([config.min_cells, config.max_cells, config.max_blobs,
                     config.position == 'surface', config.surface_gap,
                     config.surface_radius, config.centre_offset,
                     config.structure_min_points, config.structure_elongation], dtype=float)


@jit.kernel
def _root(parent, k):
    while parent[k] != k:
        parent[k] = parent[parent[k]]
        k = parent[k]
    return k


@jit.kernel
def label_cells(flat, cells):
    """4-connected components of the cells ``flat`` (sorted unique flat indices into a
    cells x cells grid, as ``np.unique`` returns them): (number of components, component
    index 0.. of each cell, numbered in raster order of their first cell as
    ``scipy.ndimage.label`` numbers them, and per component the larger side of its bounding
    box in cells)."""
    c = flat.size
    parent = np.arange(c)
    for k in range(c):
        ix, iy = flat[k] // cells, flat[k] % cells
        if iy > 0 and k > 0 and flat[k - 1] == flat[k] - 1:            # left
            a, b = _root(parent, k), _root(parent, k - 1)
            parent[max(a, b)] = min(a, b)
        if ix > 0:                                                       # above
            j = np.searchsorted(flat, flat[k] - cells)
            if j < c and flat[j] == flat[k] - cells:
                a, b = _root(parent, k), _root(parent, j)
                parent[max(a, b)] = min(a, b)
    labels = np.empty(c, np.intp)
    number = np.full(c, -1, np.intp)
    count = 0
    for k in range(c):
        r = _root(parent, k)
        if number[r] < 0:
            number[r] = count
            count += 1
        labels[k] = number[r]
    lo = np.full((count, 2), cells, np.intp)
    hi = np.full((count, 2), -1, np.intp)
    for k in range(c):
        ix, iy = flat[k] // cells, flat[k] % cells
        lab = labels[k]
        lo[lab, 0], lo[lab, 1] = min(lo[lab, 0], ix), min(lo[lab, 1], iy)
        hi[lab, 0], hi[lab, 1] = max(hi[lab, 0], ix), max(hi[lab, 1], iy)
    side = np.empty(count, np.intp)
    for lab in range(count):
        side[lab] = max(hi[lab, 0] - lo[lab, 0], hi[lab, 1] - lo[lab, 1]) + 1
    return count, labels, side


@jit.kernel
def _nearest_surface(points, ids, x, y, resolution):
    """The surface of the end point nearest ``(x, y)``, -1 when none lies within a cell
    diagonal."""
    best, near = np.inf, -1
    for k in range(points.shape[0]):
        dx, dy = x - points[k, 0], y - points[k, 1]
        d2 = dx * dx + dy * dy
        if d2 < best:
            best, near = d2, k
    return ids[near] if near >= 0 and best <= 2.0 * resolution ** 2 else -1


@jit.kernel
def _surface_ids(points, gap):
    """The visible surfaces: runs of consecutive end points closer than ``gap``; per point
    its run's number, per run its first point (and one past the last run)."""
    n = points.shape[0]
    ids = np.empty(n, np.intp)
    starts = np.empty(n + 1, np.intp)
    runs = 0
    for k in range(n):
        if k > 0:
            dx, dy = points[k, 0] - points[k - 1, 0], points[k, 1] - points[k - 1, 1]
            if dx * dx + dy * dy > gap * gap:
                runs += 1
                starts[runs] = k
        else:
            starts[0] = 0
        ids[k] = runs
    starts[runs + 1] = n
    return ids, starts[:runs + 2]


@jit.kernel
def _surface_shape(points, ids, starts, centroids, settings, resolution):
    """(8, b): per blob at ``centroids`` (scanner frame) the shape of its surface: the points
    of the surface of the end point nearest it (a run of beams) within ``surface_radius`` of
    it: how many, their mean and covariance, and the arguments of the arctan2 of their
    principal direction. Their sums are added in the order numpy's ``w @ features`` adds
    them (one blob: OpenBLAS's gemv, in blocks of 4 points counted from the scan's first
    point for the first four features; more blobs: one point after the other), so that the
    figures stay those of the numpy formulation bit for bit."""
    b = centroids.shape[0]
    out = np.zeros((8, b))
    r2 = settings[_RADIUS] ** 2
    n_points = points.shape[0]
    full = n_points - n_points % 4                     # gemv: blocks of 4, then 2, then 1
    pair = full + (n_points - full) // 2 * 2
    sums = np.zeros(5)
    block = np.zeros(4)
    for i in range(b):
        cx, cy = centroids[i, 0], centroids[i, 1]
        sid = _nearest_surface(points, ids, cx, cy, resolution)
        sums[:] = 0.0
        block[:] = 0.0
        current = -1
        count = 0
        for k in range(starts[sid] if sid >= 0 else 0, starts[sid + 1] if sid >= 0 else 0):
            dx, dy = cx - points[k, 0], cy - points[k, 1]
            if not dx * dx + dy * dy <= r2:
                continue
            x, y = points[k, 0], points[k, 1]
            v = (x, y, x * x, y * y, x * y)
            count += 1
            if b > 1:
                for f in range(5):
                    sums[f] += v[f]
                continue
            sums[4] += v[4]
            which = k // 4 if k < full else (full // 4 if k < pair else full // 4 + 1)
            if which != current:
                for f in range(4):
                    sums[f] += block[f]
                    block[f] = 0.0
                current = which
            for f in range(4):
                block[f] += v[f]
        for f in range(4):
            sums[f] += block[f]
        n = max(count, 1)
        mx, my = sums[0] / n, sums[1] / n
        cxx, cyy, cxy = sums[2] / n - mx * mx, sums[3] / n - my * my, sums[4] / n - mx * my
        out[_COUNT, i], out[_MX, i], out[_MY, i] = count, mx, my
        out[_CXX, i], out[_CYY, i], out[_CXY, i] = cxx, cyy, cxy
        out[_ATAN_Y, i], out[_ATAN_X, i] = 2.0 * cxy, cxx - cyy
    return out


@jit.kernel
def _blobs(changed, cells, resolution, points, settings):
    """The blobs of the changed cells ``changed`` (sorted unique flat indices), scanner frame:
    (centroids, cells, extents, surface shapes (:func:`_surface_shape`; none without
    ``points``), blobs dropped by ``max_blobs``, components found)."""
    count, labels, side = label_cells(changed, cells)
    n = np.zeros(count, np.int64)
    local = np.zeros((count, 2))
    for k in range(changed.size):
        lab = labels[k]
        n[lab] += 1
        local[lab, 0] += changed[k] // cells
        local[lab, 1] += changed[k] % cells
    half = cells / 2.0 - 0.5
    for lab in range(count):
        for a in range(2):
            local[lab, a] = (local[lab, a] / n[lab] - half) * resolution
    extent = resolution * side.astype(np.float64)
    dropped = 0
    if settings[_MIN_CELLS] > 1 or settings[_MAX_CELLS] or count > settings[_MAX_BLOBS]:
        keep = n >= settings[_MIN_CELLS]
        if settings[_MAX_CELLS]:
            keep &= n <= settings[_MAX_CELLS]
        kept = np.count_nonzero(keep)
        if kept > settings[_MAX_BLOBS]:      # the largest are kept (of equal ones the first)
            largest = keep.copy()
            for i in range(count):
                if keep[i]:
                    rank = 0
                    for j in range(count):
                        rank += keep[j] and (n[j] > n[i] or (n[j] == n[i] and j < i))
                    largest[i] = rank < settings[_MAX_BLOBS]
            keep = largest
            dropped = kept - int(settings[_MAX_BLOBS])
        m = 0
        for i in range(count):
            if keep[i]:
                local[m], n[m], extent[m] = local[i], n[i], extent[i]
                m += 1
        local, n, extent = local[:m], n[:m], extent[:m]
    if points.shape[0] == 0 or local.shape[0] == 0:
        return local, n, extent, np.zeros((8, 0)), dropped, count
    ids, starts = _surface_ids(points, settings[_GAP])
    b = local.shape[0]
    if settings[_SURFACE] != 0.0 and b > 1:
        # Changed components on one visible surface are one blob (in the order of
        # np.unique over the surfaces, blobs on none first, last blob first).
        sid = np.empty(b, np.intp)
        for i in range(b):
            sid[i] = _nearest_surface(points, ids, local[i, 0], local[i, 1], resolution)
            if sid[i] < 0:
                sid[i] = -1 - i
        groups = jit.unique(sid)
        if groups.size < b:
            g = groups.size
            total = np.zeros(g)
            sums = np.zeros((g, 2))
            big = np.zeros(g)
            for i in range(b):
                j = np.searchsorted(groups, sid[i])
                total[j] += n[i]
                sums[j, 0] += local[i, 0] * n[i]
                sums[j, 1] += local[i, 1] * n[i]
                big[j] = max(big[j], extent[i])
            local = np.empty((g, 2))
            for j in range(g):
                local[j, 0], local[j, 1] = sums[j, 0] / total[j], sums[j, 1] / total[j]
            n, extent = total.astype(np.int64), big
    return local, n, extent, _surface_shape(points, ids, starts, local, settings,
                                            resolution), dropped, count


@jit.kernel
def _place(local, shape, angle, origin, settings, resolution):
    """Per blob (scanner-frame centroid ``local``, surface ``shape``, direction ``angle`` of
    its surface): its position in the odometry frame of scanner pose ``origin`` (with
    ``position`` 'surface': its surface's centroid, moved away from the scanner by
    ``centre_offset`` times the surface's width) and the direction of the wall it lies on
    (see :func:`segment`; NaN where none, else radians mod pi, odometry frame)."""
    b = local.shape[0]
    xy = np.empty((b, 2))
    structure = np.full(b, np.nan)
    c, s = math.cos(origin[2]), math.sin(origin[2])
    measured = shape.shape[1] == b and b > 0
    any_surface = False
    for i in range(shape.shape[1]):
        any_surface |= shape[_COUNT, i] > 0
    offset_ratio = settings[_CENTRE_OFFSET]
    floor = resolution * resolution / 12.0                 # quantisation floor
    for i in range(b):
        px, py = local[i, 0], local[i, 1]
        if measured:
            count, mx, my = shape[_COUNT, i], shape[_MX, i], shape[_MY, i]
            cxx, cyy, cxy = shape[_CXX, i], shape[_CYY, i], shape[_CXY, i]
            half_tr = 0.5 * (cxx + cyy)
            under = 0.25 * (cxx - cyy) ** 2 + cxy * cxy
            root = math.sqrt(0.0 if under < 0.0 else under)
            l1 = half_tr + root
            ox, oy = (mx, my) if count > 0 else (px, py)
            if offset_ratio > 0 and any_surface:
                shift = 0.0
                if count > 0:
                    width = math.sqrt(12.0 * (0.0 if l1 < 0.0 else l1))   # uniform stretch
                    shift = offset_ratio * width / max(math.hypot(mx, my), 1e-9)
                ox, oy = ox + ox * shift, oy + oy * shift
            l2 = half_tr - root + floor
            a = angle[i]
            off = (mx - px) * math.cos(a) + (my - py) * math.sin(a)
            if count >= settings[_MIN_POINTS] and \
                    l1 + floor >= settings[_ELONGATION] ** 2 * (1e-12 if l2 < 1e-12 else l2) \
                    and off * off < l1 + floor:
                structure[i] = (a + origin[2]) % np.pi
            if settings[_SURFACE] != 0.0:
                px, py = ox, oy
        xy[i, 0] = jit.fma(py, -s, px * c) + origin[0]
        xy[i, 1] = jit.fma(py, c, px * s) + origin[1]
    return xy, structure


def segment(changed: np.ndarray, cells: int, resolution: float, origin, stamp: float,
            config: BlobConfig, points: np.ndarray | None = None) -> Blobs:
    """Blobs of the changed cells ``changed`` (sorted unique flat indices), in two kernel
    calls around numpy's arctan2 (the wall direction, kept bit for bit).

    ``origin`` is the scanner pose in the odometry frame; ``points`` the scan's end points in
    beam order (scanner frame), for the surfaces (position and structure; None: neither).
    """
    origin = np.asarray(origin, dtype=float)
    settings = settings_of(config)
    local, n, extent, shape, dropped, count = _blobs(
        changed, cells, float(resolution), _NO_POINTS if points is None else points, settings)
    if count == 0:
        return Blobs.empty()
    if dropped:
        log.warning('%d blobs in one scan at t=%.3f: kept the %d largest (blobs.max_blobs)',
                    count, stamp, config.max_blobs)
    xy, structure = _place(local, shape, 0.5 * np.arctan2(shape[_ATAN_Y], shape[_ATAN_X]),
                           origin, settings, float(resolution))
    return Blobs(xy=xy, cells=n, extent=extent, structure=structure, dropped=dropped)


def surface_centroids(centroids: np.ndarray, points: np.ndarray, config: BlobConfig,
                      resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Surface centroids and wall directions (mod pi; NaN: no wall) of blobs at
    ``centroids``, given the scan's end points in beam order (scanner frame both)."""
    settings = settings_of(config)
    settings[_SURFACE] = 1.0
    ids, starts = _surface_ids(points, config.surface_gap)
    shape = _surface_shape(points, ids, starts, np.asarray(centroids, dtype=float), settings,
                           float(resolution))
    return _place(np.asarray(centroids, dtype=float), shape,
                  0.5 * np.arctan2(shape[_ATAN_Y], shape[_ATAN_X]), _ORIGIN, settings,
                  float(resolution))


_NO_POINTS = np.zeros((0, 2))
_ORIGIN = np.zeros(3)
