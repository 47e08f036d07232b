"""Initiation: new hypotheses from new blobs (paper Sec. 7) and from people.

* **From blobs.** A new blob (Equation 2) pairs with every blob of the previous frame within
  ``max_speed * dt`` and at least ``min_displacement`` away ("seen in two separate
  locations"), creating a hypothesis with the pair's velocity and ``initial_weight`` (the
  wall penalty applies). With ``creation_window`` a blob pairs with the blobs of the most
  recent earlier frame within that many seconds that has one in reach, so a blob that
  flickers (seen in every other scan of a fast scanner) still creates its hypothesis. A burst
  creates at most ``max_hypotheses`` (the pairs of the strongest blobs, nearest first).
* **From people.** A person detection no hypothesis claims starts one: its velocity from
  the nearest person detection or motion blob of the most recent earlier frame within reach,
  else zero. It remembers where it stood and whether the person walked in
  (``state.PERSON_WALKED_IN``), for confirmation.

A hypothesis' first sample is its creation (the first velocity measurement).
"""
from __future__ import annotations

from collections import deque

import numpy as np

from laser_tracker.core import jit
from laser_tracker.core.geometry import pairwise_distances
from laser_tracker.core.tracking.association import wall_penalty
from laser_tracker.core.tracking.frame import Frame
from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import PERSON, PERSON_WALKED_IN, Hypotheses


class Initiation(Role):
    """New hypotheses (see the module docstring); remembers the measurements of recent
    frames to pair with; ``identity`` gives the new ones their ids."""

    def __init__(self, config, filter, stats: dict, identity):
        super().__init__(config, filter, stats)
        self.identity = identity
        self.reset()

    def reset(self) -> None:
        # Earlier frames (newest last): (stamp, motion blobs, person detections).
        self.recent: deque = deque(maxlen=64)

    def remember(self, frame: Frame) -> None:
        """The frame's measurements, for later frames to pair with."""
        self.recent.append((frame.stamp, frame.xy, frame.persons))

    def _earlier(self, t: float):
        """Earlier frames within reach, newest first: (dt, blobs, persons); only the
        previous frame unless ``creation_window`` is set (paper)."""
        window = self.config.creation_window
        for k, (stamp, blobs, persons) in enumerate(reversed(self.recent)):
            dt = t - stamp
            if dt <= 0.0:
                continue
            if k > 0 and dt > window:
                break
            yield dt, blobs, persons

    def from_blobs(self, frame: Frame, new: np.ndarray, weight: np.ndarray) -> Hypotheses:
        """Hypotheses of the ``new`` blobs of ``frame`` (their Eq. 2 ``weight``)."""
        c, t = self.config, frame.stamp
        if not new.any():
            return Hypotheses.empty(self.filter.dim)
        new_xy, structure, weight = frame.xy[new], frame.structure[new], weight[new]
        todo = np.ones(new_xy.shape[0], bool)
        pairs = []
        for dt, earlier, _ in self._earlier(t):
            if not todo.any():
                break
            if earlier.shape[0] == 0:
                continue
            ni, pi, disp = _pairs(new_xy, todo, earlier, c.max_speed * dt, c.min_displacement)
            if ni.size:
                pairs.append((new_xy[ni], earlier[pi], np.full(ni.size, dt), structure[ni], disp,
                              weight[ni]))
        if not pairs:
            return Hypotheses.empty(self.filter.dim)
        now, then, dt, structure, disp, weight = pairs[0] if len(pairs) == 1 else \
            (np.concatenate(p) for p in zip(*pairs))
        if now.shape[0] > c.max_hypotheses:    # a burst: the pairs of the strongest blobs
            keep = np.lexsort((disp, -weight))[:c.max_hypotheses]
            now, then, dt, structure = now[keep], then[keep], dt[keep], structure[keep]
        return self._create(frame, now, then, dt, structure)

    def from_people(self, frame: Frame, fresh: np.ndarray) -> Hypotheses:
        """Hypotheses of the ``fresh`` person detections of ``frame``."""
        if not fresh.any():
            return Hypotheses.empty(self.filter.dim)
        persons, free, spread = frame.persons[fresh], frame.free[fresh], frame.spread[fresh]
        prev = persons.copy()
        dt = np.ones(persons.shape[0])
        todo = np.ones(persons.shape[0], bool)
        for age, blobs_then, persons_then in self._earlier(frame.stamp):
            if not todo.any():
                break
            earlier = np.vstack((persons_then, blobs_then))
            if earlier.shape[0] == 0:
                continue
            idx = np.flatnonzero(todo)
            d = pairwise_distances(persons[idx], earlier)
            near = d.argmin(axis=1)
            ok = d[np.arange(idx.size), near] <= self.config.max_speed * age
            prev[idx[ok]] = earlier[near[ok]]
            dt[idx[ok]] = age
            todo[idx[ok]] = False
        out = self._create(frame, persons, prev, dt, np.full(persons.shape[0], np.nan))
        if self.config.person_initial_weight > 0:
            out.weight = self.config.person_initial_weight
        out.person_samples = 1
        out.pair_samples = ~np.isnan(spread)
        out.origin = np.where(free, PERSON_WALKED_IN, PERSON)
        out.spread = np.column_stack((spread, spread))
        return out

    def _create(self, frame: Frame, new_xy, prev_xy, dt, structure) -> Hypotheses:
        """Hypotheses seen at ``prev_xy`` and, ``dt`` seconds later, at ``new_xy`` (now)."""
        n, t = new_xy.shape[0], frame.stamp
        state, P = self.filter.initial(new_xy, prev_xy, np.full(n, dt))
        out = Hypotheses.empty(self.filter.dim, n)
        out.track_id = self.identity.new_ids(n)
        out.state, out.P, out.t_state, out.position = state, P, t, new_xy
        out.weight = wall_penalty(self.config, np.full(n, self.config.initial_weight),
                                  state[:, 2:], structure)
        out.samples = 1
        out.supported = True
        out.born, out.start = t, new_xy
        out.t_still = -np.inf
        out.start_local = frame.scanner.to_scanner(new_xy)
        out.spread = np.nan
        self.stats['created'] += n
        return out


@jit.kernel
def _pairs(new, todo, earlier, reach, least):
    """The pairs (``new`` blob, ``earlier`` blob, their distance) within ``reach`` and at
    least ``least`` apart, of the new blobs still ``todo`` (row-major); the paired ones are
    done (``todo`` updated)."""
    n = 0
    ni, pi, dist = np.empty(0, np.intp), np.empty(0, np.intp), np.empty(0)
    for sweep in range(2):                   # count, then fill
        n = 0
        for i in range(new.shape[0]):
            if not todo[i]:
                continue
            for j in range(earlier.shape[0]):
                dx, dy = new[i, 0] - earlier[j, 0], new[i, 1] - earlier[j, 1]
                d = np.sqrt(dx * dx + dy * dy)
                if d <= reach and d >= least:
                    if sweep:
                        ni[n], pi[n], dist[n] = i, j, d
                    n += 1
        if not sweep:
            ni, pi, dist = np.empty(n, np.intp), np.empty(n, np.intp), np.empty(n)
    for m in range(n):
        todo[ni[m]] = False
    return ni, pi, dist
