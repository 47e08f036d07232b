"""Association (paper Sec. 7-8): which measurement supports which hypothesis, and the update.

* :class:`PersonAssociation`: person detections (legs) are measurements of their own kind.
  Each hypothesis takes its nearest detection within ``person_gate`` and is updated by it
  (Eq. 3 counting only the distance beyond ``person_tolerance``); a detection no hypothesis
  claims, confident enough, starts one (``initiation``); the motion blobs within
  ``person_radius`` of the people so used are their legs, not movers of their own.
* :class:`BlobAssociation`: the motion blobs as in the paper. Equation 2 weighs each blob
  by the predictions near it (a blob above ``new_blob_threshold`` is new and creates
  hypotheses); every blob within ``gate`` of a prediction supports that hypothesis (a
  person's only within ``person_blob_gate``); with several the hypothesis splits, one copy
  per blob (both legs of a walker); Equation 3 updates the weight, the blob goes to the
  Kalman filter, and the wall penalty applies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.core.geometry import pairwise_distances
from laser_tracker.core.tracking.frame import Frame
from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import PERSON, PERSON_WALKED_IN, Hypotheses


def wall_penalty(config, weight: np.ndarray, velocity: np.ndarray,
                 structure: np.ndarray) -> np.ndarray:
    """``weight`` times ``wall_factor`` where the velocity (at least ``wall_min_speed``)
    runs within ``wall_angle`` of the direction of the structure the blob lies on (NaN:
    none), paper Sec. 8."""
    has = ~np.isnan(structure)
    if not has.any():
        return weight
    c = config
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    heading = np.arctan2(velocity[:, 1], velocity[:, 0])
    diff = np.abs(np.mod(heading - np.where(has, structure, 0.0) + np.pi / 2, np.pi)
                  - np.pi / 2)
    along = has & (speed >= c.wall_min_speed) & (diff <= math.radians(c.wall_angle))
    return np.where(along, weight * c.wall_factor, weight)


def _percent(weight: np.ndarray) -> np.ndarray:
    """``weight`` clipped to 0..100 (``np.clip``'s values, without its overhead)."""
    return np.minimum(np.maximum(weight, 0.0), 100.0)


@dataclass
class PersonMatch:
    """Person detections against the hypotheses: ``person_of`` (k,) the detection that
    supports each hypothesis (-1: none; ``supported``: not -1), ``fresh`` (p,) the
    detections that start one."""

    person_of: np.ndarray
    supported: np.ndarray
    fresh: np.ndarray


class PersonAssociation(Role):
    """Person detections as measurements (see the module docstring)."""

    def associate(self, hyp: Hypotheses, pred: np.ndarray, frame: Frame) -> PersonMatch:
        """Claims and fresh detections; drops the legs of the people used from the frame's
        motion blobs (a person starting a hypothesis takes its legs' blobs only if seen
        walking in: else the blobs may be a mover beside clutter and start their own)."""
        c = self.config
        k, persons = len(hyp), frame.persons
        person_of = np.full(k, -1, np.intp)
        fresh = np.zeros(persons.shape[0], bool)
        if persons.shape[0]:
            dp = pairwise_distances(pred, persons)
            if k:
                near = dp.argmin(axis=1)
                person_of = np.where(dp[np.arange(k), near] <= c.person_gate, near, -1)
            claimed = (dp <= c.person_gate).any(axis=0) if k else fresh.copy()
            fresh = ~claimed & (frame.confidence >= c.person_create_confidence)
            used = fresh & frame.free
            used[person_of[person_of >= 0]] = True
            if frame.xy.shape[0] and c.person_radius > 0 and used.any():
                frame.without_blobs(pairwise_distances(frame.xy, persons[used]).min(axis=1)
                                    <= c.person_radius)
        return PersonMatch(person_of, person_of >= 0, fresh)

    def support(self, hyp: Hypotheses, pred: np.ndarray, frame: Frame,
                match: PersonMatch) -> Hypotheses:
        """The hypotheses a detection supports, updated: Eq. 3 with its distance, Kalman,
        one more sample; a person seen in space that was free before, or whose legs'
        separation has varied by ``gait_spread``, is walking (``PERSON_WALKED_IN``)."""
        rows = np.flatnonzero(match.supported)
        if not rows.size:
            return Hypotheses.empty(hyp.dim)
        c, t = self.config, frame.stamp
        out = hyp.take(rows)
        which = match.person_of[rows]
        persons, free, spread = frame.persons[which], frame.free[which], frame.spread[which]
        d = np.maximum(np.hypot(*(persons - pred[rows]).T) - c.person_tolerance, 0.0)
        state, P, position = self.filter.correct(out.state, out.P, out.t_state, persons, t)
        out.state, out.P, out.position, out.t_state = state, P, position, t
        out.weight = _percent(out.weight + c.w_inc - c.w_dec / c.distance_unit * d)
        out.samples += 1
        out.person_samples += 1
        out.supported, out.stopped = True, False
        least, largest = out.spread[:, 0], out.spread[:, 1]
        least[:] = np.fmin(least, spread)
        largest[:] = np.fmax(largest, spread)
        walks = free | ((c.gait_spread > 0) & (largest - least >= c.gait_spread))
        out.origin = np.where(walks & (out.origin == PERSON), PERSON_WALKED_IN, out.origin)
        return out


@dataclass
class BlobMatch:
    """Motion blobs against the hypotheses: ``dist`` (k, b) from the predictions, the
    Eq. 2 ``weight`` (b,) of each blob, the ``new`` ones (b,), the supporting pairs
    (hypothesis ``hi``, blob ``bi``) and the hypotheses no measurement supports."""

    dist: np.ndarray
    weight: np.ndarray
    new: np.ndarray
    hi: np.ndarray
    bi: np.ndarray
    unsupported: np.ndarray


class BlobAssociation(Role):
    """The paper's association of motion blobs (see the module docstring); ``identity``
    names the copies of a split."""

    def __init__(self, config, filter, stats: dict, identity):
        super().__init__(config, filter, stats)
        self.identity = identity

    def associate(self, hyp: Hypotheses, pred: np.ndarray, frame: Frame,
                  people: PersonMatch) -> BlobMatch:
        c = self.config
        k, b = len(hyp), frame.xy.shape[0]
        by_person = people.supported
        if not (k and b):                       # no hypothesis lowers a blob's weight
            weight, pairs = np.full(b, 100.0), np.zeros(0, np.intp)
            return BlobMatch(np.zeros((k, b)), weight, weight > c.new_blob_threshold, pairs,
                             pairs, ~by_person)
        dist = pairwise_distances(pred, frame.xy)
        # Equation 2 (a stopped object held by the scans does not make the motion near it
        # old).
        weight = _percent(100.0 - np.maximum(c.blob_radius - dist[~hyp.stopped] /
                                             c.distance_unit, 0.0).sum(axis=0))
        new = weight > c.new_blob_threshold
        if c.new_when_ungated:
            new |= ~(dist <= c.gate).any(axis=0)
        gate = (dist <= c.gate) & ~by_person[:, None]
        if c.person_blob_gate > 0:
            person_kind = hyp.is_person(c.person_kind_samples)
            gate[person_kind] &= dist[person_kind] <= c.person_blob_gate
        hi, bi = np.nonzero(gate)
        return BlobMatch(dist, weight, new, hi, bi, ~gate.any(axis=1) & ~by_person)

    def support(self, hyp: Hypotheses, frame: Frame, match: BlobMatch) -> Hypotheses:
        """One copy of hypothesis ``hi[j]`` per supporting blob ``bi[j]``: Eq. 3, Kalman,
        wall penalty; on a split the identity rules of ``identity.split``."""
        hi, bi = match.hi, match.bi
        if not hi.size:
            return Hypotheses.empty(hyp.dim)
        c, t = self.config, frame.stamp
        out = hyp.take(hi)
        d = match.dist[hi, bi]
        state, P, position = self.filter.correct(out.state, out.P, out.t_state, frame.xy[bi],
                                                 t)
        out.state, out.P, out.position, out.t_state = state, P, position, t
        weight = _percent(out.weight + (c.w_inc - c.w_dec / c.distance_unit * d))
        out.weight = wall_penalty(c, weight, state[:, 2:], frame.structure[bi])
        out.samples += 1
        out.supported, out.stopped = True, False
        self.identity.split(out, hi, d)
        return out
