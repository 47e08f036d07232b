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

Ray casting, vectorised. Per (beam geometry, grid geometry) a :class:`RayTable` is computed
once and cached, the way laser_geometry caches cos/sin per scan geometry: for every cell the
beam whose direction passes nearest the cell centre and the range at which that beam reaches
the centre (plus the margin). A beam thus covers the wedge of cells between it and its
neighbours (its share of the field of view); at ranges where beams are further apart than a
cell this leaves no unobserved stripes between beams. Per scan, casting all rays is then one
gather and one comparison over the cells: ``FREE where reach[cell] < free_range[beam[cell]]``
(``Scan.free_ranges``: a return frees space up to the hit, a no-return reading up to
``no_return_free``, NaN nothing), after which the end points are marked ``OCCUPIED``.

The previous grid is brought into the current scanner frame with the ego-motion estimate by
:func:`transform_grid` (``scipy.ndimage.affine_transform``, order 0 = nearest cell, cells that
come from outside the previous grid are ``UNKNOWN``). The difference map only needs the
previous grid at the cells occupied now, so the per-scan path uses :func:`lookup_padded` (and
:func:`lookup_stack` for several earlier grids at once), the same nearest-cell mapping
evaluated at those cells only (a few hundred instead of the whole grid); the tests check that
both agree. Grids live in buffers with a ``PAD``-cell UNKNOWN border that a
:class:`GridBuilder` reuses scan after scan (no per-scan allocation of grids): cells that map
outside read the border, so lookups need no bounds checks.

Size: the default 16 m x 16 m (160 x 160 cells) covers the SICK's 8 m mode in every direction;
measured on the bundled recordings, 12 m loses people at the far end of the corridor
(exp4 MOTA 0.59 -> 0.38) and 24 m finds nothing more for 37 % more grid time.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage

from laser_tracker.config import param
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
        'up to the straight line joining them (the echo was lost on something there). In '
        'open space it frees no_return_free as before. false = up to no_return_free '
        '(paper).')
    lost_echoes: float = param(
        0.03, 'The chord between two returns bounds the beams without a return between them '
        '(no_return_bounds) once at least this share of the scanner\'s '
        'beams (over its last 200 scans) return nothing between two returns nearer than half '
        'its range: the scanner loses echoes on surfaces within range (dark, specular, '
        'grazing), as Hokuyo-class scanners do indoors (8-10 % of their beams in the '
        'leg_tracker recordings, 0-3 % for SICK LMS logs).', min=0.0, max=1.0)
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


@lru_cache(maxsize=8)
def ray_table(angle_min: float, angle_increment: float, n_beams: int, cells: int,
              resolution: float, free_margin: float) -> RayTable:
    """Cached ray table for one beam geometry and one grid geometry.

    Indexed by the flat index of the *padded* grid (``cells + 2`` per side, see
    :class:`GridBuilder`); the border cells have no beam and infinite reach (never FREE).
    """
    m = cells + 2 * PAD
    c = (np.arange(m) - PAD + 0.5 - cells / 2.0) * resolution
    cx, cy = np.meshgrid(c, c, indexing='ij')
    rng = np.hypot(cx, cy).ravel()
    bearing = np.arctan2(cy, cx).ravel()
    inc = float(angle_increment)
    # Fractional beam index of each cell's bearing, measured in the scan's direction of sweep.
    delta = np.mod((bearing - angle_min) * math.copysign(1.0, inc), 2.0 * math.pi)
    k = delta / abs(inc)
    beam = np.rint(k)
    wrapped = np.rint(k - 2.0 * math.pi / abs(inc))  # bearings just before angle_min
    use_wrapped = (beam > n_beams - 1) & (wrapped >= 0) & (wrapped <= n_beams - 1)
    beam = np.where(use_wrapped, wrapped, beam)
    beam = np.where((beam >= 0) & (beam <= n_beams - 1), beam, n_beams).astype(np.intp)
    reach = (rng + free_margin).astype(np.float32)
    border = np.ones((m, m), bool)
    border[PAD:-PAD, PAD:-PAD] = False
    border = border.ravel()
    beam[border] = n_beams
    reach[border] = np.inf
    beam.setflags(write=False)
    reach.setflags(write=False)
    return RayTable(beam=beam, reach=reach, n_beams=n_beams)


def cell_centres(cells: int, resolution: float, flat: np.ndarray) -> np.ndarray:
    """Centres (k, 2) in metres (scanner frame) of cells given by flat index."""
    ix, iy = np.divmod(flat, cells)
    half = cells / 2.0
    return np.column_stack(((ix + 0.5 - half) * resolution, (iy + 0.5 - half) * resolution))


