"""Visibility: a coasting track the scan sees through, or sees hidden, is not reported.

A confirmed track that nothing measured in this frame coasts on its velocity (paper
Sec. 8): the object may be hidden behind something, or missed by the detector. Where the
scan sees the place itself, it can tell which:

* **Seen empty.** When the beams through the disc of ``seen_empty_radius`` around the
  track's predicted position all pass beyond it (or return nothing at all, as from a dark
  surface, and at least one passes beyond), nothing that the scanner sees stands there: the
  object has gone elsewhere (it turned, or the track followed something that never was).
  So too when none of them returns at all while the scan returns from farther elsewhere
  (``silent_is_empty``): the place lies within the scanner's reach, and an object there
  would have returned some beam. A leg is round: some of it faces the scanner, never all
  at grazing incidence, as a wall's continuation is.
* **Hidden** (``report_hidden`` false). When the beam towards the position itself does not
  pass beyond the disc, some beam through the disc returns from well in front of it
  (nearer than the disc by more than its radius: farther from the place than the object
  could have strayed off its prediction, so not the object itself) and none returns from
  the disc or from just in front of it, the position is out of the scanner's sight and
  nothing in sight is near it. Annotated recordings count the people in view; such a track
  is no one in view. A return from static background just in front of the position
  (``background_hides``: the scans had long seen something there, so it is not an object
  that has just walked there) counts as what hides it: the wall a person walked behind.

Such a track is left out of ``tracks`` for this frame (it lives on with its id, and comes
back when it is measured again). A track whose place the scan sees something at (the
detector missed the object for a scan), outside the field of view, or with the scanner
inside the disc stays reported.
"""
from __future__ import annotations

import math

import numpy as np

from laser_tracker.core import jit
from laser_tracker.core.tracking.frame import Frame
from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import Hypotheses


class Visibility(Role):
    """Which confirmed, unmeasured tracks the frame's scan sees through or sees hidden
    (module docstring)."""

    def left_out(self, hyp: Hypotheses, frame: Frame) -> np.ndarray:
        """Mask over ``hyp``: confirmed, not measured at the frame's stamp, and the disc of
        ``seen_empty_radius`` around the position seen empty by the frame's view, or (with
        ``report_hidden`` false) seen hidden."""
        radius, view = self.config.seen_empty_radius, frame.view
        out = np.zeros(len(hyp), bool)
        rows = (hyp.confirmed & (hyp.t_state < frame.stamp)).nonzero()[0]
        if radius <= 0 or not rows.size or not len(view):
            return out
        local = frame.scanner.to_scanner(hyp.position[rows])
        background = view.background if self.config.background_hides \
            else np.zeros(len(view), bool)     # Frame's view: flags as long as the beams
        scan_reach = float(np.max(view.reach, where=np.isfinite(view.reach), initial=0.0)) \
            if self.config.silent_is_empty else 0.0   # 0: a silent disc is no evidence
        out[rows] = _left_out(local, view.bearing, view.reach, background, radius,
                              not self.config.report_hidden, scan_reach)
        return out


@jit.kernel
def _left_out(local, bearing, reach, background, radius, hidden_too, scan_reach):
    """Per point of ``local`` (k, 2; scanner frame), of the beams (``bearing``, ``reach``:
    range of the return, +inf none, -inf too close) through the disc of ``radius`` around
    it (``rho`` from the scanner):

    * seen empty: every one passes beyond the disc's far side (``rho + radius``: a return
      behind a person's leg at the disc's edge does not count) or returns nothing, and one
      at least passes beyond, or none returns while the far side lies within
      ``scan_reach`` (the farthest return of the scan; 0: silence is no evidence);
    * hidden (``hidden_too``): one at least returns from in front of ``rho - 2 radius``
      (the object may stand up to ``radius`` off the point, nearer the scanner: a return
      behind that may be the object itself), none from between there and the far side,
      and the one nearest the point's bearing does not pass beyond: the point is out of
      sight. A return on static background (``background``) between ``rho - 2 radius``
      and the point is not the object but in front of it."""
    out = np.zeros(local.shape[0], np.bool_)
    for i in range(local.shape[0]):
        x, y = local[i, 0], local[i, 1]
        rho = math.sqrt(x * x + y * y)
        if not rho > radius:                    # the scanner inside the disc, or NaN
            continue
        centre = math.atan2(y, x)
        half = math.asin(radius / rho)
        near, far = rho - 2.0 * radius, rho + radius
        through, front, at, silent = False, False, False, False
        nearest, nearest_off = math.nan, math.inf
        for j in range(bearing.size):
            off = abs((bearing[j] - centre + math.pi) % (2.0 * math.pi) - math.pi)
            if off > half:
                continue
            r = reach[j]
            if background[j] and near <= r < rho:      # not the object: it hides it
                r = -math.inf
            if off < nearest_off:
                nearest, nearest_off = r, off
            if r == math.inf:
                silent = True
                continue
            if r > far:
                through = True
            elif r >= near:
                at = True
                break
            else:
                front = True
        seen_empty = (through or (silent and far < scan_reach)) and not front and not at
        hidden = hidden_too and front and not at and not (far < nearest < math.inf)
        out[i] = seen_empty or hidden
    return out
