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

from laser_tracker.core import jit
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
        person_of, fresh, legs = _claims(pred, frame.persons, frame.confidence, frame.free,
                                         frame.xy, c.person_gate, c.person_create_confidence,
                                         c.person_radius)
        if legs is not None:
            frame.without_blobs(legs)
        return PersonMatch(person_of, person_of >= 0, fresh)

    def support(self, hyp: Hypotheses, pred: np.ndarray, frame: Frame,
                match: PersonMatch) -> Hypotheses:
        """The hypotheses a detection supports, updated: Eq. 3 with its distance, Kalman,
        one more sample; a person seen in space that was free before, or whose legs'
        separation has varied by ``gait_spread``, is walking (``PERSON_WALKED_IN``)."""
        rows = match.supported.nonzero()[0]
        if not rows.size:
            return Hypotheses.empty(hyp.dim)
        c = self.config
        out = hyp.take(rows)
        which = match.person_of[rows]
        persons = frame.persons[which]
        self.filter.support(out, persons, frame.stamp)
        o = out.rows
        _person_measured(o['weight'], o['samples'], o['person_samples'], o['pair_samples'],
                         o['spread'], o['origin'], pred[rows], persons, frame.free[which],
                         frame.spread[which], c.w_inc, c.w_dec / c.distance_unit,
                         c.person_tolerance, c.gait_spread)
        out.supported, out.stopped = True, False
        return out


@dataclass
class BlobMatch:
    """Motion blobs against the hypotheses: the Eq. 2 ``weight`` (b,) of each blob, the
    ``new`` ones (b,), the supporting pairs (hypothesis ``hi``, blob ``bi``, at distance
    ``d`` from the prediction) and the hypotheses no measurement supports."""

    weight: np.ndarray
    new: np.ndarray
    hi: np.ndarray
    bi: np.ndarray
    d: np.ndarray
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
        person_kind = hyp.is_person(c.person_kind_samples)
        return BlobMatch(*_eq2_and_gates(pred, frame.xy, hyp.stopped, people.supported,
                                         person_kind, c.blob_radius, c.distance_unit,
                                         c.new_blob_threshold, c.new_when_ungated, c.gate,
                                         c.person_blob_gate))

    def support(self, hyp: Hypotheses, frame: Frame, match: BlobMatch) -> Hypotheses:
        """One copy of hypothesis ``hi[j]`` per supporting blob ``bi[j]``: Eq. 3, Kalman,
        wall penalty; on a split the identity rules of ``identity.split``."""
        hi, bi = match.hi, match.bi
        if not hi.size:
            return Hypotheses.empty(hyp.dim)
        c, t = self.config, frame.stamp
        out = hyp.take(hi)
        d = match.d
        self.filter.support(out, frame.xy[bi], t)
        o = out.rows
        _equation_3(o['weight'], o['samples'], d, c.w_inc, c.w_dec / c.distance_unit)
        out.weight = wall_penalty(c, o['weight'], out.velocity, frame.structure[bi])
        out.supported, out.stopped = True, False
        self.identity.split(out, hi, d)
        return out


@jit.kernel
def _equation_3(weight, samples, d, w_inc, w_dec):
    """Equation 3 for hypotheses (their fields, in place) supported by blobs ``d`` from their
    predictions (``w_dec`` per metre), clipped to 0..100; one more sample."""
    for i in range(weight.size):
        weight[i] = min(max(weight[i] + (w_inc - w_dec * d[i]), 0.0), 100.0)
        samples[i] += 1


@jit.kernel
def _person_measured(weight, samples, person_samples, pair_samples, spread, origin, pred,
                     persons, free, seen, w_inc, w_dec, tolerance, gait):
    """Hypotheses (their fields, in place) predicted at ``pred`` and supported by person
    detections ``persons`` (walked in: ``free``; leg separation ``seen``, NaN: none): Eq. 3
    with the distance beyond ``tolerance`` (``w_dec`` per metre), one more sample of both
    kinds (and of two legs when ``seen``: a pair off static background), the least and
    largest separation seen, and walking (``PERSON_WALKED_IN``) once walked in or the
    separation varied by ``gait`` (above 0)."""
    for i in range(weight.size):
        d = max(np.hypot(persons[i, 0] - pred[i, 0], persons[i, 1] - pred[i, 1]) - tolerance,
                0.0)
        weight[i] = min(max(weight[i] + w_inc - w_dec * d, 0.0), 100.0)
        samples[i] += 1
        person_samples[i] += 1
        if seen[i] == seen[i]:
            pair_samples[i] += 1
        least, largest = np.fmin(spread[i, 0], seen[i]), np.fmax(spread[i, 1], seen[i])
        spread[i, 0], spread[i, 1] = least, largest
        walks = free[i] or (gait > 0 and largest - least >= gait)
        if walks and origin[i] == PERSON:
            origin[i] = PERSON_WALKED_IN