@dataclass
class GridFrame:
    """One scan's grid and what the later stages need from it (valid for ``keep - 1`` more
    builds of its :class:`GridBuilder`: its buffers rotate).

    ``padded`` is the grid with a ``PAD``-cell UNKNOWN border, ``grid`` its interior view
    (``grid[ix, iy]``); ``points`` the end points inside the grid in beam order (scanner
    frame, metres), ``ij`` their cell indices (float, interior coordinates) and ``flat``
    their flat index in the unpadded grid (one per point; a cell hit by several beams
    appears several times).
    """

    padded: np.ndarray
    points: np.ndarray
    ij: np.ndarray
    flat: np.ndarray
    index: int = 0          # which buffer of its builder's ``stack``
    free: np.ndarray | None = None   # (beams,) free range of each beam after erosion (m)
    angle_min: float = 0.0
    angle_increment: float = 1.0

    def free_depth(self, xy: np.ndarray) -> np.ndarray:
        """How far (m) beyond each point ``xy`` (k, 2; this scan's frame) the beam covering it
        (the one nearest its bearing, as in the ray table) continued freeing space: the free
        range of that beam minus the point's range. Negative where the beam stopped short,
        -inf outside the field of view."""
        free = self.free
        if free is None or free.size == 0:
            return np.full(xy.shape[0], -np.inf)
        rng = np.hypot(xy[:, 0], xy[:, 1])
        inc = self.angle_increment
        k = np.mod((np.arctan2(xy[:, 1], xy[:, 0]) - self.angle_min) * math.copysign(1.0, inc),
                   2.0 * math.pi) / abs(inc)
        beam = np.rint(k)
        wrapped = np.rint(k - 2.0 * math.pi / abs(inc))
        n = free.size
        beam = np.where((beam > n - 1) & (wrapped >= 0), wrapped, beam)
        inside = (beam >= 0) & (beam <= n - 1)
        depth = free[np.where(inside, beam, 0).astype(np.intp)] - rng
        return np.where(inside, depth, -np.inf)

    @property
    def grid(self) -> np.ndarray:
        return self.padded[PAD:-PAD, PAD:-PAD]

    def occupied(self) -> np.ndarray:
        """Sorted unique flat indices of the occupied cells."""
        return np.unique(self.flat)


