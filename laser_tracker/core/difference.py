"""Difference map, paper Equation 1 (Sec. 5, Fig. 5c).

With G the current grid and G' the previous grid brought into the current frame::

    D[i, j] = 1  if G[i, j] = OCCUPIED and G'[i, j] = FREE,  else 0

Only cells occupied now matter: any other change is an object becoming occluded or motion
already seen through occupied cells. ``G' = FREE`` means *observed* free: a cell that was
UNKNOWN before (never seen, e.g. structure coming into view as the platform turns) is not a
change (METHOD.md Sec. 2).

Options (not in the paper):

* ``memory`` (default 5): the cell must also not have been OCCUPIED in the ``memory`` grids
  before the previous one (each brought into the current frame the same way). Thin static
  objects that the beams hit in one scan and miss in the next (chair and table legs a few
  centimetres wide, beams 5 cm apart at 6 m) otherwise light up the difference map whenever
  the platform moves: on the translating-platform recording they made 70 % of all blobs.
  Measured (three seeds of each bundled scenario): blobs on exp2 1260 -> 180, false
  detections exp2 7 -> 1 and exp3 10 -> 0, detections of people unchanged. A target that
  returns within ``memory`` scans to cells it occupied is not seen there again.
* ``motion_depth`` (default 0.5; 0 = paper): a changed cell's previous FREE observation must
  come from a beam that continued at least ``motion_depth`` x (platform translation + cell
  range x |rotation| since the previous scan) beyond the cell (:func:`deep_free`). From a
  moving scanner static clutter and surfaces shift in range by about that displacement
  (parallax, beams re-sampling chairs and desks, registration error that grows with the
  turn); a person walks into space seen free far behind. A stationary scanner is unaffected.
  On the real moving-platform log (mit-csail) 61 of 121 confirmed tracks came from cells whose
  previous beam ended less than half that displacement behind them; 0.5 takes the log from
  121 to 50 confirmed tracks (48 -> 25 estimated false) with the simulated recordings
  unchanged but for crossing_walkers' MOTA 0.724 -> 0.722 (1.0: 28 tracks, MOTA 0.716).
  The same evidence says whether a detected person walked in (:func:`people_in_odometry`):
  a wall's end or a chair the moving scanner uncovers has not (negative_2 left scanner 1 -> 0
  false tracks, mit-csail 5 -> 4, the rest unchanged).
* ``free_neighbourhood`` (default 0 = paper): the previous cell's neighbours must have been
  FREE too, tolerating a one-cell misalignment of the two grids, at the price of missing
  objects that move into cells next to occupied ones: it removed nearly every detection of
  the slow (0.5 m/s, one cell per scan) robot of fig8, so it stays off.
* ``pose_gate`` (default on) with ``pose_min_inlier_ratio`` (default 0.6): a scan whose
  ego-motion cannot be trusted reports no changes at all (no blobs; the tracker coasts
  through it). Untrusted (:func:`pose_trusted`): the ICP match was tried and refused (odometry
  used instead), or ICP matched less than ``pose_min_inlier_ratio`` of the scan's points.
  Odometry used because no match could be tried (too few points) is not gated
  (:func:`pose_quality`): a platform on odometry alone would otherwise see nothing. A wrong
  pose shifts every static surface in the difference map (paper Sec. 4). On the real
  moving-platform log (mit-csail) 36 of 1987 scans are gated (11.9 blobs per scan against
  2.7 overall); 50 -> 29 confirmed tracks (25 -> 16 estimated false), each removed track
  having had a gated scan between its creation and its confirmation; no scan of the simulated
  recordings is gated. The grid of a gated scan is still built and kept as history: only its
  report is withheld. Measured and not kept: a bound on the motion covariance (ICP's
  covariance is no larger on a low-overlap match; a yaw bound mostly gates turns, where the
  odometry prior widens), also gating the next scan, comparing the next scan with the last
  trusted grid, a larger ``motion_depth`` for the scan; a ratio of 0.7 costs fig8 (its
  matches explain 66-70 % of the points).

* ``ignore_lone_returns`` (default on): a changed cell whose every return is a lone return
  (:func:`without_lone_returns`: both neighbouring beams pass well beyond it, or return
  nothing) is no change. A spurious echo (dust, a reflection, a glitch of the scanner)
  stands in space the previous scans saw free, so each one is a change, and at half a
  percent of the beams they made 6 to 13 false tracks in 40 s of the simulated Hokuyo
  recordings; a person's leg within range spans several beams, and a thin static object
  seen by one beam stays in the grid, holding its cell against later changes.

Pose quality (:class:`PoseQuality`, from an ego-motion estimate by :func:`pose_quality`) is
what the gate reads; between the nodes it travels on ``ego_motion/status`` beside the pose
(``conversions.ego_motion_to_msgs``).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core import jit
from laser_tracker.core.egomotion import SOURCE_ICP, SOURCE_INIT, SOURCE_ODOMETRY, \
    SOURCE_PARTIAL
from laser_tracker.core.grid import (FREE, NEIGHBOURS_I, NEIGHBOURS_J, OCCUPIED, PAD, UNKNOWN,
                                     GridHistory, covering_beam, history_motions,
                                     index_map, lookup_grid, mapped_cell)
from laser_tracker.core.scan import beam_table

#: Ego-motion sources whose pose detection may trust (``core.egomotion``): ``odometry`` and
#: ``constant_velocity`` (coasting: no match accepted) and ``none`` are not.
TRUSTED_SOURCES = frozenset((SOURCE_INIT, SOURCE_ICP, SOURCE_PARTIAL))
#: The x, y and yaw variance that stands for "no trusted estimate" (ICP refused, odometry
#: used): any variance at or above it (or not finite) marks the pose as failed.
FAILED_VARIANCE = 1e6


@dataclass(frozen=True)
class DifferenceConfig:
    """Equation 1 options (node ``detection``, ``difference.*``)."""

    memory: int = param(
        5, 'Earlier grids (before the previous one) in which a changed cell must not have '
        'been OCCUPIED: a thin static object (a chair leg) that the beams miss in one scan '
        'and hit in the next is then not a change. 0 = paper (previous grid only).',
        min=0, max=50)
    free_window: float = param(
        0.3, 'Seconds of earlier grids (the previous one always included) in any of which a '
        'cell seen FREE (by a deep enough beam, see motion_depth) counts as free before: a '
        'cell the previous scan did not see (in the moving object\'s own shadow, between '
        'beams at a fast scan rate) is then still a change, so a walker gives a whole blob '
        'from its first scans. The memory rule still applies. 0 = paper (the previous grid '
        'alone).', min=0.0, max=10.0)
    static_time: float = param(
        10.0, 'Time constant (s) of the static background: for every cell of the odometry '
        'frame, how long the scans have seen it occupied, decaying by e every static_time '
        'seconds. A cell (or a neighbour, for registration error) seen occupied for '
        'static_occupied seconds is static structure and never a change. Catches structure '
        'seen from a moving platform that the last few grids missed (grazing walls, door '
        'frames, clutter re-sampled from a new viewpoint). 0 = off (paper).', min=0.0,
        max=600.0)
    static_occupied: float = param(
        0.75, 'Seconds of (decayed) occupancy from which a background cell is static '
        'structure; in seconds, not scans, so that 4 Hz and 75 Hz scanners agree. Each scan '
        'adds the time since the previous one (at most static_max_step).', min=0.01,
        max=600.0)
    static_max_step: float = param(
        0.5, 'Largest time (s) one scan adds to a background cell (after a gap).',
        min=0.01, max=10.0)
    max_history: int = param(
        12, 'At most this many earlier grids are kept for memory and free_window (bounds the '
        'work at high scan rates).', min=1, max=100)
    free_neighbourhood: int = param(
        0, 'Previous-grid cells that must have been FREE for an occupied cell to count as a '
        'change: 0 = the cell itself (paper Eq. 1); 1 = also its 4-neighbours; 2 = also its '
        '8-neighbours (tolerance to a one-cell misalignment).', min=0, max=2)
    motion_depth: float = param(
        0.5, 'A changed cell\'s previous FREE observation must come from a beam that '
        'continued at least motion_depth x (platform translation + cell range x |rotation|) '
        'beyond the cell (the displacement the motion since the previous scan causes at the '
        'cell, in m): static surfaces seen from a moving scanner shift in range by about that '
        '(parallax, resampling, registration error growing with the turn), a moving object '
        'enters space seen free far behind it. A stationary scanner is not affected. '
        '0 = paper (any FREE cell).', min=0.0, max=10.0)
    footprint: bool = param(
        True, 'Seen from a scanner that has moved since by the beams\' spacing at the cell or '
        'more, an earlier grid\'s FREE cell counts as free only if no beam that crossed it '
        '(its angular extent seen from the scanner, not only the beam nearest its centre) '
        'ended short of freeing it (in it, before it, or within grid.free_margin beyond its '
        'centre) on something the current scan still sees within a cell of that end, outside '
        'the cell itself. An object\'s edge lies somewhere between two beams, and a surface met '
        'at an angle may cross a cell\'s corner: the beam through the centre passes, yet the '
        'object fills part of the cell, and from another viewpoint its points fall there (door '
        'frames, shelf ends, oblique walls that the robot drives past). A scanner that has not '
        'moved samples them the same way every scan; the end of a leg that has swung on is '
        'gone. With free_neighbourhood, the neighbours count by their nearest beam. false = '
        'the beam nearest the cell\'s centre (paper).')
    pose_gate: bool = param(
        True, 'A scan whose ego-motion is not trusted reports no changes (no blobs; the '
        'tracker coasts; the grid history is kept): ICP was refused and odometry used, or '
        'ICP matched less than pose_min_inlier_ratio of the points. A wrong pose lights up '
        'static structure as moving objects. false = previous behaviour (every scan '
        'reports).')
    pose_min_inlier_ratio: float = param(
        0.6, 'With pose_gate: least fraction of the scan\'s points the ego-motion match '
        'must have matched for the scan to report changes (0 = only the ICP-refused test).',
        min=0.0, max=1.0)
    max_gap: float = param(
        2.0, 'A scan more than this long (s) after the previous one is not compared with the '
        'grids before the gap (the scene and the platform moved on): it starts a new '
        'history.', min=0.01, max=3600.0)
    max_scan_rate: float = param(
        10.0, 'Scans a second (Hz) that detection uses at most. Of a scanner faster than 4/3 '
        'of this, a scan is used once 1/max_scan_rate less a third of the scanner\'s period '
        'has passed since the one used last (every second scan at 15 and 20 Hz, every third at '
        '25 and 30 Hz, every fourth at 40 Hz); the ego-motion still matches every scan. The '
        'method counts scans (the paper\'s four samples, Eq. 3\'s gain per supporting scan, '
        'the grids of memory), and its counts were set at 4 to 10 Hz: at 15 Hz and above they '
        'confirm what flickers. 0 = every scan (paper).', min=0.0, max=1000.0)
    ignore_lone_returns: bool = param(
        True, 'A changed cell whose every return is a lone return is no change: a return '
        'whose neighbouring beams both pass more than segments.jump_distance (or three beam '
        'spacings at its range, a surface met obliquely) beyond it, or return nothing. A '
        'spurious echo (dust, a reflection, a glitch) stands alone in space seen free; a '
        'person\'s leg spans several beams, and a thin static object seen by one beam still '
        'holds its cell in the grid. false = paper (every return).')
    walked_out_window: float = param(
        1.0, 'A detected person has also walked (like one who walked in) when, in a scan of '
        'the last this many seconds, the person detected nearest them was at least two '
        'walked_out_radius away, within walked_out_speed of reach, and stood where the '
        'current scan now sees empty space: every beam through a disc of walked_out_radius '
        'around that place goes on beyond it (by motion_depth times the displacement, as for '
        'a changed cell) or returns nothing, and one at least goes on. Someone '
        'who walks away from the scanner leaves space seen free, though they never entered '
        'space seen free before (their own shadow); a chair or table leg never leaves its '
        'place, and a track that hops between two of them finds the first one still there. '
        '0 = off (walked in only).', min=0.0, max=10.0)
    walked_out_radius: float = param(
        0.3, 'Radius (m) of the place a person stands on (both legs of a stride) for '
        'walked_out_window.', min=0.05, max=2.0)
    walked_out_speed: float = param(
        3.0, 'Fastest a person moves (m/s): an earlier detection farther than this times the '
        'time since (plus walked_out_radius) is someone else (walked_out_window).',
        min=0.1, max=20.0)


@dataclass(frozen=True)
class PoseQuality:
    """How far the scanner pose of one scan can be trusted (what the detection gate reads).

    ``variance``: x, y, yaw variances of the motion since the previous scan (scanner frame;
    m^2, m^2, rad^2); :data:`FAILED_VARIANCE` when no trusted estimate exists (ICP refused).
    ``unmatched``: fraction of the scan's points the match left unexplained, 1 - the ICP
    inlier ratio (0 when no match was needed, the first scan, or nothing is known). Kept in
    this form so that it crosses the message unchanged, bit for bit.
    ``restarted``: the ego-motion (re)started its pose chain at this scan (source ``init``), so
    the odometry-frame history of detection and tracking is void.
    """

    variance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    unmatched: float = 0.0
    restarted: bool = False

    @property
    def inlier_ratio(self) -> float:
        return 1.0 - self.unmatched

    @property
    def failed(self) -> bool:
        """True when the pose is not a trusted estimate (a non-finite value counts)."""
        x, y, theta = self.variance
        return not (x < FAILED_VARIANCE and y < FAILED_VARIANCE and theta < FAILED_VARIANCE)


def pose_quality(estimate) -> PoseQuality:
    """The quality of an ego-motion estimate (``core.egomotion.EgoMotionEstimate``).

    Failed (:data:`FAILED_VARIANCE`): a coasting estimate (``coasting``, or a source other than
    ``init``, ``icp``, ``icp_partial``) *after a match was tried and refused* (did not
    converge, too little overlap, too large a residual, implausible speed or correction), and
    any coasting estimate that is not odometry (the constant-velocity motion model is a guess).
    Odometry used because no match could be tried at all (too few scan or map points; ``rms``
    is NaN exactly then) is not evidence against the pose: it keeps the odometry covariance and
    nothing unmatched, as the paper's odometry-only platform would.
    """
    source = str(estimate.source)
    if source == SOURCE_INIT:
        return PoseQuality(restarted=True)
    ratio = float(estimate.inlier_ratio)
    tried = not math.isnan(float(estimate.rms))
    unmatched = (1.0 - ratio if 0.0 <= ratio <= 1.0 else 1.0) if tried else 0.0
    coasting = bool(getattr(estimate, 'coasting', False)) or source not in TRUSTED_SOURCES
    if coasting and (tried or source != SOURCE_ODOMETRY):
        return PoseQuality((FAILED_VARIANCE,) * 3, unmatched)
    cov = estimate.covariance
    if type(cov) is np.ndarray and cov.shape == (3, 3):
        var = (float(cov.item(0)), float(cov.item(4)), float(cov.item(8)))
    else:
        try:
            var = (float(cov[0][0]), float(cov[1][1]), float(cov[2][2]))
        except (TypeError, IndexError, ValueError):
            var = (FAILED_VARIANCE,) * 3
    return PoseQuality(var, unmatched)


def pose_trusted(quality: PoseQuality | None, config: DifferenceConfig) -> bool:
    """False when ``config.pose_gate`` is on and ``quality`` fails it (see the module
    docstring); None (no quality known) is trusted."""
    if quality is None or not config.pose_gate:
        return True
    return not quality.failed and quality.unmatched <= 1.0 - config.pose_min_inlier_ratio


def difference_map(grid: np.ndarray, previous_in_current: np.ndarray) -> np.ndarray:
    """Equation 1 over whole grids: boolean D, True where occupied now and free before."""
    return (grid == OCCUPIED) & (previous_in_current == FREE)


# ------------------------------------------------------------------------------ kernels
#
# Settings of the difference kernel (a float array: one argument instead of many).
_WINDOW, _MEMORY, _NEIGHBOURHOOD, _MOTION_DEPTH, _RES, _FOOTPRINT = range(6)
# Settings of the static background: 1 / resolution, static_time, static_occupied, bits.
_INV, _TAU, _THRESHOLD, _BITS = range(4)
@jit.inline
def _displaced(i, j, x, y, theta, cells, resolution, motion_depth):
    """Current cell ``(i, j)`` in the frame of an earlier scan (``x, y, theta``: the current
    scanner pose there) and how far beyond it that scan's beam must have freed space: at
    least ``motion_depth`` times the displacement the motion causes at the cell."""
    c, s = math.cos(theta), math.sin(theta)
    px = (i + (0.5 - cells / 2.0)) * resolution
    py = (j + (0.5 - cells / 2.0)) * resolution
    qx = c * px - s * py + x
    qy = s * px + c * py + y
    return qx, qy, motion_depth * (math.hypot(x, y) + math.hypot(qx, qy) * abs(theta))


@jit.inline
def _shaded(free, rays, reach, meta, buffer, p, maps, k, stack, current, here, cells,
            resolution):
    """Whether a beam of the earlier grid in ``buffer`` that crossed its cell ``p`` (``rays``:
    the ray table's beams of each cell) ended in it or before it, rather than going on
    beyond, on something the current grid (buffer ``current``, -1: none) still sees within a
    cell, other than in the cell being judged (``here``, padded flat index of the current
    grid): part of the cell may then have been that thing, seen now from another place (the
    end of a door frame). An end that has gone since (a leg that swung on) does not count;
    a free range of 0 (NaN, below ``range_min``) says nothing."""
    need = reach[p]
    x, y, th = maps[k, 4], maps[k, 5], maps[k, 6]   # the current scanner pose there
    c, s = math.cos(th), math.sin(th)
    m = cells + 2 * PAD
    half = cells / 2.0
    shaded = False
    lo, hi = rays[1, p], rays[2, p]
    if current >= 0 and lo <= hi < meta[current, 6] and (
            meta[current, 4] != meta[buffer, 4] or meta[current, 5] != meta[buffer, 5]
            or meta[current, 6] != meta[buffer, 6]):
        # the ray table's beams are the current scan's: the earlier scan's beams at their
        # angles (a driver whose beam count varies from scan to scan)
        last = meta[buffer, 6] - 1
        a = round((meta[current, 4] + lo * meta[current, 5] - meta[buffer, 4])
                  / meta[buffer, 5])
        z = round((meta[current, 4] + hi * meta[current, 5] - meta[buffer, 4])
                  / meta[buffer, 5])
        lo, hi = int(max(min(a, z), 0.0)), int(min(max(a, z), last))
    for b in range(lo, hi + 1):
        f = np.float64(free[buffer, b])
        if not (f > 0.0 and not need < f):
            continue
        if current < 0:
            shaded = True
            break
        a = meta[buffer, 4] + b * meta[buffer, 5]
        ex, ey = f * math.cos(a) - x, f * math.sin(a) - y
        u = math.floor((c * ex + s * ey) / resolution + half)
        w = math.floor((-s * ex + c * ey) / resolution + half)
        if u < -1 or u > cells or w < -1 or w > cells:
            continue                             # outside the current grid
        q = (int(u) + PAD) * m + int(w) + PAD
        for n in range(9):
            r = q + NEIGHBOURS_I[n] * m + NEIGHBOURS_J[n]
            if r != here and stack[current, r] == OCCUPIED:
                shaded = True
                break
        if shaded:
            break
    jit.alive((free, rays, reach, meta, maps, stack))   # one exit: no reference counting
    return shaded


@jit.inline
def _earlier(stack, lazy, free, rays, reach, meta, buffer, maps, k, i, j, cells, resolution,
             around, motion_depth, footprint, current):
    """The value of the earlier grid in ``buffer`` (``maps[k]``: its index map, then the
    current scanner pose in its frame) at current cell ``(i, j)``: with ``around`` 5 or 9
    (``free_neighbourhood``) FREE only when the mapped cell's 4- or 8-neighbours are FREE
    too, and with ``motion_depth`` only when the beam that freed it went on far enough
    beyond (:func:`_displaced`); else a FREE cell reads UNKNOWN. Reads the arrays
    directly: a helper that passes them on costs reference counting per cell (and so
    would a second exit: ``jit.alive``)."""
    m = cells + 2 * PAD
    p = mapped_cell(i, j, maps[k, 0], maps[k, 1], maps[k, 2], maps[k, 3], cells)
    v = stack[buffer, p]
    if v == UNKNOWN and lazy[buffer] and reach[p] < free[buffer, rays[0, p]]:
        v = FREE
    if footprint and v == FREE:
        # only once the scanner has moved by the beams' spacing at the cell (the cell itself:
        # free_neighbourhood's neighbours by their nearest beam; a second call of the inlined
        # check, in that loop, would cost every cell a little)
        qx, qy, moved = _displaced(i, j, maps[k, 4], maps[k, 5], maps[k, 6], cells,
                                   resolution, 1.0)
        here = (int(i) + PAD) * m + int(j) + PAD
        if moved >= math.hypot(qx, qy) * abs(meta[buffer, 5]) and _shaded(
                free, rays, reach, meta, buffer, p, maps, k, stack, current, here, cells,
                resolution):
            v = UNKNOWN
    if v == FREE:
        for n in range(1, around):
            q = p + NEIGHBOURS_I[n] * m + NEIGHBOURS_J[n]
            if not (stack[buffer, q] == FREE or (stack[buffer, q] == UNKNOWN and lazy[buffer]
                                                 and reach[q] < free[buffer, rays[0, q]])):
                v = UNKNOWN
                break
    if v == FREE and motion_depth > 0.0:
        qx, qy, need = _displaced(i, j, maps[k, 4], maps[k, 5], maps[k, 6], cells,
                                  resolution, motion_depth)
        b = covering_beam(qx, qy, meta[buffer, 4], meta[buffer, 5], meta[buffer, 6])
        if not (b >= 0 and np.float64(free[buffer, b]) - math.hypot(qx, qy) >= need):
            v = UNKNOWN
    jit.alive((stack, lazy, free, rays, reach, meta, maps))
    return v


@jit.kernel
def _background_count(x, y, key, count, last, settings, stamp):
    """The largest decayed occupancy (s) of the background among the cells within one cell
    of point ``(x, y)`` (odometry frame)."""
    bits = int(settings[_BITS])
    mask = (1 << bits) - 1
    i0 = np.int64(math.floor(x * settings[_INV]))
    j0 = np.int64(math.floor(y * settings[_INV]))
    best = 0.0
    for i in range(i0 - 1, i0 + 2):
        for j in range(j0 - 1, j0 + 2):
            slot = ((i & mask) << bits) | (j & mask)
            if key[slot] == (i << 32) + j:
                best = max(best, count[slot] * math.exp((last[slot] - stamp) / settings[_TAU]))
    return best


@jit.kernel
def _on_background(x, y, key, count, last, settings, stamp):
    """Point ``(x, y)`` (odometry frame) is on static background: the decayed occupancy of a
    cell within one cell of it reaches ``static_occupied`` (the largest of
    :func:`_background_count`, read until one cell does: the point's own cell first, and
    the decay's exponential only where its bound ``exp(-a) >= 1 - a`` does not decide)."""
    bits = int(settings[_BITS])
    mask = (1 << bits) - 1
    i0 = np.int64(math.floor(x * settings[_INV]))
    j0 = np.int64(math.floor(y * settings[_INV]))
    threshold = settings[_THRESHOLD]
    for n in range(9):
        i = i0 + (n + 4) % 9 // 3 - 1
        j = j0 + (n + 4) % 3 - 1
        slot = ((i & mask) << bits) | (j & mask)
        if key[slot] != (i << 32) + j:
            continue
        c = count[slot]
        age = (stamp - last[slot]) / settings[_TAU]
        if c * (1.0 - age) >= threshold:
            return True
        if (c >= threshold or age < 0.0) and c * math.exp(-age) >= threshold:
            return True
    return False


@jit.kernel
def _to_world(pose, x, y):
    """Point ``(x, y)`` of the scanner frame at ``pose`` in the odometry frame
    (``geometry.transform_points``)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return c * x - s * y + pose[0], s * x + c * y + pose[1]


@jit.kernel
def _changed(frame_ij, frame_flat, points, stack, lazy, free, rays, reach, meta, order, pose,
             stamp, settings, cells, current, key, count, last, background):
    """Equation 1 with memory and free-space evidence at the cells occupied now: the sorted
    unique flat indices of the changed cells (see :func:`changed_with_history`), without
    those on static background (``background``: its settings, empty when it is off)."""
    n_grids = order.size
    n_free = 1
    for k in range(1, n_grids):
        if stamp - meta[order[k], 3] <= settings[_WINDOW]:
            n_free += 1
    n_occ = min(n_grids, int(settings[_MEMORY]) + 1)
    depth = max(n_free, n_occ)
    res = settings[_RES]
    motion_depth = settings[_MOTION_DEPTH]
    footprint = settings[_FOOTPRINT] != 0.0
    motions = history_motions(meta, order[:depth], pose)
    maps = np.empty((depth, 7))                 # index map, then the motion
    for k in range(depth):
        maps[k, 0], maps[k, 1], maps[k, 2], maps[k, 3] = index_map(
            motions[k, 0], motions[k, 1], motions[k, 2], cells, res)
        maps[k, 4:] = motions[k]
    neighbourhood = int(settings[_NEIGHBOURHOOD])
    around = 1 if neighbourhood <= 0 else (5 if neighbourhood == 1 else 9)
    changed = np.zeros(frame_ij.shape[0], np.intp)
    n_changed = 0
    cell_changed = False
    for r in range(frame_ij.shape[0]):
        if r == 0 or frame_flat[r] != frame_flat[r - 1]:   # a new cell (beams share cells)
            # OCCUPIED in none of the first n_occ earlier grids, seen FREE (deep enough) in
            # one of the first n_free; each read only when needed (most cells occupied now
            # were occupied in the previous grid: one read).
            cell_changed = False
            for k in range(depth):
                v = _earlier(stack, lazy, free, rays, reach, meta, order[k], maps, k,
                             frame_ij[r, 0], frame_ij[r, 1], cells, res,
                             around if k == 0 else 1, motion_depth if k < n_free else 0.0,
                             footprint, current)
                if k < n_occ and v == OCCUPIED:
                    cell_changed = False
                    break
                cell_changed |= k < n_free and v == FREE
                if cell_changed and k >= n_occ - 1:
                    break
        if not cell_changed:
            continue
        if background.size:
            x, y = _to_world(pose, points[r, 0], points[r, 1])
            if _on_background(x, y, key, count, last, background, stamp):
                continue
        changed[n_changed] = frame_flat[r]
        n_changed += 1
    return jit.unique(changed[:n_changed])


@jit.inline
def _left_empty(x, y, pose_then, current, free, meta, silent, radius, motion_depth):
    """Whether the current scan (grid buffer ``current``) sees the disc of ``radius`` around
    ``(x, y)`` (odometry frame) empty: every beam through it goes on beyond its far side by
    ``motion_depth`` times the displacement between the scanner pose then (``pose_then``)
    and now at that place (:func:`_displaced`'s margin), or returned nothing at all
    (``silent``: NaN, +inf, a no-return code below ``range_min``; a person there would have
    returned an echo on some of them), and at least one beam goes on beyond it."""
    px, py, pt = meta[current, 0], meta[current, 1], meta[current, 2]
    c, s = math.cos(pt), math.sin(pt)
    dx, dy = x - px, y - py
    lx, ly = c * dx + s * dy, -s * dx + c * dy       # the place in the current scanner frame
    rho = math.hypot(lx, ly)
    if rho <= radius:
        return False
    turn = abs((pt - pose_then[2] + math.pi) % (2.0 * math.pi) - math.pi)
    need = rho + radius + motion_depth * (math.hypot(px - pose_then[0], py - pose_then[1])
                                          + rho * turn)
    half = math.asin(radius / rho)
    bearing = math.atan2(ly, lx)
    inc = abs(meta[current, 5])
    steps = int(math.ceil(half / inc))
    through = False
    for k in range(-steps, steps + 1):
        a = bearing + k * inc
        if abs(a - bearing) > half and k != 0:
            continue
        b = covering_beam(math.cos(a), math.sin(a), meta[current, 4], meta[current, 5],
                          meta[current, 6])
        if b < 0:
            return False
        if np.float64(free[current, b]) >= need:
            through = True
        elif not silent[b]:
            return False
    return through


@jit.kernel
def _people(persons, legs, leg_xy, pose, stamp, stack, lazy, free, rays, reach, meta, order,
            cells, resolution, motion_depth, footprint, key, count, last, background,
            current, silent, recent, walked_out):
    """People (``persons`` at their ``legs``, rows of ``leg_xy``, -1: none; the scanner frame
    at ``pose``) in the odometry frame with, per person: were the places of all its legs seen
    FREE in one of the grids ``order`` and are they not static background (someone who
    walked in), are all of them static background, and the distance between its two legs
    (NaN for one); and ``leg_xy`` in the odometry frame. FREE as for a changed cell: with
    ``motion_depth``, only by a beam that went on far enough beyond (:func:`_earlier`), so
    that a wall's corner or a chair's leg that the moving scanner's parallax uncovers has not
    walked in. With ``walked_out`` (window, radius, speed; window 0: off) a person has also
    walked when, in an earlier scan of the window, the detection nearest it (of the
    ``recent`` ones, rows: x, y, stamp and the scanner pose then, in time order) was in reach
    and at least two radii away and stood where the current grid (buffer ``current``; its
    beams without a return: ``silent``) sees empty space (:func:`_left_empty`)."""
    n, k = persons.shape[0], leg_xy.shape[0]
    world = np.empty((n, 2))
    for r in range(n):
        world[r, 0], world[r, 1] = _to_world(pose, persons[r, 0], persons[r, 1])
    legs_world = np.empty((k, 2))
    for r in range(k):
        legs_world[r, 0], legs_world[r, 1] = _to_world(pose, leg_xy[r, 0], leg_xy[r, 1])
    spread = np.full(n, np.nan)
    walked = np.ones(n, np.bool_)
    standing = np.ones(n, np.bool_)
    motions = history_motions(meta, order, pose)
    maps = np.empty((order.size, 7))                 # index map, then the motion
    for q in range(order.size):
        maps[q, 0], maps[q, 1], maps[q, 2], maps[q, 3] = index_map(
            motions[q, 0], motions[q, 1], motions[q, 2], cells, resolution)
        maps[q, 4:] = motions[q]
    ij = np.empty(2)
    for r in range(n):
        if legs[r, 1] >= 0:
            dx = leg_xy[legs[r, 0], 0] - leg_xy[legs[r, 1], 0]
            dy = leg_xy[legs[r, 0], 1] - leg_xy[legs[r, 1], 1]
            spread[r] = math.hypot(dx, dy)
        for leg in legs[r]:
            if leg < 0:
                continue
            x, y = legs_world[leg, 0], legs_world[leg, 1]
            static = background.size > 0 and _on_background(
                x, y, key, count, last, background, stamp)
            inside = True
            for a in range(2):
                v = math.floor(leg_xy[leg, a] / resolution + cells / 2.0)
                inside &= 0 <= v < cells
                ij[a] = min(max(v, 0.0), cells - 1.0)
            seen_free = False
            if inside and not static:
                for q in range(order.size):
                    seen_free |= _earlier(stack, lazy, free, rays, reach, meta, order[q], maps,
                                          q, ij[0], ij[1], cells, resolution, 1,
                                          motion_depth, footprint, current) == FREE
            walked[r] &= seen_free
            standing[r] &= static
    window, radius, speed = walked_out[0], walked_out[1], walked_out[2]
    if window > 0.0 and current >= 0:
        for r in range(n):
            first = 0
            while first < recent.shape[0] and not walked[r]:
                # one earlier scan (rows of one stamp): its detection nearest this person
                last = first
                while last < recent.shape[0] and recent[last, 2] == recent[first, 2]:
                    last += 1
                age = stamp - recent[first, 2]
                if 0.0 < age <= window:
                    e, d = -1, np.inf
                    for q in range(first, last):
                        dq = math.hypot(world[r, 0] - recent[q, 0], world[r, 1] - recent[q, 1])
                        if dq < d:
                            e, d = q, dq
                    if 2.0 * radius <= d <= speed * age + radius:
                        walked[r] = _left_empty(recent[e, 0], recent[e, 1], recent[e, 3:6],
                                                current, free, meta, silent, radius,
                                                motion_depth)
                first = last
    return world, walked, standing, spread, legs_world


@jit.kernel
def _background_counts(xy, key, count, last, settings, stamp):
    out = np.empty(xy.shape[0])
    for r in range(xy.shape[0]):
        out[r] = _background_count(xy[r, 0], xy[r, 1], key, count, last, settings, stamp)
    return out


@jit.kernel
def _returns_on_background(bearing, reach, pose, key, count, last, settings, stamp):
    """Per beam (``bearing``, ``reach``: scanner frame at ``pose``; not finite: no return):
    its return lies on static background (:func:`_on_background`). Beams whose returns
    share a cell share its answer."""
    out = np.zeros(bearing.size, np.bool_)
    inv = settings[_INV]
    last_i, last_j, last_answer, known = np.int64(0), np.int64(0), False, False
    for b in range(bearing.size):
        r = reach[b]
        if not math.isfinite(r):
            continue
        a = bearing[b] + pose[2]
        x, y = pose[0] + r * math.cos(a), pose[1] + r * math.sin(a)
        i, j = np.int64(math.floor(x * inv)), np.int64(math.floor(y * inv))
        if not (known and i == last_i and j == last_j):
            last_answer = _on_background(x, y, key, count, last, settings, stamp)
            last_i, last_j, known = i, j, True
        out[b] = last_answer
    return out


@jit.kernel
def _points_on_background(xy, key, count, last, settings, stamp):
    out = np.zeros(xy.shape[0], np.bool_)
    for r in range(xy.shape[0]):
        out[r] = _on_background(xy[r, 0], xy[r, 1], key, count, last, settings, stamp)
    return out


@jit.kernel
def _background_add(points, pose, movers, radius, key, count, last, settings, stamp, step):
    """The end points ``points`` (scanner frame at ``pose``) farther than ``radius`` from
    every mover (``movers``, odometry frame) hit their background cells, each cell once."""
    bits = int(settings[_BITS])
    mask = (1 << bits) - 1
    c, s = math.cos(pose[2]), math.sin(pose[2])
    local = np.empty((movers.shape[0], 2))             # the movers in the scanner frame
    for b in range(movers.shape[0]):
        dx, dy = movers[b, 0] - pose[0], movers[b, 1] - pose[1]
        local[b, 0], local[b, 1] = c * dx + s * dy, -s * dx + c * dy
    n = points.shape[0]
    slots = np.empty(n, np.int64)
    keys = np.empty(n, np.int64)
    values = np.empty(n)
    k = 0
    for r in range(n):
        near = False
        for b in range(local.shape[0]):
            if _within(points[r, 0] - local[b, 0], points[r, 1] - local[b, 1], radius):
                near = True
                break
        if near:
            continue
        px, py = points[r, 0], points[r, 1]
        x, y = c * px - s * py + pose[0], s * px + c * py + pose[1]      # _to_world
        i = np.int64(math.floor(x * settings[_INV]))
        j = np.int64(math.floor(y * settings[_INV]))
        slot = ((i & mask) << bits) | (j & mask)
        keys[k], slots[k] = (i << 32) + j, slot
        # Several points of one cell write the same value: each cell counts once (the
        # neighbour along the scan in the same cell has computed it).
        if k and slots[k - 1] == slot and keys[k - 1] == keys[k]:
            values[k] = values[k - 1]
        else:
            values[k] = (count[slot] * math.exp((last[slot] - stamp) / settings[_TAU])
                         if key[slot] == keys[k] else 0.0) + step
        k += 1
    for r in range(k):
        key[slots[r]] = keys[r]
        count[slots[r]] = values[r]
        last[slots[r]] = stamp


@jit.inline
def _within(dx, dy, limit):
    """``math.sqrt(dx * dx + dy * dy) <= limit`` (the square root only where the squares
    leave it open)."""
    side = jit.compare_length(dx, dy, limit)
    return side < 0 or (side == 0 and math.sqrt(dx * dx + dy * dy) <= limit)


#: A lone return stands out from both neighbouring returns by at least this many beam
#: spacings at its range: adjacent returns on one surface lie r dtheta tan(incidence) apart
#: in range, within three spacings up to 72 deg of incidence.
LONE_SPACINGS = 3.0
#: The narrowest target the tracker follows (m): a leg. A lone return is no change only
#: where a leg spans two beams or more (nearer than LEG_WIDTH / 2 over the beam spacing:
#: 8 m for 0.35 deg beams, 5.7 m for 0.5 deg, 2.9 m for 1 deg); farther, a leg may be one.
LEG_WIDTH = 0.1


def without_lone_returns(changed: np.ndarray, frame, scan, jump: float) -> np.ndarray:
    """``changed`` (flat cell indices, as :func:`changed_with_history` gives them) without
    the cells whose every return in ``scan`` (the scan ``frame`` was built from) is a lone
    return: one whose neighbouring beams both pass more than ``jump`` (or
    ``LONE_SPACINGS`` beam spacings at its range) beyond it, or return nothing, nearer than
    where a leg (``LEG_WIDTH``) spans fewer than two beams. One kernel call."""
    if not changed.size:
        return changed
    b = frame.builder
    _, cos, sin = beam_table(float(scan.angle_min), float(scan.angle_increment), scan.n_beams)
    keep = _lone_kept(changed, frame.flat, np.asarray(scan.ranges, dtype=np.float64), cos, sin,
                      abs(float(scan.angle_increment)), max(float(scan.range_min), 1e-6),
                      float(scan.range_max), float(jump), LONE_SPACINGS, 0.5 * LEG_WIDTH,
                      b.cells, float(b.config.resolution))
    return changed if keep.all() else changed[keep]


@jit.kernel
def _lone_kept(changed, flat, r, cos, sin, spacing, range_min, range_max, jump, spacings,
               half_leg, cells, resolution):
    """Per changed cell, whether it holds a return that is not lone (all True when the
    scan's returns do not line up with the grid's points ``flat``: nothing is dropped)."""
    keep = np.ones(changed.size, np.bool_)
    n = r.size
    lone_in = np.zeros(cells * cells, np.bool_)
    other_in = np.zeros(cells * cells, np.bool_)
    half = cells * resolution / 2.0          # the grid's own arithmetic (grid._build)
    inv = 1.0 / resolution
    k = 0
    any_lone = False
    for i in range(n):
        ri = r[i]
        if not (range_min <= ri < range_max):       # NaN, inf and no-return codes
            continue
        x, y = ri * cos[i], ri * sin[i]
        if not (abs(x) < half and abs(y) < half):
            continue
        u = int(math.floor(x * inv + cells / 2.0))
        v = int(math.floor(y * inv + cells / 2.0))
        if u >= cells or v >= cells:               # rounded onto the edge: not in the grid
            continue
        cell = u * cells + v
        if k >= flat.size or flat[k] != cell:
            return keep
        k += 1
        margin = max(jump, spacings * ri * spacing)
        lone = ri * spacing <= half_leg
        for j in (i - 1, i + 1):
            if lone and 0 <= j < n and range_min <= r[j] < range_max and r[j] - ri <= margin:
                lone = False
        if lone:
            lone_in[cell] = True
            any_lone = True
        else:
            other_in[cell] = True
    if k != flat.size or not any_lone:
        return keep
    for m in range(changed.size):
        c = changed[m]
        keep[m] = not (lone_in[c] and not other_in[c])
    return keep


def changed_with_history(frame, stamp: float, pose, history: GridHistory,
                         config: DifferenceConfig,
                         background: StaticBackground | None = None) -> np.ndarray:
    """Equation 1 with memory and free-space evidence at the cells occupied now: the sorted
    unique flat indices of the changed cells, in one kernel call.

    ``frame``, ``stamp``, ``pose``: the current scan's grid, stamp and scanner pose;
    ``history``: the earlier grids with their poses and stamps. A cell is changed when it
    was seen FREE (and, with ``motion_depth``, by a beam that went on far enough beyond it,
    see :func:`deep_free`) in one of the grids of the last ``free_window`` seconds (the
    previous grid at least; with ``free_neighbourhood``, the previous grid's neighbours too),
    was OCCUPIED in none of the previous grid and the ``memory`` grids before it, and (with
    ``background``) is not static background. With ``free_window`` 0 and ``memory`` 0 this
    is Equation 1 exactly.
    """
    if frame.ij.shape[0] == 0 or not len(history):
        return frame.flat[:0]
    bg = background.arrays if background is not None else _NO_BACKGROUND
    return _changed(frame.ij, frame.flat, frame.points, *history.builder.arrays[:5],
                    history.builder.meta, history.order, np.asarray(pose, dtype=float),
                    float(stamp), _settings(config, history.builder.config.resolution),
                    history.builder.cells, frame.index, *bg)


def people_in_odometry(people, pose, stamp: float, history: GridHistory,
                       background: StaticBackground | None, motion_depth: float,
                       recent: np.ndarray | None = None, walked_out=(0.0, 0.0, 0.0),
                       silent: np.ndarray | None = None, footprint: bool = False) -> tuple:
    """``people`` (``person_detector.PersonDetections`` of the scan at ``pose``, whose grid
    is ``history[0]``) in the odometry frame: (positions, walked in or out, on static
    background, leg spread) per person (see :func:`_people`; ``recent``: earlier detections,
    rows x, y, stamp, scanner pose; ``walked_out``: window, radius, speed, window 0 = off;
    ``silent``: the scan's beams without a return, :meth:`Scan.silent`, default none;
    ``footprint``: ``DifferenceConfig.footprint``) and the positions of their clusters."""
    b = history.builder
    bg = background.arrays if background is not None else _NO_BACKGROUND
    current = int(history.order[0]) if len(history) else -1
    if silent is None:
        silent = np.zeros(int(b.meta[current, 6]) if current >= 0 else 0, np.bool_)
    return _people(people.xy, people.legs, np.ascontiguousarray(people.leg_xy, dtype=float),
                   np.asarray(pose, dtype=float), float(stamp), *b.arrays[:5], b.meta,
                   history.order[1:], b.cells, float(b.config.resolution),
                   float(motion_depth), bool(footprint), *bg, current, silent,
                   _NO_RECENT if recent is None else recent,
                   np.asarray(walked_out, dtype=float))


@functools.lru_cache(maxsize=8)
def _settings(config: DifferenceConfig, resolution: float) -> np.ndarray:
    """The kernels' settings of ``config`` (one array per configuration)."""
    return np.array([config.free_window, config.memory, config.free_neighbourhood,
                     config.motion_depth, resolution, config.footprint])


def deep_free(ij: np.ndarray, previous, motion, resolution: float, cells: int,
              config: DifferenceConfig) -> np.ndarray:
    """Mask over the rows of ``ij`` (current-grid cells): True where the beam of the previous
    scan covering the cell continued at least ``motion_depth`` times the motion-induced
    displacement at the cell beyond it (``previous``: the previous ``GridFrame``; ``motion``:
    current scanner pose in the previous scanner frame)."""
    b = previous.builder
    meta = b.meta[previous.index]
    out = np.zeros(ij.shape[0], dtype=bool)
    for r, (i, j) in enumerate(ij.tolist()):
        qx, qy, need = _displaced(i, j, *(float(v) for v in motion), cells, resolution,
                                  config.motion_depth)
        beam = covering_beam(qx, qy, meta[4], meta[5], int(meta[6]))
        out[r] = beam >= 0 and float(b.free[previous.index, beam]) - math.hypot(qx, qy) >= need
    return out


def changed_cells(ij: np.ndarray, previous_padded: np.ndarray, motion, resolution: float,
                  config: DifferenceConfig) -> np.ndarray:
    """Equation 1 alone at the cells ``ij`` (k, 2) occupied now: a boolean mask over them.
    ``previous_padded``: the previous grid in its own frame with its UNKNOWN border;
    ``motion``: the current scanner pose in the previous scanner frame. With
    ``free_neighbourhood`` the previous cell's neighbours must have been FREE too."""
    k = config.free_neighbourhood
    before = lookup_grid(previous_padded, motion, resolution, ij, k)
    return (before == FREE).all(axis=1)


class StaticBackground:
    """Where the scans have hit, over time, in the odometry frame (``static_time``).

    A toroidal grid of ``size x size`` cells (the grid resolution): world cell ``(ix, iy)``
    lives in slot ``(ix mod size, iy mod size)`` with its own key, so the robot can drive
    anywhere without scrolling and a slot reused far away reads as empty. Each slot keeps the
    time it has been seen occupied, decayed exponentially with time constant ``static_time``,
    and the time of its last hit (decay is applied lazily when a slot is read or hit). Per
    scan only the cells of the scan's end points are touched (the kernels of the difference
    and the detection stage read and write it through :attr:`arrays`).
    """

    def __init__(self, resolution: float, config: DifferenceConfig, size: int = 512):
        self.resolution = float(resolution)
        self.max_step = float(config.static_max_step)
        self.previous: float | None = None
        bits = max(1, int(size - 1).bit_length())      # size: a power of two
        n = 1 << (2 * bits)
        # written whole now (np.full, not np.zeros' untouched pages): the memory is the
        # process's before the first scan, not page by page as the first scans hit it
        self.key = np.full(n, _NO_KEY, np.int64)
        self.count = np.full(n, 0.0)
        self.last = np.full(n, 0.0)
        self.settings = np.array([1.0 / self.resolution, config.static_time,
                                  config.static_occupied, bits])

    def clear(self) -> None:
        """Forget every hit: the state of a new background (its memory kept)."""
        self.previous = None
        self.key.fill(_NO_KEY)
        self.count.fill(0.0)
        self.last.fill(0.0)

    @property
    def arrays(self) -> tuple:
        return self.key, self.count, self.last, self.settings

    def counts(self, xy: np.ndarray, stamp: float) -> np.ndarray:
        """The largest decayed occupancy (s) among the cells within one cell of each point
        ``xy`` (k, 2; odometry frame)."""
        return _background_counts(np.asarray(xy, dtype=float), *self.arrays, float(stamp))

    def static(self, xy: np.ndarray, stamp: float) -> np.ndarray:
        """Mask: points on static structure (see the class doc)."""
        return _points_on_background(np.asarray(xy, dtype=float), *self.arrays, float(stamp))

    def on_returns(self, bearing: np.ndarray, reach: np.ndarray, pose, stamp: float) -> np.ndarray:
        """Mask over the beams (``bearing``, ``reach``: scanner frame at ``pose``, odometry
        frame; not finite: no return): the return lies on static structure."""
        return _returns_on_background(np.asarray(bearing, dtype=float),
                                      np.asarray(reach, dtype=float),
                                      np.asarray(pose, dtype=float), *self.arrays,
                                      float(stamp))

    def add(self, xy: np.ndarray, stamp: float, pose=(0.0, 0.0, 0.0), movers=None,
            radius: float = 0.0) -> None:
        """One scan's end points hit their cells, each cell once, adding the time since the
        previous scan (at most ``max_step``). ``xy``: in the frame of ``pose`` (default the
        odometry frame); points within ``radius`` of one of ``movers`` (odometry frame) are
        left out."""
        step = 0.0 if self.previous is None else \
            min(max(stamp - self.previous, 0.0), self.max_step)
        self.previous = stamp
        movers = _NO_POINTS if movers is None else movers
        _background_add(np.asarray(xy, dtype=float), np.asarray(pose, dtype=float), movers,
                        float(radius), *self.arrays, float(stamp), step)


_NO_POINTS = np.zeros((0, 2))
#: The key of a slot no cell has hit.
_NO_KEY = np.iinfo(np.int64).min
_NO_BACKGROUND = (np.zeros(1, np.int64), np.zeros(1), np.zeros(1), np.zeros(0))
#: No earlier person detections (rows: x, y, stamp, scanner pose x, y, theta).
_NO_RECENT = np.zeros((0, 6))
