"""Confirmation: when a hypothesis is reported as a moving object.

The paper's rule (Sec. 8) is ``confirm_samples`` (m = 4) samples: the creation pair and
three supporting blobs. Each further rule is a small function that says which of the
candidates (hypotheses not confirmed yet, with m samples) may be confirmed, given the
confirmed tracks and the frame; it applies while its parameter is above 0 (the paper mode
sets them all to 0). A hypothesis is confirmed once every applying rule allows it, and stays
confirmed.
"""
from __future__ import annotations

import numpy as np

from laser_tracker.core.geometry import pairwise_distances
from laser_tracker.core.tracking.frame import Frame
from laser_tracker.core.tracking.role import Role
from laser_tracker.core.tracking.state import MOTION, PERSON, Hypotheses


def _travel(h: Hypotheses, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
    """How far (m) each hypothesis is from where it started: in the world and in the
    scanner's frame."""
    return (np.hypot(*(h.position - h.start).T),
            np.hypot(*(frame.scanner.to_scanner(h.position) - h.start_local).T))


def _legs_seen(c, h: Hypotheses) -> np.ndarray:
    """Supported by ``person_confirm_pairs`` detections of both legs off static background
    (0: never): a person in view, however the hypothesis started."""
    if c.person_confirm_pairs <= 0:
        return np.zeros(len(h), bool)
    return h.pair_samples >= c.person_confirm_pairs


def walked(c, candidates: Hypotheses, confirmed: Hypotheses, frame: Frame) -> np.ndarray:
    """A hypothesis started by a person detection standing where the scans always saw
    something (chair and table legs look like legs) only once it has moved
    ``person_min_travel`` from where it started, both in the world (not clutter the robot
    passes) and in the scanner's frame (not something riding along with the robot); or once
    ``person_confirm_samples`` detections, or ``person_confirm_pairs`` detections of two
    legs off static background, supported it (someone in view from the start). A detection
    standing in space seen free before (someone who walked in), away from a place the scan
    sees left empty (walked out) or legs whose separation swings (``gait_spread``) made it
    ``PERSON_WALKED_IN``: no restriction here (but see :func:`moved_more_than_the_view`)."""
    h = candidates
    world, local = _travel(h, frame)
    out = (h.origin != PERSON) | (np.minimum(world, local) >= c.person_min_travel)
    if c.person_confirm_samples > 0:
        out |= h.person_samples >= c.person_confirm_samples
    return out | _legs_seen(c, h)


def moved_more_than_the_view(c, candidates: Hypotheses, confirmed: Hypotheses,
                             frame: Frame) -> np.ndarray:
    """A hypothesis started by motion blobs or by a person who walked in
    (``PERSON_WALKED_IN``) has moved, in the world, ``view_travel_ratio`` times the
    displacement the scanner's motion since its start causes at its starting place (where
    a static object there now is in the scanner's frame against where it was then): a
    change that the changing viewpoint alone explains (parallax, beams that passed a static
    object before, registration error) is no evidence of motion. Or, as for a hypothesis a
    person detection started (:func:`walked`), ``person_confirm_pairs`` detections of both
    legs off static background supported it: a person who stands where a driving robot
    comes upon them shows as motion blobs first, and walks no farther."""
    h = candidates
    world, _ = _travel(h, frame)
    view = np.hypot(*(frame.scanner.to_scanner(h.start) - h.start_local).T)
    return (h.origin == PERSON) | (world >= c.view_travel_ratio * view) | _legs_seen(c, h)


def not_riding_along(c, candidates: Hypotheses, confirmed: Hypotheses,
                     frame: Frame) -> np.ndarray:
    """Not a hypothesis (other than a person) that moves with the scanner: its velocity
    within ``ride_along_speed`` of the velocity of the point of the scanner's rigid frame
    where it is, while the scanner moves at least ``ride_along_min_speed`` (glass or a mirror
    at normal incidence, the robot's own parts); nor one that has, on average since it
    started, moved that slowly in the scanner's frame and at least ``ride_along_min_speed``
    in the world (the filter's velocity lags behind a part of the robot that turns with
    it). A person who walks with the robot shows both legs apart now and then: one seen only
    as a lone leg (the edge of a wall where the field of view ends looks like one) is not
    taken for a person here."""
    h = candidates
    age = np.maximum(frame.stamp - h.born, 1e-9)
    world, local = _travel(h, frame)
    riding = (local < c.ride_along_speed * age) & (world >= c.ride_along_min_speed * age)
    motion = frame.scanner.motion(frame.stamp)
    if motion is not None and motion[2] >= c.ride_along_min_speed:
        velocity, turn, _ = motion
        arm = h.position - frame.scanner.pose[:2]
        rigid = velocity + turn * np.column_stack((-arm[:, 1], arm[:, 0]))
        riding |= np.hypot(*(h.velocity - rigid).T) < c.ride_along_speed
    person = h.is_person(c.person_kind_samples) & (h.pair_samples > 0)
    return ~(riding & ~person)


def old_enough(c, candidates: Hypotheses, confirmed: Hypotheses, frame: Frame) -> np.ndarray:
    """Lived ``confirm_time`` since its creation, whatever the scan rate (a hypothesis a
    person detection started: ``person_confirm_time`` when set)."""
    age = frame.stamp - candidates.born
    if c.person_confirm_time <= 0:
        return age >= c.confirm_time
    return age >= np.where(candidates.origin == MOTION, c.confirm_time, c.person_confirm_time)


def fast_enough(c, candidates: Hypotheses, confirmed: Hypotheses, frame: Frame) -> np.ndarray:
    """Moves at ``confirm_min_speed`` or faster (not a flicker in place)."""
    return (candidates.velocity ** 2).sum(axis=1) >= c.confirm_min_speed ** 2


def travelled(c, candidates: Hypotheses, confirmed: Hypotheses, frame: Frame) -> np.ndarray:
    """Started by motion blobs: ``confirm_min_travel`` from where it was created (a moving
    object goes somewhere; a thin static object flickering in the scans does not), unless
    both legs of a person were seen there (:func:`_legs_seen`)."""
    h = candidates
    far = ((h.position - h.start) ** 2).sum(axis=1) >= c.confirm_min_travel ** 2
    return far | (h.origin != MOTION) | _legs_seen(c, h)


def not_a_duplicate(c, candidates: Hypotheses, confirmed: Hypotheses,
                    frame: Frame) -> np.ndarray:
    """Not within ``duplicate_radius`` of a confirmed track (it follows the same legs and
    merges into it: confirming it would show a new id for a frame)."""
    if not len(confirmed):
        return np.ones(len(candidates), bool)
    return ~(pairwise_distances(candidates.position, confirmed.position)
             <= c.duplicate_radius).any(axis=1)


def measured(c, candidates: Hypotheses, confirmed: Hypotheses, frame: Frame) -> np.ndarray:
    """Supported by a blob or a person detection in this frame: while a hypothesis coasts
    its position is extrapolated along its velocity, so the travel and time it reaches then
    are no evidence (clutter that flickered for a few scans is confirmed on its last
    extrapolated frame otherwise)."""
    return candidates.supported.copy()


#: The further rules, each with the parameter that switches it on (above 0, or true).
RULES = ((measured, 'confirm_when_measured'), (walked, 'person_min_travel'),
         (moved_more_than_the_view, 'view_travel_ratio'), (not_riding_along, 'ride_along_speed'),
         (old_enough, 'confirm_time'), (fast_enough, 'confirm_min_speed'),
         (travelled, 'confirm_min_travel'), (not_a_duplicate, 'duplicate_radius'))

#: The rules that ask for evidence that a person walks (not clutter standing, not part of the
#: robot): a hypothesis that takes over a lost confirmed track has given it already.
WALKING_EVIDENCE = (walked, not_riding_along)


class Confirmation(Role):
    """The paper's rule and the further rules (see the module docstring)."""

    def confirm(self, hyp: Hypotheses, frame: Frame,
                continuing: np.ndarray | None = None) -> np.ndarray:
        """Confirms the hypotheses every applying rule allows; returns the indices of those
        confirmed now. ``continuing`` (mask over ``hyp``): hypotheses that take over a lost
        confirmed track (``identity``), which the rules of :data:`WALKING_EVIDENCE` let
        through."""
        c = self.config
        # The candidates: not confirmed yet, with the paper's m samples.
        rows = (~hyp.confirmed & (hyp.samples >= c.confirm_samples)).nonzero()[0]
        if rows.size:
            candidates, confirmed = hyp.take(rows), hyp.take(hyp.confirmed)
            for rule, switch in RULES:
                if getattr(c, switch) > 0:
                    allowed = rule(c, candidates, confirmed, frame)
                    if continuing is not None and rule in WALKING_EVIDENCE:
                        allowed |= continuing[rows]
                    if not allowed.all():
                        rows = rows[allowed]
                        if not rows.size:
                            break
                        candidates = candidates.take(allowed)
            hyp.rows['confirmed'][rows] = True
            self.stats['confirmed'] += int(rows.size)
        return rows