class GridBuilder:
    """Builds the occupancy grid of each scan into reusable buffers (no grid allocation per
    scan). Flat indices into the padded buffer let the difference stage read a cell and its
    neighbours with one gather and no bounds checks (the border is UNKNOWN)."""

    def __init__(self, config: GridConfig, keep: int = 2):
        """``keep``: how many grids stay valid (the current one and ``keep - 1`` before it)."""
        self.config = config
        self.cells = config.cells
        m = self.cells + 2 * PAD
        # One array holds every buffer, so that several grids can be read with one gather.
        self.stack = np.zeros((max(2, keep), m, m), np.uint8)
        self._which = 0
        self._free_at_cell = np.empty(m * m, np.float32)
        self._ext = np.empty(0, np.float32)
        self._table_key = None
        self._table: RayTable | None = None
        self.echo_loss = 0.0            # see _loses_echoes
        self._echo_scans = 0

    def _loses_echoes(self, r, valid, no_return, range_max: float) -> bool:
        """Whether this scanner loses echoes on surfaces within its range: the share of its
        beams without a return between two returns nearer than half its range, averaged over
        its scans (the last ``ECHO_LOSS_SCANS``), is at least ``lost_echoes``. A scanner that
        returns from every surface in range (a SICK LMS) sees through such a gap into free
        space; one that loses echoes on dark, specular or grazing surfaces (many Hokuyo-class
        scanners indoors) may have hit a surface in it."""
        idx = np.flatnonzero(valid)
        share = 0.0
        if idx.size >= 2:
            beams = np.flatnonzero(no_return)
            after = np.searchsorted(idx, beams)
            inner = (after > 0) & (after < idx.size)
            near = 0.5 * range_max
            left = r[idx[np.maximum(after - 1, 0)]]
            right = r[idx[np.minimum(after, idx.size - 1)]]
            share = np.count_nonzero(inner & (left < near) & (right < near)) / r.size
        self._echo_scans = min(self._echo_scans + 1, ECHO_LOSS_SCANS)
        self.echo_loss += (share - self.echo_loss) / self._echo_scans
        return self.echo_loss >= self.config.lost_echoes

    def table(self, scan: Scan) -> RayTable:
        key = (scan.angle_min, scan.angle_increment, scan.n_beams)
        if key != self._table_key:
            c = self.config
            self._table = ray_table(float(scan.angle_min), float(scan.angle_increment),
                                    scan.n_beams, self.cells, float(c.resolution),
                                    float(c.free_margin))
            self._table_key = key
        return self._table

    def build(self, scan: Scan) -> GridFrame:
        c = self.config
        n = self.cells
        table = self.table(scan)
        beams = scan.n_beams
        if self._ext.size != beams + 1:
            self._ext = np.empty(beams + 1, np.float32)   # beam count changed: tables adapt
        ext = self._ext
        # Scan.valid() and Scan.free_ranges() in one pass (same rules, fewer array passes).
        r = scan.ranges
        _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment), beams)
        limit = min(c.no_return_free, scan.range_max)
        with np.errstate(invalid='ignore'):
            valid = (r >= max(scan.range_min, 1e-6)) & (r < scan.range_max)
            no_return = r >= scan.range_max
        fr = ext[:beams]
        # A return frees space up to the hit (no_return_free bounds only the beams that
        # returned nothing: capping returns at it made no_return_free = 0 free nothing at all).
        np.copyto(fr, r, where=valid)
        fr[~valid] = 0.0
        fr[no_return] = limit
        if c.no_return_bounds and no_return.any():
            chords = self._loses_echoes(r, valid, no_return, scan.range_max)
            np.minimum(fr, no_return_bounds(r, valid, no_return, cos, sin, c, chords),
                       out=fr)
        if c.free_erosion:
            raw = fr.copy()
            jump = c.free_erosion_jump
            for j in range(1, min(c.free_erosion, beams - 1) + 1):
                # A neighbour's shorter free range bounds this beam's when both lie on one
                # surface (a grazing wall), not across a depth jump (an object's edge).
                a, b = raw[:-j], raw[j:]
                near = np.abs(a - b) < jump
                np.minimum(fr[j:], np.where(near, a, np.inf), out=fr[j:])
                np.minimum(fr[:-j], np.where(near, b, np.inf), out=fr[:-j])
        ext[beams] = -1.0   # "no beam": never free
        index = self._which
        padded = self.stack[index]
        self._which = (self._which + 1) % self.stack.shape[0]
        np.take(ext, table.beam, out=self._free_at_cell, mode='wrap')  # indices are valid
        np.less(table.reach, self._free_at_cell, out=padded.reshape(-1).view(np.bool_))
        # End points -> OCCUPIED cells.
        rv = r[valid]
        pts = np.empty((rv.size, 2))
        np.multiply(rv, cos[valid], out=pts[:, 0])
        np.multiply(rv, sin[valid], out=pts[:, 1])
        half = n * c.resolution / 2.0
        inside = (np.abs(pts) < half).all(axis=1)
        pts = pts[inside]
        ij = np.floor(pts * (1.0 / c.resolution) + n / 2.0)
        flat = (ij[:, 0] * n + ij[:, 1]).astype(np.intp)
        m = n + 2 * PAD
        padded.reshape(-1)[(ij[:, 0] * m + ij[:, 1] + PAD * (m + 1)).astype(np.intp)] = \
            OCCUPIED
        return GridFrame(padded=padded, points=pts, ij=ij, flat=flat, index=index,
                         free=fr.copy(), angle_min=float(scan.angle_min),
                         angle_increment=float(scan.angle_increment))


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