@jit.kernel
def _claims(pred, persons, confidence, free, xy, gate, create_confidence, radius):
    """Person detections ``persons`` (p, 2) against the predictions ``pred`` (k, 2): the
    nearest detection of each hypothesis within ``gate`` (-1: none), the detections no
    prediction is within ``gate`` of that are confident enough to start one (fresh), and
    the blobs ``xy`` within ``radius`` of the detections used (claimed, or fresh and
    walked in), None when there are none."""
    k, p, b = pred.shape[0], persons.shape[0], xy.shape[0]
    person_of = np.full(k, -1, np.intp)
    claimed = np.zeros(p, np.bool_)
    for i in range(k):
        near = -1
        best = np.inf
        for j in range(p):
            dx, dy = pred[i, 0] - persons[j, 0], pred[i, 1] - persons[j, 1]
            d = np.sqrt(dx * dx + dy * dy)
            claimed[j] |= d <= gate
            if near < 0 or (best == best and (d < best or d != d)):   # argmin: first NaN
                near, best = j, d
        if near >= 0 and best <= gate:
            person_of[i] = near
    fresh = np.empty(p, np.bool_)
    used = np.empty(p, np.bool_)
    for j in range(p):
        fresh[j] = not claimed[j] and confidence[j] >= create_confidence
        used[j] = fresh[j] and free[j]
    for i in range(k):
        if person_of[i] >= 0:
            used[person_of[i]] = True
    if not (b and radius > 0 and used.any()):
        return person_of, fresh, None
    legs = np.zeros(b, np.bool_)
    for m in range(b):
        least = np.inf
        for j in range(p):
            if used[j]:
                dx, dy = xy[m, 0] - persons[j, 0], xy[m, 1] - persons[j, 1]
                d = np.sqrt(dx * dx + dy * dy)
                if d != d or least != least:
                    least = np.nan
                elif d < least:
                    least = d
        legs[m] = least <= radius
    return person_of, fresh, legs if legs.any() else None


@jit.kernel
def _eq2_and_gates(pred, xy, stopped, by_person, person_kind, blob_radius, unit,
                   new_threshold, new_when_ungated, gate, person_blob_gate):
    """The blobs ``xy`` (b, 2) against the predictions ``pred`` (k, 2): Equation 2 (a
    stopped object held by the scans does not make the motion near it old), the new blobs,
    the gated pairs (row-major, with their distances; none for a hypothesis a person
    detection supports, a person's only within ``person_blob_gate`` when above 0) and the
    hypotheses no measurement supports. The sums add as numpy adds a column."""
    k, b = pred.shape[0], xy.shape[0]
    dist = np.empty((k, b))
    for i in range(k):
        for j in range(b):
            dx, dy = pred[i, 0] - xy[j, 0], pred[i, 1] - xy[j, 1]
            dist[i, j] = np.sqrt(dx * dx + dy * dy)
    weight, new = np.empty(b), np.empty(b, np.bool_)
    terms = np.empty(k)
    for j in range(b):
        n = 0
        total = 0.0
        for i in range(k):
            if not stopped[i]:
                term = max(blob_radius - dist[i, j] / unit, 0.0)
                terms[n] = term
                total = total + term if n else term
                n += 1
        if b == 1:                  # numpy adds a single column pairwise
            total = jit.pairwise_sum(terms, 0, n)
        weight[j] = min(max(100.0 - total, 0.0), 100.0)
        new[j] = weight[j] > new_threshold
        if new_when_ungated and k:
            near = False
            for i in range(k):
                near |= dist[i, j] <= gate
            new[j] |= not near
    gated = np.zeros((k, b), np.bool_)
    unsupported = np.empty(k, np.bool_)
    pairs = 0
    for i in range(k):
        reach = gate
        if person_blob_gate > 0 and person_kind[i]:
            reach = min(gate, person_blob_gate)
        for j in range(b):
            gated[i, j] = not by_person[i] and dist[i, j] <= gate and dist[i, j] <= reach
            pairs += gated[i, j]
        unsupported[i] = not by_person[i]
    hi, bi, d = np.empty(pairs, np.intp), np.empty(pairs, np.intp), np.empty(pairs)
    n = 0
    for i in range(k):
        for j in range(b):
            if gated[i, j]:
                hi[n], bi[n], d[n] = i, j, dist[i, j]
                unsupported[i] = False
                n += 1
    return weight, new, hi, bi, d, unsupported
