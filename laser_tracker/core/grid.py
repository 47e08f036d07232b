"""Occupancy grid around the scanner (paper Sec. 5, Fig. 4).

An ``n x n`` grid of square cells (10 cm in the paper) centred on the scanner and aligned with
its axes: ``grid[ix, iy]``, ``ix`` along the scanner's x (forward), ``iy`` along its y (left).
Cell ``(ix, iy)`` has its centre at ``((ix + 0.5 - n/2) * res, (iy + 0.5 - n/2) * res)``.

Every cell holds one of three values (METHOD.md Sec. 2, "our reading" of Fig. 5):

* ``OCCUPIED``: a beam of this scan ended in the cell;
* ``FREE``: a beam of this scan passed through the cell (it continued at least
  ``free_margin`` beyond the cell centre, so a return near the cell does not free it);
* ``UNKNOWN``: not observed (behind an obstacle, outside the field of view or beyond the
  distance a beam freed).

Ray casting, compiled and lazy. Per (beam geometry, grid geometry) a :class:`RayTable` is
computed once and cached, the way laser_geometry caches cos/sin per scan geometry: for every
cell the beam whose direction passes nearest the cell centre and the range at which that beam
reaches the centre (plus the margin). A beam thus covers the wedge of cells between it and its
neighbours (its share of the field of view); at ranges where beams are further apart than a
cell this leaves no unobserved stripes between beams. A cell is then ``FREE`` exactly when
``reach[cell] < free_range[beam[cell]]`` (``Scan.free_ranges``: a return frees space up to
the hit, a no-return reading up to ``no_return_free``, NaN nothing) and it is not
``OCCUPIED`` (an end point lies in it).

Per scan one kernel call (:meth:`GridBuilder.build`) computes the valid beams, the free range
of every beam (with ``no_return_bounds`` and ``free_erosion``), the end points and their
cells, and marks those cells ``OCCUPIED`` in the scan's buffer: nothing else of the grid is
written. Only a few hundred cells of a grid are ever read (the cells occupied now, looked up
in the earlier grids), so a cell's FREE / UNKNOWN value is computed when it is read
(:func:`cell_value`) from the ray table and the grid's free ranges. The whole grid is
rendered on request only (:attr:`GridFrame.grid`, for figures and recordings), and for the
grids still held when the beam geometry changes (their ray table is about to be replaced).

The previous grid is brought into the current scanner frame with the ego-motion estimate by
:func:`transform_grid` (``scipy.ndimage.affine_transform``, order 0 = nearest cell, cells that
come from outside the previous grid are ``UNKNOWN``), for figures. The difference map only
needs the earlier grids at the cells occupied now: the kernels evaluate the same
nearest-cell mapping at those cells only (:func:`mapped_cell`); the tests check that both
agree. Grids live in buffers with a ``PAD``-cell UNKNOWN border that a :class:`GridBuilder`
reuses scan after scan (no per-scan allocation of grids): cells that map outside read the
border, so lookups need no bounds checks.

Size: the default 16 m x 16 m (160 x 160 cells) covers the SICK's 8 m mode in every direction;
measured on the bundled recordings, 12 m loses people at the far end of the corridor
(exp4 MOTA 0.59 -> 0.38) and 24 m finds nothing more for 37 % more grid time.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage

from laser_tracker.config import param
from laser_tracker.core import jit
from laser_tracker.core.scan import Scan, beam_table

UNKNOWN = np.uint8(0)
FREE = np.uint8(1)
OCCUPIED = np.uint8(2)
PAD = 2   # UNKNOWN border of the grid buffers: neighbour reads need no bounds checks


@dataclass(frozen=True)
class GridConfig:
    """Occupancy grid geometry and ray-casting parameters (node ``detection``, ``grid.*``)."""

    resolution: float = param(0.1, 'Cell side in metres (paper: 10 cm gave the best results).',
                              min=0.02, max=1.0)
    size: float = param(16.0, 'Side of the square grid in metres, centred on the scanner; '
                        'objects further than size/2 along either axis are not detected.',
                        min=1.0, max=200.0)
    free_margin: float = param(0.1, 'A cell is FREE only if a beam continued at least this far '
                               '(m) beyond the cell centre; absorbs range noise so that a '
                               'return near a cell boundary does not free the cell.',
                               min=0.0, max=1.0)
    no_return_free: float = param(8.0, 'Distance (m) freed along a beam that returned nothing '
                                  '(inf or >= range_max); 0 = such beams free nothing.',
                                  min=0.0, max=100.0)
    free_erosion: int = param(1, 'Beams on each side whose free range also bounds a beam\'s '
                              '(a minimum filter along the scan, across surfaces only, see '
                              'free_erosion_jump): 0 = each beam alone (paper); 1 keeps cells '
                              'at grazing walls from being FREE in one scan and OCCUPIED in '
                              'the next.', min=0, max=10)
    free_erosion_jump: float = param(0.5, 'Neighbouring beams whose free ranges differ by this '
                                     'much (m) or more are a depth jump (an object\'s edge), '
                                     'not one surface: no erosion across it.', min=0.0,
                                     max=100.0)
    no_return_bounds: bool = param(
        True, 'A beam without a return frees space only up to the surfaces its neighbours '
        'see: beside a surface seen at grazing incidence (grazing_incidence), up to that '
        'surface\'s continuation (the echoes fade with the incidence); and, for a scanner '
        'that loses echoes on surfaces within its range (lost_echoes), between two returns '
        'up to the straight line joining them (the echo was lost on something there) and '
        'beside a surface at least 1 m long at any incidence up to its continuation (a dark '
        'wall fades with range). In open space and beside small objects it frees '
        'no_return_free as before. false = up to no_return_free (paper).')
    lost_echoes: float = param(
        0.03, 'The chord between two returns bounds the beams without a return between them '
        '(no_return_bounds) once at least this share of the scanner\'s '
        'beams (over its last 200 scans) return nothing between two returns nearer than half '
        'its range: the scanner loses echoes on surfaces within range (dark, specular, '
        'grazing), as Hokuyo-class scanners do indoors (8-10 % of their beams in the '
        'leg_tracker recordings, 0-3 % for SICK LMS logs).', min=0.0, max=1.0)
    lost_echo_free: float = param(
        3.0, 'On a scanner that loses echoes (lost_echoes), a beam without a return frees '
        'at most this far (m): beyond it its silence may be a dark, specular or grazing '
        'surface, seen again at the next scan (0: a lost echo frees nothing; 100: '
        'no_return_free applies alone). Depends on how far the scanner still sees the '
        'darkest surfaces around it: 3 m for the Hokuyo-class scanners of the recordings '
        'indoors. A scanner that returns from every surface in range (SICK LMS) is not '
        'affected.', min=0.0, max=100.0)
    grazing_incidence: float = param(
        60.0, 'A surface seen at this angle of incidence or more (deg from its normal) at the '
        'edge of a run of beams without a return is taken to continue into the run '
        '(no_return_bounds): a scanner loses its returns at grazing incidence, so those beams '
        'may well have hit it further along (the receding end of a wall the robot drives '
        'along). The return\'s strength falls with the cosine of the incidence: at 60 deg it '
        'is half that at normal incidence; Hokuyo-class scanners lose most returns beyond '
        '70-80 deg, SICK LMS beyond 85 deg.', min=0.0, max=90.0)

    @property
    def cells(self) -> int:
        """Cells per side (even, so the scanner sits on a cell corner at the centre)."""
        n = int(round(self.size / self.resolution))
        return max(2, n + (n % 2))


@dataclass(frozen=True)
class RayTable:
    """For every cell (padded flat index), the beam nearest its centre and the range needed to
    free it.

    ``beam[c] == n_beams`` means no beam covers the cell (outside the field of view).
    """

    beam: np.ndarray    # (n*n,) intp
    reach: np.ndarray   # (n*n,) float32: cell-centre range + free margin
    n_beams: int
    #: (3, n*n) intp: ``beam``, then the first and last beam crossing the cell (its
    #: footprint; both ``beam`` when the footprint is not used): what the kernels read.
    rays: np.ndarray


@lru_cache(maxsize=8)
def ray_table(angle_min: float, angle_increment: float, n_beams: int, cells: int,
              resolution: float, free_margin: float, footprint: bool = False) -> RayTable:
    """Cached ray table for one beam geometry and one grid geometry.

    Indexed by the flat index of the *padded* grid (``cells + 2`` per side, see
    :class:`GridBuilder`); the border cells have no beam and infinite reach (never FREE).
    What depends on the grid alone (the cells' bearings and reach) is made once per grid
    geometry (:func:`cell_bearings`, :func:`cell_reach`: a :class:`GridBuilder` makes them
    when it is built), the beams of the cells per beam geometry in one kernel call
    (:func:`_cell_beams`), at the first scan of that geometry.
    """
    bearing = cell_bearings(cells, resolution)
    inc = float(angle_increment)
    rays = np.empty((3, bearing.size), np.intp)
    _cell_beams(bearing, float(angle_min), math.copysign(1.0, inc), abs(inc),
                2.0 * math.pi / abs(inc), n_beams, cells + 2 * PAD, rays[0],
                cell_spans(cells, resolution) if footprint else _NO_SPAN, rays[1], rays[2])
    rays.setflags(write=False)
    beam = rays[0]
    return RayTable(beam=beam, reach=cell_reach(cells, resolution, free_margin),
                    n_beams=n_beams, rays=rays)


def _cell_centres_padded(cells: int, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """x and y (m, scanner frame) of the centre of every cell of the padded grid."""
    m = cells + 2 * PAD
    c = (np.arange(m) - PAD + 0.5 - cells / 2.0) * resolution
    return np.meshgrid(c, c, indexing='ij')


@lru_cache(maxsize=4)
def cell_bearings(cells: int, resolution: float) -> np.ndarray:
    """The bearing (rad, scanner frame) of every cell centre of the padded grid (flat)."""
    cx, cy = _cell_centres_padded(cells, resolution)
    bearing = np.arctan2(cy, cx).ravel()
    bearing.setflags(write=False)
    return bearing


@lru_cache(maxsize=4)
def cell_spans(cells: int, resolution: float) -> np.ndarray:
    """Half the angle (rad) under which the scanner sees every cell of the padded grid
    (flat): the largest angle between its centre's bearing and a corner's (pi for the
    cells at the scanner)."""
    cx, cy = _cell_centres_padded(cells, resolution)
    centre = np.arctan2(cy, cx)
    half = resolution / 2.0
    span = np.zeros_like(centre)
    for dx, dy in ((-half, -half), (-half, half), (half, -half), (half, half)):
        off = np.arctan2(cy + dy, cx + dx) - centre
        span = np.maximum(span, np.abs((off + np.pi) % (2.0 * np.pi) - np.pi))
    inside = (np.abs(cx) <= half) & (np.abs(cy) <= half)
    span[inside] = np.pi
    span = span.ravel()
    span.setflags(write=False)
    return span


@lru_cache(maxsize=4)
def cell_reach(cells: int, resolution: float, free_margin: float) -> np.ndarray:
    """The range (m, float32) a beam must reach to free each cell of the padded grid (flat):
    the cell centre's range plus ``free_margin``; infinite on the border (never FREE)."""
    cx, cy = _cell_centres_padded(cells, resolution)
    reach = (np.hypot(cx, cy).ravel() + free_margin).astype(np.float32)
    m = cells + 2 * PAD
    border = np.ones((m, m), bool)
    border[PAD:-PAD, PAD:-PAD] = False
    reach[border.ravel()] = np.inf
    reach.setflags(write=False)
    return reach


@jit.kernel
def _cell_beams(bearing, angle_min, sign, step, turn, n_beams, m, beam, span, lo, hi):
    """Into ``beam``: for every cell of the padded grid (``m`` per side; ``bearing``: of its
    centre), the beam whose direction passes nearest it, ``n_beams`` when none does or on
    the border. The beams' directions are ``angle_min + i * sign * step``; ``turn`` is
    ``2 pi / step``. Each cell's arithmetic is numpy's (``np.mod``'s floored remainder,
    ``np.rint``), so that the table is the same to the bit whichever way it is made.
    Into ``lo`` and ``hi``: the first and the last beam whose direction lies within
    ``span`` (rad, per cell; empty: none) of the cell's bearing, its own beam at least,
    clipped to the scan (a 360 deg scan's seam is not crossed)."""
    two_pi = 2.0 * math.pi
    last = n_beams - 1
    footprints = span.size > 0
    for p in range(bearing.size):
        i, j = p // m, p % m
        if i < PAD or i >= m - PAD or j < PAD or j >= m - PAD:
            beam[p] = n_beams
            lo[p], hi[p] = n_beams, n_beams
            continue
        # np.mod(a, 2 pi): fmod, moved into [0, 2 pi) as numpy does (npy_divmod)
        a = (bearing[p] - angle_min) * sign
        delta = np.fmod(a, two_pi)
        if delta != 0.0:
            if delta < 0.0:
                delta += two_pi
        else:
            delta = 0.0
        k = delta / step
        b = np.rint(k)
        wrapped = np.rint(k - turn)      # bearings just before angle_min
        if b > last and wrapped >= 0 and wrapped <= last:
            b = wrapped
            k -= turn
        beam[p] = int(b) if b >= 0 and b <= last else n_beams
        lo[p], hi[p] = beam[p], beam[p]
        if footprints and beam[p] < n_beams:
            w = span[p] / step
            lo[p] = min(max(int(math.ceil(k - w)), 0), beam[p])
            hi[p] = max(min(int(math.floor(k + w)), last), beam[p])


def cell_centres(cells: int, resolution: float, flat: np.ndarray) -> np.ndarray:
    """Centres (k, 2) in metres (scanner frame) of cells given by flat index."""
    ix, iy = np.divmod(flat, cells)
    half = cells / 2.0
    return np.column_stack(((ix + 0.5 - half) * resolution, (iy + 0.5 - half) * resolution))


# ------------------------------------------------------------------------------ kernels
#
# Settings of the build kernel (a float array: one argument instead of many).
_RES, _BOUNDS, _LOST, _COS_GRAZE, _GRAZE, _EROSION, _JUMP, _LOST_FREE = range(8)
#: Scans over which GridBuilder averages the share of beams that lost their echo (the mean
#: of all scans so far until there are this many): a property of the scanner and the
#: surfaces it sees, not of one scan.
ECHO_LOSS_SCANS = 200
#: Returns that define the surface at the edge of a run of beams without a return ...
SURFACE_POINTS = 5
#: ... lying within this distance (m) of the edge return, ...
SURFACE_SPAN = 0.6
#: ... and within this RMS distance (m) of one straight line (a wall, not clutter or a corner),
SURFACE_RMS = 0.03
#: ... on a surface that runs on for at least this long (m) before the edge (a wall, not the
#: side of a box, a cart or a robot: the robot of fig8_robot_target lost its evidence to it).
SURFACE_LENGTH = 1.0


@jit.inline
def _within(dx, dy, limit):
    """``math.hypot(dx, dy) < limit`` (hypot only where the squares leave it open)."""
    side = jit.compare_length(dx, dy, limit)
    return side < 0 or (side == 0 and math.hypot(dx, dy) < limit)


@jit.kernel
def _sign(x):
    """``np.sign``: 1, -1, 0 (a NaN stays NaN)."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0 if x == 0.0 else x


@jit.kernel
def _shrink(x, by):
    """``sign(x) * max(|x| - by, 0)``: ``x`` moved ``by`` towards 0, not past it."""
    v = abs(x) - by
    return _sign(x) * (0.0 if v < 0.0 else v)


@jit.kernel
def _loses_echoes(r, idx, range_max, echo, lost):
    """Whether this scanner loses echoes on surfaces within its range: the share of its
    beams without a return between two returns nearer than half its range, averaged over
    its scans (the last ``ECHO_LOSS_SCANS``; ``echo`` = [mean, scans], updated), is at least
    ``lost`` (``lost_echoes``). A scanner that returns from every surface in range (a SICK
    LMS) sees through such a gap into free space; one that loses echoes on dark, specular or
    grazing surfaces (many Hokuyo-class scanners indoors) may have hit a surface in it."""
    n, nv = r.size, idx.size
    share = 0.0
    if nv >= 2:
        near = 0.5 * range_max
        count = 0
        after = 0                                   # valid beams before beam b
        for b in range(n):
            if after < nv and idx[after] == b:
                after += 1
            elif r[b] >= range_max and 0 < after < nv and r[idx[after - 1]] < near \
                    and r[idx[after]] < near:
                count += 1
        share = count / n
    scans = min(echo[1] + 1.0, ECHO_LOSS_SCANS)
    echo[1] = scans
    echo[0] += (share - echo[0]) / scans
    return echo[0] >= lost


@jit.kernel
def _bound_no_returns(r, cos, sin, idx, range_max, chords, settings, free):
    """Bound the free range of every beam without a return (``no_return_bounds``) by the
    surfaces its neighbours see. Its run of beams without a return lies between the returns
    before and after it (the run's edges):

    * with both edges, up to the chord joining them, when ``chords`` (the scanner loses
      echoes on surfaces within its range, :func:`_loses_echoes`: the beam may have hit
      anything beyond its neighbours' returns);
    * at an edge whose surface is seen at grazing incidence (``grazing_incidence``), or at
      any incidence when ``chords`` (a dark surface fades with range too), up to that
      surface's continuation: the line through the last ``SURFACE_POINTS`` returns
      before the run (the first ones after it), when they lie within ``SURFACE_SPAN`` of the
      edge and ``SURFACE_RMS`` of a line, on a surface at least ``SURFACE_LENGTH`` long.

    Each bound is moved half a cell towards the scanner, so that the cells the surface runs
    through are never freed."""
    nv = idx.size
    if nv < 2:
        return
    m = SURFACE_POINTS
    shift = 0.5 * settings[_RES]
    qx = np.empty(nv)
    qy = np.empty(nv)
    for k in range(nv):
        qx[k] = r[idx[k]] * cos[idx[k]]
        qy[k] = r[idx[k]] * sin[idx[k]]
    windows = nv - m + 1
    grazing = settings[_GRAZE] != 0.0 and windows > 0
    cum = np.zeros((nv + 1 if grazing else 0, 5))
    first = np.empty(nv, np.intp)
    last = np.empty(nv, np.intp)
    if grazing:
        # Window sums (cumulative, one zero row in front) for the line of m returns, and
        # how far each return's surface runs on behind and ahead of it (returns closer than
        # free_erosion_jump to the previous one continue the surface).
        for k in range(nv):
            v = (qx[k], qy[k], qx[k] * qx[k], qx[k] * qy[k], qy[k] * qy[k])
            for c in range(5):
                cum[k + 1, c] = v[c] if k == 0 else cum[k, c] + v[c]
            first[k] = k if k == 0 or not _within(qx[k] - qx[k - 1], qy[k] - qy[k - 1],
                                                  settings[_JUMP]) else first[k - 1]
        for k in range(nv - 1, -1, -1):
            last[k] = k if k == nv - 1 or first[k + 1] == k + 1 else last[k + 1]
    cos_graze = settings[_COS_GRAZE]
    after = 0
    for b in range(r.size):
        if after < nv and idx[after] == b:
            after += 1
            continue
        if not r[b] >= range_max:
            continue
        dx, dy = cos[b], sin[b]
        bound = np.inf
        if chords and 0 < after < nv:            # the chord joining the run's edges
            ax, ay = qx[after - 1], qy[after - 1]
            ex, ey = qx[after] - ax, qy[after] - ay
            length = math.hypot(ex, ey)
            if length > 0.0:
                nx, ny = -ey / length, ex / length
                along = dx * nx + dy * ny
                if along != 0.0:
                    t = _shrink(ax * nx + ay * ny, shift) / along
                    if t > 0.0:
                        bound = t
        for side in range(2 if grazing else 0):
            edge = after - 1 if side == 0 else after
            w = after - m if side == 0 else after
            if not (0 <= edge < nv and 0 <= w < windows):
                continue
            mx = (cum[w + m, 0] - cum[w, 0]) / m
            my = (cum[w + m, 1] - cum[w, 1]) / m
            sxx = (cum[w + m, 2] - cum[w, 2]) / m - mx * mx
            sxy = (cum[w + m, 3] - cum[w, 3]) / m - mx * my
            syy = (cum[w + m, 4] - cum[w, 4]) / m - my * my
            angle = 0.5 * math.atan2(2.0 * sxy, sxx - syy)      # direction of the line
            half = 0.5 * (sxx + syy)
            under = half * half - (sxx * syy - sxy * sxy)
            smallest = half - math.sqrt(0.0 if under < 0.0 else under)
            span = math.hypot(qx[w + m - 1] - qx[w], qy[w + m - 1] - qy[w])
            if not (span <= SURFACE_SPAN and smallest <= SURFACE_RMS ** 2):
                continue
            nx, ny = -math.sin(angle), math.cos(angle)          # the line's normal
            e = idx[edge]
            if side == 0:
                extent = math.hypot(qx[edge] - qx[first[edge]], qy[edge] - qy[first[edge]])
            else:
                extent = math.hypot(qx[last[edge]] - qx[edge], qy[last[edge]] - qy[edge])
            if not ((chords or abs(cos[e] * nx + sin[e] * ny) <= cos_graze)
                    and extent >= SURFACE_LENGTH):
                continue
            along = dx * nx + dy * ny
            if along != 0.0:
                t = _shrink(mx * nx + my * ny, shift) / along
                if t > 0.0:
                    bound = min(bound, t)
        if bound < free[b]:
            free[b] = np.float32(bound)


@jit.kernel
def _build(r, cos, sin, valid_min, range_max, limit, settings, cells, echo, free, occupied,
           marks, meta, about):
    """One scan's grid: ``free[:n]`` (float32) the free range of every beam, ``free[n]`` = -1
    (the ray table's "no beam"), its end points' cells marked OCCUPIED in ``occupied`` (the
    padded buffer, flat; first cleared: the cells ``marks`` of its previous grid, or all
    when ``marks`` is empty), and ``about`` (pose, stamp, beam geometry) into ``meta``.
    Returns the end points inside the grid (beam order, scanner frame), their cell indices
    (float) and flat indices (unpadded grid, then padded)."""
    if marks.size:
        for p in marks:
            occupied[p] = UNKNOWN
    else:
        occupied[:] = UNKNOWN
    meta[:] = about
    n = r.size
    res = settings[_RES]
    nv = 0
    none = False
    for i in range(n):
        x = r[i]
        if x >= valid_min and x < range_max:        # NaN: neither
            free[i] = np.float32(x)
            nv += 1
        elif x >= range_max:
            free[i] = np.float32(limit)
            none = True
        else:
            free[i] = 0.0
    idx = np.empty(nv, np.intp)
    k = 0
    for i in range(n):
        if r[i] >= valid_min and r[i] < range_max:
            idx[k] = i
            k += 1
    if settings[_BOUNDS] != 0.0 and none:
        chords = _loses_echoes(r, idx, range_max, echo, settings[_LOST])
        if chords and settings[_LOST_FREE] < limit:
            for i in range(n):
                if r[i] >= range_max and free[i] > settings[_LOST_FREE]:
                    free[i] = np.float32(settings[_LOST_FREE])
        _bound_no_returns(r, cos, sin, idx, range_max, chords, settings, free)
    erosion = min(int(settings[_EROSION]), n - 1)
    if erosion > 0:
        # A neighbour's shorter free range bounds a beam's when both lie on one surface (a
        # grazing wall), not across a depth jump (an object's edge). In float32.
        raw = free[:n].copy()
        jump = np.float32(settings[_JUMP])
        for j in range(1, erosion + 1):
            for i in range(n - j):
                a, b = raw[i], raw[i + j]
                if abs(a - b) < jump:
                    if a < free[i + j]:
                        free[i + j] = a
                    if b < free[i]:
                        free[i] = b
    free[n] = -1.0
    half = cells * res / 2.0
    inv = 1.0 / res
    m = cells + 2 * PAD
    pts = np.empty((nv, 2))
    ij = np.empty((nv, 2))
    flat = np.empty(nv, np.intp)
    padded = np.empty(nv, np.intp)
    k = 0
    for i in idx:
        x, y = r[i] * cos[i], r[i] * sin[i]
        if abs(x) < half and abs(y) < half:
            u = math.floor(x * inv + cells / 2.0)
            v = math.floor(y * inv + cells / 2.0)
            if u >= cells or v >= cells:      # just inside the edge, rounded onto it
                continue
            pts[k, 0], pts[k, 1] = x, y
            ij[k, 0], ij[k, 1] = u, v
            flat[k] = int(u) * cells + int(v)
            padded[k] = (int(u) + PAD) * m + int(v) + PAD
            occupied[padded[k]] = OCCUPIED
            k += 1
    return pts[:k], ij[:k], flat[:k], padded[:k]


@jit.kernel
def _render(occupied, free, rays, reach):
    """The whole grid into ``occupied`` (a buffer with its OCCUPIED cells marked): FREE
    where the cell's beam freed it."""
    for p in range(occupied.size):
        if occupied[p] == UNKNOWN and reach[p] < free[rays[0, p]]:
            occupied[p] = FREE


@jit.inline
def cell_value(stack, lazy, free, rays, reach, k, p):
    """The value of cell ``p`` (padded flat index) of the grid in buffer ``k``: its mark
    (OCCUPIED; or any value once rendered), else FREE when the ray table says its beam
    freed it (``lazy[k]``: the buffer holds only the marks)."""
    v = stack[k, p]
    if v == UNKNOWN and lazy[k] and reach[p] < free[k, rays[0, p]]:
        v = FREE
    jit.alive((stack, lazy, free, rays, reach))       # one exit: no reference counting
    return v


@jit.kernel
def relative_motion(a, b):
    """Pose ``b`` in the frame of pose ``a`` (SE(2) ``inverse(a) (+) b``) as a tuple:
    ``geometry.between`` without numpy's per-call cost."""
    ax, ay, at = a[0], a[1], a[2]
    c, s = math.cos(at), math.sin(at)
    dx, dy = b[0] - ax, b[1] - ay
    return (c * dx + s * dy, -s * dx + c * dy,
            (b[2] - at + math.pi) % (2.0 * math.pi) - math.pi)


@jit.kernel
def index_map(x, y, theta, cells, resolution):
    """The nearest-cell map from current-grid cells to cells of an earlier grid (``x, y,
    theta``: the current scanner pose in that grid's frame): ``(c, s, u0, v0)``, a current
    cell at continuous index ``(i, j)`` (cell centres at integers) lying at
    ``(c i - s j + u0, s i + c j + v0)`` there."""
    c, s = math.cos(theta), math.sin(theta)
    centre = cells / 2.0 - 0.5
    u0 = centre - (c * centre + -s * centre) + x / resolution
    v0 = centre - (s * centre + c * centre) + y / resolution
    return c, s, u0, v0


@jit.inline
def mapped_cell(i, j, c, s, u0, v0, cells):
    """Padded flat index of the earlier grid's cell nearest to current cell ``(i, j)``
    (:func:`index_map`; scipy's order-0 rounding, floor(x + 0.5)); outside the grid: the
    UNKNOWN border."""
    u = min(max(math.floor(jit.fma(j, -s, i * c) + (u0 + 0.5)), -1.0), float(cells))
    v = min(max(math.floor(jit.fma(j, c, i * s) + (v0 + 0.5)), -1.0), float(cells))
    return (int(u) + PAD) * (cells + 2 * PAD) + int(v) + PAD


@jit.inline
def covering_beam(x, y, angle_min, angle_increment, n_beams):
    """The beam covering point ``(x, y)`` of a scan's frame (the one nearest its bearing, as
    in the ray table), -1 outside the field of view."""
    inc = angle_increment
    k = ((math.atan2(y, x) - angle_min) * math.copysign(1.0, inc)) % (2.0 * math.pi) / abs(inc)
    beam = np.rint(k)
    wrapped = np.rint(k - 2.0 * math.pi / abs(inc))
    if beam > n_beams - 1 and wrapped >= 0:
        beam = wrapped
    return int(beam) if 0 <= beam <= n_beams - 1 else -1


@dataclass
class GridFrame:
    """One scan's grid and what the later stages need from it (valid for ``keep - 1`` more
    builds of its :class:`GridBuilder`: its buffers rotate).

    ``points`` are the end points inside the grid in beam order (scanner frame, metres),
    ``ij`` their cell indices (float, interior coordinates) and ``flat`` their flat index in
    the unpadded grid (one per point; a cell hit by several beams appears several times);
    ``free`` the free range of every beam (m, float32, after bounds and erosion). ``grid``
    (and ``padded``, with its ``PAD``-cell UNKNOWN border) renders the whole grid.
    """

    builder: GridBuilder
    index: int                       # which buffer of its builder
    points: np.ndarray
    ij: np.ndarray
    flat: np.ndarray
    free: np.ndarray
    angle_min: float = 0.0
    angle_increment: float = 1.0

    @property
    def padded(self) -> np.ndarray:
        self.builder.render(self.index)
        return self.builder.stack[self.index]

    @property
    def grid(self) -> np.ndarray:
        return self.padded[PAD:-PAD, PAD:-PAD]

    def free_depth(self, xy: np.ndarray) -> np.ndarray:
        """How far (m) beyond each point ``xy`` (k, 2; this scan's frame) the beam covering it
        (:func:`covering_beam`) continued freeing space: the free range of that beam minus
        the point's range. Negative where the beam stopped short, -inf outside the field of
        view."""
        out = np.full(xy.shape[0], -np.inf)
        for r, (x, y) in enumerate(xy.tolist()):
            beam = covering_beam(x, y, self.angle_min, self.angle_increment, self.free.size)
            if beam >= 0:
                out[r] = float(self.free[beam]) - math.hypot(x, y)
        return out

    def occupied(self) -> np.ndarray:
        """Sorted unique flat indices of the occupied cells."""
        return np.unique(self.flat)


class GridBuilder:
    """Builds the occupancy grid of each scan into reusable buffers (no grid allocation per
    scan) and keeps the last ``keep`` of them with each one's scanner pose and stamp, for
    the difference map. The kernels read them through :attr:`arrays`."""

    def __init__(self, config: GridConfig, keep: int = 2, footprints: bool = False):
        """``keep``: how many grids stay valid (the current one and ``keep - 1`` before it);
        ``footprints``: the ray tables list the beams crossing each cell (for
        ``DifferenceConfig.footprint``)."""
        self.config = config
        self.footprints = footprints
        self.cells = config.cells
        m = self.cells + 2 * PAD
        keep = max(2, keep)
        # One array holds every buffer, so that a kernel reads any of them.
        self.stack = np.zeros((keep, m, m), np.uint8)
        self._flat_stack = self.stack.reshape(keep, m * m)
        self.lazy = np.zeros(keep, np.bool_)         # the buffer holds only OCCUPIED marks
        self.free = np.full((keep, 2), -1.0, np.float32)   # per buffer: free ranges, -1
        #: per buffer: scanner pose x, y, theta, stamp, angle_min, angle_increment, beams
        self.meta = np.zeros((keep, 7))
        self._marks: list[np.ndarray | None] = [None] * keep
        self._which = 0
        self._table_key = None
        self._table: RayTable | None = None
        # what the ray tables of this grid share, made now rather than at the first scan
        cell_bearings(self.cells, float(config.resolution))
        cell_reach(self.cells, float(config.resolution), float(config.free_margin))
        if footprints:
            cell_spans(self.cells, float(config.resolution))
        self.echo = np.zeros(2)                      # share of echoes lost: mean, scans
        cos_graze = math.cos(math.radians(config.grazing_incidence))
        self.settings = np.array([config.resolution, config.no_return_bounds,
                                  config.lost_echoes, cos_graze,
                                  config.grazing_incidence < 90.0, config.free_erosion,
                                  config.free_erosion_jump, config.lost_echo_free],
                                 dtype=float)

    @property
    def echo_loss(self) -> float:
        """The scanner's share of beams without a return between nearby returns (mean over
        its last ``ECHO_LOSS_SCANS`` scans with such beams)."""
        return float(self.echo[0])

    @property
    def arrays(self) -> tuple:
        """What the kernels read: the buffers (flat), which of them hold marks only, the
        free ranges, the ray table (rays, reach) and the per-buffer ``meta``."""
        table = self._table
        rays, reach = (table.rays, table.reach) if table is not None else (_NO_RAYS, _NO_REACH)
        return self._flat_stack, self.lazy, self.free, rays, reach, self.meta

    def table(self, scan: Scan) -> RayTable:
        key = (scan.angle_min, scan.angle_increment, scan.n_beams)
        if key != self._table_key:
            for k in np.flatnonzero(self.lazy):     # their cells are read with this table
                self.render(int(k))
            c = self.config
            self._table = ray_table(float(scan.angle_min), float(scan.angle_increment),
                                    scan.n_beams, self.cells, float(c.resolution),
                                    float(c.free_margin), self.footprints)
            self._table_key = key
        return self._table

    def render(self, index: int) -> None:
        """Write the whole grid of buffer ``index`` (FREE cells too)."""
        if self.lazy[index]:
            _render(self._flat_stack[index], self.free[index], self._table.rays,
                    self._table.reach)
            self.lazy[index] = False
            self._marks[index] = None

    def build(self, scan: Scan, pose=(0.0, 0.0, 0.0)) -> GridFrame:
        """The grid of ``scan``, taken at scanner pose ``pose`` (odometry frame)."""
        c = self.config
        beams = scan.n_beams
        self.table(scan)
        if self.free.shape[1] < beams + 1:           # more beams than ever: wider rows
            wider = np.full((self.free.shape[0], beams + 1), -1.0, np.float32)
            wider[:, :self.free.shape[1]] = self.free
            self.free = wider
        index = self._which
        self._which = (index + 1) % self.stack.shape[0]
        marks = self._marks[index]
        angle_min, increment = float(scan.angle_min), float(scan.angle_increment)
        _, cos, sin = beam_table(angle_min, increment, beams)
        free = self.free[index]
        x, y, theta = pose
        pts, ij, flat, marks = _build(
            scan.ranges, cos, sin, max(scan.range_min, 1e-6), float(scan.range_max),
            min(c.no_return_free, scan.range_max), self.settings, self.cells, self.echo, free,
            self._flat_stack[index], _NO_MARKS if marks is None else marks, self.meta[index],
            np.array([x, y, theta, scan.stamp, angle_min, increment, beams], dtype=float))
        self._marks[index] = marks
        self.lazy[index] = True
        return GridFrame(builder=self, index=index, points=pts, ij=ij, flat=flat,
                         free=free[:beams], angle_min=float(scan.angle_min),
                         angle_increment=float(scan.angle_increment))


def build_grid(scan: Scan, config: GridConfig) -> np.ndarray:
    """The occupancy grid of one scan (a fresh array)."""
    return GridBuilder(config).build(scan).grid.copy()


class GridHistory:
    """The earlier grids of a :class:`GridBuilder`, newest first, at most ``depth`` of them
    (their poses and stamps are in the builder's ``meta``); ``order``: their buffers, as the
    kernels read them."""

    def __init__(self, builder: GridBuilder, depth: int):
        self.builder = builder
        self.frames: deque[GridFrame] = deque(maxlen=depth)
        self.order = np.zeros(0, np.intp)

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, k: int) -> GridFrame:
        return self.frames[k]

    def push(self, frame: GridFrame) -> None:
        self.frames.appendleft(frame)
        order = np.empty(len(self.frames), np.intp)
        order[0] = frame.index
        order[1:] = self.order[:order.size - 1]
        self.order = order

    def clear(self) -> None:
        self.frames.clear()
        self.order = self.order[:0]


@jit.kernel
def history_motions(meta, order, pose):
    """(K, 3): the current scanner pose ``pose`` in the frame of each grid ``order[k]``
    (``meta`` rows start with the grid's scanner pose)."""
    out = np.empty((order.size, 3))
    for k in range(order.size):
        out[k, 0], out[k, 1], out[k, 2] = relative_motion(meta[order[k]], pose)
    return out


#: Cell offsets (row, column) read around a cell: itself, its 4- then its 8-neighbours.
NEIGHBOURS_I = np.array([0, 1, -1, 0, 0, 1, 1, -1, -1])
NEIGHBOURS_J = np.array([0, 0, 0, 1, -1, 1, -1, 1, -1])


@jit.kernel
def lookup(stack, lazy, free, rays, reach, buffers, motions, ij, cells, resolution,
           neighbourhood):
    """(K, c, q) uint8: the grid in buffer ``buffers[k]`` brought into the current frame by
    ``motions[k]`` (nearest cell, as :func:`transform_grid`), at the current cells ``ij``
    (c, 2); ``q`` = 1, or 5 / 9 with ``neighbourhood`` 1 / 2: also the mapped cell's 4- / 8-
    neighbours there. Cells outside that grid read UNKNOWN."""
    q = 1 if neighbourhood <= 0 else (5 if neighbourhood == 1 else 9)
    m = cells + 2 * PAD
    out = np.empty((buffers.size, ij.shape[0], q), np.uint8)
    for k in range(buffers.size):
        c, s, u0, v0 = index_map(motions[k, 0], motions[k, 1], motions[k, 2], cells,
                                 resolution)
        for r in range(ij.shape[0]):
            p = mapped_cell(ij[r, 0], ij[r, 1], c, s, u0, v0, cells)
            for n in range(q):
                out[k, r, n] = cell_value(stack, lazy, free, rays, reach, buffers[k],
                                          p + NEIGHBOURS_I[n] * m + NEIGHBOURS_J[n])
    return out


def lookup_grid(padded: np.ndarray, motion, resolution: float, ij: np.ndarray,
                neighbourhood: int = 0) -> np.ndarray:
    """:func:`lookup` in one whole grid with its UNKNOWN border (``padded``): (c, q)."""
    m = padded.shape[0]
    motions = np.asarray(motion, dtype=float).reshape(1, 3)
    return lookup(np.ascontiguousarray(padded).reshape(1, m * m), _NOT_LAZY, _NO_FREE,
                  _NO_RAYS, _NO_REACH, _FIRST, motions, np.asarray(ij, dtype=float),
                  m - 2 * PAD, float(resolution), neighbourhood)[0]


def transform_grid(previous: np.ndarray, motion, resolution: float) -> np.ndarray:
    """The previous grid resampled in the current scanner frame (nearest cell).

    ``motion`` is the current scanner pose in the previous scanner frame (the ego-motion over
    the time step). Cells that map outside the previous grid become ``UNKNOWN``.
    """
    c, s, u0, v0 = index_map(*(float(v) for v in motion), previous.shape[0],
                             float(resolution))
    return ndimage.affine_transform(previous, np.array([[c, -s], [s, c]]),
                                    offset=(u0, v0), order=0, mode='grid-constant',
                                    cval=int(UNKNOWN), output=np.uint8)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


# Stand-ins for a whole grid's lookups (no ray table), typed as the builder's arrays.
#: ``_build``'s ``marks`` of a buffer without (clear all of it); writable, as marks are.
_NO_MARKS = np.zeros(0, np.intp)
_NO_RAYS = _read_only(np.zeros((3, 1), np.intp))
_NO_SPAN = _read_only(np.zeros(0))
_NO_REACH = _read_only(np.full(1, np.inf, np.float32))
_NO_FREE = np.zeros((1, 1), np.float32)
_NOT_LAZY = np.zeros(1, np.bool_)
_FIRST = np.zeros(1, np.intp)