def no_return_bounds(r: np.ndarray, valid: np.ndarray, no_return: np.ndarray,
                     cos: np.ndarray, sin: np.ndarray, config: GridConfig,
                     chords: bool = True) -> np.ndarray:
    """Per beam, the farthest range (m) a beam without a return may free
    (``no_return_bounds``); inf where nothing bounds it. Its run of beams without a return
    lies between the returns before and after it (the run's edges):

    * with both edges, up to the chord joining them, when ``chords`` (the scanner loses
      echoes on surfaces within its range, ``GridBuilder._loses_echoes``: the beam may
      have hit anything beyond its neighbours' returns);
    * at an edge whose surface is seen at grazing incidence (``grazing_incidence``), up to
      that surface's continuation: the line through the last ``SURFACE_POINTS`` returns
      before the run (the first ones after it), when they lie within ``SURFACE_SPAN`` of the
      edge and ``SURFACE_RMS`` of a line, on a surface at least ``SURFACE_LENGTH`` long.

    Each bound is moved half a cell towards the scanner, so that the cells the surface runs
    through are never freed."""
    n = r.size
    out = np.full(n, np.inf)
    idx = np.flatnonzero(valid)
    m = SURFACE_POINTS
    shift = 0.5 * config.resolution
    if idx.size < 2:
        return out
    q = np.column_stack((r[idx] * cos[idx], r[idx] * sin[idx]))
    # Window sums (cumulative, one zero row in front) for the line of m consecutive returns.
    cum = np.zeros((idx.size + 1, 5))
    np.cumsum(np.column_stack((q, q[:, 0] ** 2, q[:, 0] * q[:, 1], q[:, 1] ** 2)), axis=0,
              out=cum[1:])
    sums = (cum[m:] - cum[:-m]) / m                      # window w: returns w .. w + m - 1
    mx, my = sums[:, 0], sums[:, 1]
    sxx, sxy, syy = sums[:, 2] - mx * mx, sums[:, 3] - mx * my, sums[:, 4] - my * my
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)       # direction of the line
    half = 0.5 * (sxx + syy)
    smallest = half - np.sqrt(np.maximum(half * half - (sxx * syy - sxy * sxy), 0.0))
    span = np.hypot(*(q[m - 1:] - q[:1 - m or None]).T)
    nx, ny = -np.sin(angle), np.cos(angle)               # the line's normal
    offset = mx * nx + my * ny                           # its signed distance from the scanner
    offset = np.sign(offset) * np.maximum(np.abs(offset) - shift, 0.0)
    line_ok = (span <= SURFACE_SPAN) & (smallest <= SURFACE_RMS ** 2)
    cos_graze = math.cos(math.radians(config.grazing_incidence))
    # How far each return's surface runs on behind it and ahead of it (returns closer than
    # free_erosion_jump to the previous one continue the surface).
    step = np.hypot(*np.diff(q, axis=0).T)
    run = np.concatenate(([0], np.cumsum(step >= config.free_erosion_jump)))
    first = np.searchsorted(run, run, side='left')
    last = np.searchsorted(run, run, side='right') - 1
    behind = np.hypot(*(q - q[first]).T)
    ahead = np.hypot(*(q[last] - q).T)

    beams = np.flatnonzero(no_return)
    after = np.searchsorted(idx, beams)                  # first return after each beam
    dx, dy = cos[beams], sin[beams]
    # Between two returns, for a scanner that loses echoes: the chord joining them.
    both = (after > 0) & (after < idx.size) & chords
    if both.any():
        a = q[np.maximum(after - 1, 0)]
        b = q[np.minimum(after, idx.size - 1)]
        ex, ey = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
        length = np.hypot(ex, ey)
        with np.errstate(divide='ignore', invalid='ignore'):
            # The chord's distance from the scanner along its normal, moved towards it.
            nx_c, ny_c = -ey / length, ex / length
            off = a[:, 0] * nx_c + a[:, 1] * ny_c
            off = np.sign(off) * np.maximum(np.abs(off) - shift, 0.0)
            t = off / (dx * nx_c + dy * ny_c)
        bound = both & (length > 0) & (t > 0)
        out[beams[bound]] = t[bound]
    if sums.shape[0] == 0 or config.grazing_incidence >= 90.0:
        return out
    for edge, window, extent in ((after - 1, after - m, behind), (after, after, ahead)):
        has = (edge >= 0) & (edge < idx.size) & (window >= 0) & (window < sums.shape[0])
        w = np.where(has, window, 0)
        k = np.where(has, edge, 0)
        e = idx[k]
        graze = (np.abs(cos[e] * nx[w] + sin[e] * ny[w]) <= cos_graze) & \
            (extent[k] >= SURFACE_LENGTH)
        along = dx * nx[w] + dy * ny[w]
        with np.errstate(divide='ignore', invalid='ignore'):
            t = offset[w] / along
        bound = has & line_ok[w] & graze & (t > 0)
        out[beams[bound]] = np.minimum(out[beams[bound]], t[bound])
    return out


def build_grid(scan: Scan, config: GridConfig) -> np.ndarray:
    """The occupancy grid of one scan (a fresh array)."""
    return GridBuilder(config).build(scan).grid.copy()


