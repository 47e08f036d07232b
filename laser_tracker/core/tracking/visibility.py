"""Visibility: a coasting track the scan sees through is not reported.

A confirmed track that nothing measured in this frame coasts on its velocity (paper
Sec. 8): the object may be hidden behind something, or missed by the detector. Where the
scan sees the place itself, it can tell which. When the beams through the disc of
``seen_empty_radius`` around the track's predicted position all pass beyond it (or return
nothing at all, as from a dark surface, and at least one passes beyond), nothing that the
scanner sees stands there: the object has gone elsewhere (it turned, or the track followed
something that never was). Such a track is left out of ``tracks`` for this frame (it lives
on with its id, and comes back when it is measured again). A track hidden behind something
nearer, outside the field of view or with the scanner inside the disc stays reported.
"""
from __future__ import annotations

import math

import numpy as np

from laser_tracker.core import jit
from laser_tracker.core.tracking.frame import Frame
from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import Hypotheses


class Visibility(Role):
    """Which confirmed, unmeasured tracks the frame's scan sees through (module docstring)."""

    def seen_empty(self, hyp: Hypotheses, frame: Frame) -> np.ndarray:
        """Mask over ``hyp``: confirmed, not measured at the frame's stamp, and the disc of
        ``seen_empty_radius`` around the position seen empty by the frame's view."""
        radius, view = self.config.seen_empty_radius, frame.view
        out = np.zeros(len(hyp), bool)
        rows = (hyp.confirmed & (hyp.t_state < frame.stamp)).nonzero()[0]
        if radius <= 0 or not rows.size or not len(view):
            return out
        local = frame.scanner.to_scanner(hyp.position[rows])
        out[rows] = _seen_empty(local, view.bearing, view.reach, radius)
        return out


@jit.kernel
def _seen_empty(local, bearing, reach, radius):
    """Per point of ``local`` (k, 2; scanner frame): every beam (``bearing``, ``reach``:
    range of the return, +inf none, -inf too close) through the disc of ``radius`` around
    it passes beyond the disc's far side (``rho + radius``: a return behind a person's leg at
    the disc's edge does not count) or returns nothing, and one at least passes beyond."""
    out = np.zeros(local.shape[0], np.bool_)
    for i in range(local.shape[0]):
        x, y = local[i, 0], local[i, 1]
        rho = math.sqrt(x * x + y * y)
        if not rho > radius:                    # the scanner inside the disc, or NaN
            continue
        centre = math.atan2(y, x)
        half = math.asin(radius / rho)
        far = rho + radius                      # beyond the disc's far side
        through, blocked = False, False
        for j in range(bearing.size):
            off = (bearing[j] - centre + math.pi) % (2.0 * math.pi) - math.pi
            if abs(off) > half:
                continue
            r = reach[j]
            if r == math.inf:
                continue
            if r > far:
                through = True
            else:
                blocked = True
                break
        out[i] = through and not blocked
    return out
