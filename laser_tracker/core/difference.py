"""Difference map, paper Equation 1 (Sec. 5, Fig. 5c).

With G the current grid and G' the previous grid brought into the current frame::

    D[i, j] = 1  if G[i, j] = OCCUPIED and G'[i, j] = FREE,  else 0

Only cells occupied now matter: any other change is an object becoming occluded or motion
already seen through occupied cells. ``G' = FREE`` means *observed* free: a cell that was
UNKNOWN before (never seen, e.g. structure coming into view as the platform turns) is not a
change (METHOD.md Sec. 2).

Option (not in the paper, off by default): ``free_neighbourhood`` requires the previous cell's
neighbours to have been FREE too, which tolerates a one-cell misalignment of the two grids
(ego-motion error, the nearest-cell resampling) at the price of missing objects that move
into cells next to other occupied or unknown cells.

The same lookup also yields the *static* occupied cells (occupied now and occupied before at
the cell or one of its 4-neighbours): the structure the wall test of the tracker compares
hypothesis motion with (see ``blobs.structure_angles``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core.grid import FREE, OCCUPIED, lookup_padded


@dataclass(frozen=True)
class DifferenceConfig:
    """Equation 1 options (node ``detection``, ``difference.*``)."""

    free_neighbourhood: int = param(
        0, 'Previous-grid cells that must have been FREE for an occupied cell to count as a '
        'change: 0 = the cell itself (paper Eq. 1); 1 = also its 4-neighbours; 2 = also its '
        '8-neighbours (tolerance to a one-cell misalignment).', min=0, max=2)


def difference_map(grid: np.ndarray, previous_in_current: np.ndarray) -> np.ndarray:
    """Equation 1 over whole grids: boolean D, True where occupied now and free before."""
    return (grid == OCCUPIED) & (previous_in_current == FREE)


def changed_cells(ij: np.ndarray, previous_padded: np.ndarray, motion, resolution: float,
                  config: DifferenceConfig) -> tuple[np.ndarray, np.ndarray]:
    """Equation 1 evaluated at the occupied cells only.

    ``ij``: cell indices (k, 2) of the cells occupied now (one row per end point, repeats
    allowed); ``previous_padded``: the previous grid in its own frame with its one-cell
    UNKNOWN border (``GridFrame.padded``); ``motion``: current scanner pose in the previous
    scanner frame. Returns boolean masks over the rows of ``ij``:
    (changed = D, static = occupied before at the cell or a 4-neighbour).
    """
    if ij.shape[0] == 0:
        empty = np.zeros(0, dtype=bool)
        return empty, empty
    k = config.free_neighbourhood
    before = lookup_padded(previous_padded, motion, resolution, ij, neighbourhood=max(k, 1))
    if k == 0:
        changed = before[:, 0] == FREE
    else:
        changed = (before == FREE).all(axis=1)
    static = (before[:, :5] == OCCUPIED).any(axis=1)
    return changed, static