def _index_map(motion, cells: int, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Index-space affine map from current-grid cells to previous-grid cells.

    ``motion`` = (x, y, theta): the current scanner pose in the previous scanner frame.
    A current cell at continuous index ``o`` (cell centres at integers) lies at
    ``u = R o + offset`` in the previous grid.
    """
    x, y, theta = (float(v) for v in motion)
    c, s = math.cos(theta), math.sin(theta)
    rot = np.array([[c, -s], [s, c]])
    centre = cells / 2.0 - 0.5
    offset = np.array([centre, centre]) - rot @ np.array([centre, centre]) \
        + np.array([x, y]) / resolution
    return rot, offset


def transform_grid(previous: np.ndarray, motion, resolution: float) -> np.ndarray:
    """The previous grid resampled in the current scanner frame (nearest cell).

    ``motion`` is the current scanner pose in the previous scanner frame (the ego-motion over
    the time step). Cells that map outside the previous grid become ``UNKNOWN``.
    """
    cells = previous.shape[0]
    rot, offset = _index_map(motion, cells, resolution)
    return ndimage.affine_transform(previous, rot, offset=offset, order=0, mode='grid-constant',
                                    cval=int(UNKNOWN), output=np.uint8)


def lookup_padded(padded: np.ndarray, motion, resolution: float, ij: np.ndarray,
                  neighbourhood: int = 0) -> np.ndarray:
    """Values of the transformed previous grid at current cells ``ij`` (k, 2) -> (k, m).

    ``padded`` is the previous grid with its UNKNOWN border. Column 0 is the cell
    itself (what :func:`transform_grid` gives there); with ``neighbourhood = 1`` columns 1..4
    are its 4-neighbours in the previous grid, with ``neighbourhood = 2`` columns 1..8 its
    8-neighbours. Cells outside the previous grid read UNKNOWN (the border).
    """
    m = padded.shape[0]
    cells = m - 2 * PAD
    rot, offset = _index_map(motion, cells, resolution)
    uv = ij @ rot.T
    uv += offset + 0.5
    np.floor(uv, out=uv)                       # scipy's order-0 rounding: floor(x + 0.5)
    np.clip(uv, -1, cells, out=uv)             # outside -> the UNKNOWN border
    p = (uv[:, 0] * m + uv[:, 1] + PAD * (m + 1)).astype(np.intp)
    k = 1 if neighbourhood <= 0 else (5 if neighbourhood == 1 else 9)
    return padded.reshape(-1)[p[:, None] + _shift_offsets(m)[:k]]


@lru_cache(maxsize=8)
def _shift_offsets(m: int) -> np.ndarray:
    out = _SHIFTS[:, 0] * m + _SHIFTS[:, 1]
    out.setflags(write=False)
    return out


def lookup_stack(stack: np.ndarray, indices, motions, resolution: float,
                 ij: np.ndarray) -> np.ndarray:
    """Several grids at once: the value of grid ``stack[indices[k]]`` (padded) brought into the
    current frame by ``motions[k]``, at the current cells ``ij`` (c, 2) -> (K, c). One gather
    for all of them (the nearest-cell mapping of :func:`lookup_padded`)."""
    K, m = len(indices), stack.shape[1]
    cells = m - 2 * PAD
    centre = cells / 2.0 - 0.5
    motions = np.asarray(motions, dtype=float).reshape(K, 3)
    c, s = np.cos(motions[:, 2]), np.sin(motions[:, 2])
    rot = np.empty((K, 2, 2))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1] = c, -s, s, c
    offset = centre - np.einsum('kij,j->ki', rot, np.array([centre, centre])) \
        + motions[:, :2] / resolution
    uv = ij[None, :, :] @ rot.transpose(0, 2, 1)
    uv += (offset + 0.5)[:, None, :]
    np.floor(uv, out=uv)
    np.clip(uv, -1, cells, out=uv)
    base = (np.asarray(indices) * (m * m) + PAD * (m + 1)).astype(np.float64)
    p = (uv[..., 0] * m + uv[..., 1] + base[:, None]).astype(np.intp)
    return stack.reshape(-1)[p]


def lookup_previous(previous: np.ndarray, motion, resolution: float, flat: np.ndarray,
                    neighbourhood: int = 0) -> np.ndarray:
    """:func:`lookup_padded` for an unpadded grid and cells given by flat index."""
    padded = np.pad(previous, PAD, constant_values=UNKNOWN)
    ij = np.column_stack(np.divmod(flat, previous.shape[0])).astype(np.float64)
    return lookup_padded(padded, motion, resolution, ij, neighbourhood)


_SHIFTS = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1],
                    [1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=np.intp)
