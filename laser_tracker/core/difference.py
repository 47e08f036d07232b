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
* ``free_neighbourhood`` (default 0 = paper): the previous cell's neighbours must have been
  FREE too, tolerating a one-cell misalignment of the two grids, at the price of missing
  objects that move into cells next to occupied ones: it removed nearly every detection of
  the slow (0.5 m/s, one cell per scan) robot of fig8, so it stays off.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core.grid import FREE, OCCUPIED, lookup_padded, lookup_stack


@dataclass(frozen=True)
class DifferenceConfig:
    """Equation 1 options (node ``detection``, ``difference.*``)."""

    memory: int = param(
        5, 'Earlier grids (before the previous one) in which a changed cell must not have '
        'been OCCUPIED: a thin static object (a chair leg) that the beams miss in one scan '
        'and hit in the next is then not a change. 0 = paper (previous grid only).',
        min=0, max=50)
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


def difference_map(grid: np.ndarray, previous_in_current: np.ndarray) -> np.ndarray:
    """Equation 1 over whole grids: boolean D, True where occupied now and free before."""
    return (grid == OCCUPIED) & (previous_in_current == FREE)


def relative_motion(a, b) -> tuple[float, float, float]:
    """Pose ``b`` in the frame of pose ``a`` (SE(2) ``inverse(a) (+) b``), in plain floats:
    ``geometry.between`` for one pair without numpy's per-call cost."""
    ax, ay, at = (float(v) for v in a)
    bx, by, bt = (float(v) for v in b)
    c, s = math.cos(at), math.sin(at)
    dx, dy = bx - ax, by - ay
    return (c * dx + s * dy, -s * dx + c * dy,
            (bt - at + math.pi) % (2.0 * math.pi) - math.pi)


def not_occupied_before(ij: np.ndarray, stack: np.ndarray, indices, poses, pose,
                        resolution: float) -> np.ndarray:
    """Mask over the rows of ``ij`` (cells of the current grid at scanner pose ``pose``): True
    where none of the earlier grids ``stack[indices[k]]`` (padded; scanner poses ``poses[k]``)
    had the cell OCCUPIED, each brought into the current frame by the relative motion."""
    motions = [relative_motion(p, pose) for p in poses]
    before = lookup_stack(stack, indices, motions, resolution, ij)
    return ~(before == OCCUPIED).any(axis=0)


def deep_free(ij: np.ndarray, previous, motion, resolution: float, cells: int,
              config: DifferenceConfig) -> np.ndarray:
    """Mask over the rows of ``ij`` (current-grid cells): True where the beam of the previous
    scan covering the cell continued at least ``motion_depth`` times the motion-induced
    displacement at the cell beyond it (``previous``: the previous ``GridFrame``; ``motion``:
    current scanner pose in the previous scanner frame)."""
    x, y, theta = (float(v) for v in motion)
    c, s = math.cos(theta), math.sin(theta)
    p = (ij + (0.5 - cells / 2.0)) * resolution
    prev = np.empty_like(p)
    prev[:, 0] = c * p[:, 0] - s * p[:, 1] + x
    prev[:, 1] = s * p[:, 0] + c * p[:, 1] + y
    need = config.motion_depth * (math.hypot(x, y)
                                  + np.hypot(prev[:, 0], prev[:, 1]) * abs(theta))
    return previous.free_depth(prev) >= need


def changed_cells(ij: np.ndarray, previous_padded: np.ndarray, motion, resolution: float,
                  config: DifferenceConfig) -> np.ndarray:
    """Equation 1 evaluated at the occupied cells only: a boolean mask over the rows of ``ij``.

    ``ij``: cell indices (k, 2) of the cells occupied now (one row per end point, repeats
    allowed); ``previous_padded``: the previous grid in its own frame with its UNKNOWN border
    (``GridFrame.padded``); ``motion``: current scanner pose in the previous scanner frame.
    """
    if ij.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    k = config.free_neighbourhood
    before = lookup_padded(previous_padded, motion, resolution, ij, neighbourhood=k)
    if k == 0:
        return before[:, 0] == FREE
    return (before == FREE).all(axis=1)
