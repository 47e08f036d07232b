"""Sustaining the hypotheses no blob or person detection supports this frame.

* **On a segment** (``segment_gate``, beyond the paper): a confirmed person's hypothesis
  follows the nearest compact scan segment with a leg probability of at least
  ``segment_min_leg`` within ``segment_gate`` of its prediction; another object's only a
  segment within ``stop_radius`` of where it was (it stopped there), not clutter it passes.
  A segment within ``stop_radius`` of the track means the object stands (its velocity is
  measured as zero); farther, it is a position measurement like a blob. Neither gains
  weight or samples: an object that stops stays tracked, with its id, as long as it stays
  in the scans. With ``walker_time`` (off by default), a segment whose place the scans have
  seen occupied for that long, and since before the track was last measured standing, does
  not hold it: what has stood there all that time is not someone who was walking, but what
  may hide them.
* **Coasting** (paper Sec. 8): otherwise the hypothesis moves on along its velocity and
  loses ``coast_rate`` weight per second (none for the first ``coast_grace`` seconds after
  its last support), so a short occlusion is bridged.
"""
from __future__ import annotations

import numpy as np

from laser_tracker.core import jit
from laser_tracker.core.tracking.frame import Frame
from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import Hypotheses


class Sustaining(Role):
    """Segments, else coasting, for the unsupported hypotheses (see the module docstring)."""

    def sustain(self, hyp: Hypotheses, pred: np.ndarray, frame: Frame,
                unsupported: np.ndarray) -> list[Hypotheses]:
        """The ``unsupported`` hypotheses: those held by a segment, then those coasting."""
        rest = unsupported.nonzero()[0]
        if not rest.size:
            return []
        segment = self.segment_of(hyp, rest, pred[rest], frame)
        held = segment >= 0
        if not held.any():
            return [self.coast(hyp.take(rest), pred[rest], frame)]
        return [self.hold(hyp.take(rest[held]), frame.segments[segment[held]], frame.stamp),
                self.coast(hyp.take(rest[~held]), pred[rest[~held]], frame)]

    def segment_of(self, hyp: Hypotheses, rows: np.ndarray, pred: np.ndarray,
                   frame: Frame) -> np.ndarray:
        """Per row of ``rows``: the index of the segment that holds it, -1 for none (only
        confirmed hypotheses; a person's only by a leg-like segment)."""
        c = self.config
        if c.segment_gate <= 0 or frame.segments.shape[0] == 0:
            return np.full(rows.size, -1, np.intp)
        return _holding_segments(rows, pred, hyp.position, hyp.person_samples,
                                 hyp.confirmed, frame.segments, frame.leg,
                                 frame.segment_occupied, c.person_kind_samples,
                                 c.segment_min_leg, c.segment_gate, c.stop_radius,
                                 hyp.t_still, frame.stamp,
                                 c.walker_time if c.walker_time > 0 else np.inf)

    def hold(self, hyp: Hypotheses, at: np.ndarray, t: float) -> Hypotheses:
        """Support by the segments ``at`` (k, 2): standing within ``stop_radius``, else
        moving to it; no weight or sample gained."""
        if not len(hyp):
            return hyp
        still = np.hypot(*(at - hyp.position).T) <= self.config.stop_radius
        self.filter.support(hyp, at, t, still)
        hyp.supported = False
        hyp.stopped = still
        return hyp

    def coast(self, hyp: Hypotheses, pred: np.ndarray, frame: Frame) -> Hypotheses:
        """No support: on along the velocity with a reduced weight."""
        if not len(hyp):
            return hyp
        c, t, dt = self.config, frame.stamp, frame.dt
        hyp.P = self.filter.coast(hyp.P)
        hyp.position = pred
        charged = np.clip(t - hyp.t_state - c.coast_grace, 0.0, dt) if c.coast_grace > 0 \
            else dt
        hyp.weight = np.maximum(hyp.weight - c.coast_rate * charged, 0.0)
        hyp.supported, hyp.stopped = False, False
        return hyp


@jit.kernel
def _holding_segments(rows, pred, position, person_samples, confirmed, segments, leg,
                      occupied, kind_samples, min_leg, gate, stop_radius, t_still, t,
                      walker_time):
    """Per hypothesis of ``rows`` (predicted at ``pred``): the nearest segment within reach
    (a person's: of its prediction, within ``gate``, leg-like; another object's: of its
    position, within ``min(gate, stop_radius)``; not one seen ``occupied`` for at least
    ``walker_time`` seconds and since before the hypothesis was last measured standing,
    ``t_still``), -1 for none or when not confirmed."""
    out = np.full(rows.size, -1, np.intp)
    for m in range(rows.size):
        h = rows[m]
        person = person_samples[h] >= kind_samples
        ax, ay = (pred[m, 0], pred[m, 1]) if person else (position[h, 0], position[h, 1])
        walking = t - t_still[h]
        near = -1
        best = np.inf
        for j in range(segments.shape[0]):
            if (person and leg[j] < min_leg) or \
                    (occupied[j] >= walker_time and walking > occupied[j]):
                d = np.inf
            else:
                dx, dy = ax - segments[j, 0], ay - segments[j, 1]
                d = np.sqrt(dx * dx + dy * dy)
            if near < 0 or (best == best and (d < best or d != d)):   # argmin: first NaN
                near, best = j, d
        reach = gate if person else min(gate, stop_radius)
        if best <= reach and confirmed[h]:
            out[m] = near
    return out
