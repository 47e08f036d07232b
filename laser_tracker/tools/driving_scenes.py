"""The leg-labelled scenes seen from a robot that drives: real legs in a real building.

leg_tracker's positive recordings label the legs of people walking in front of a standing
robot; its ``negative_2.bag`` is the same robot driving 38 m through a building with nobody
in view. :func:`write_driving_scene` puts the labelled legs of one positive recording into
the scans of one scanner of the negative recording, which gives an annotated recording of
what no public data set holds: a Hokuyo-class robot driving among people, with its own
clutter, dropouts and body in view.

* **Placement.** The positive recording's runs (scans less than ``MAX_GAP`` apart) follow
  one another, ``START`` scans into the driving recording, one positive scan per driving
  scan (both 7.5 Hz). At a run's first scan the standing robot's frame is put on the
  driving scanner's pose (the package's own ego-motion over those scans): the people start
  where they stood relative to the robot, and the robot then drives on among them or away
  from them; a run ends where one of its people comes within ``CLEARANCE`` of the driving
  scanner (the robot would stop). The ``GAP`` driving scans after a run are left out and
  the recording ends with the last run: as in the positive recordings, whose runs are
  seconds apart, the tracker starts afresh (a gap of more than ``hypotheses.max_gap``)
  rather than follow people who vanish where the run ends.
* **Legs.** Each labelled leg is the outline of its cluster (its returns in beam order,
  the cluster nearest the label within ``MATCH_RADIUS``), carried into the driving
  scanner's frame and turned about its centre so that it shows the scanner the side it
  showed the standing one (a leg is about round), then ray-cast into the scan over each
  beam's width: a beam that mostly meets the outline returns from it when that is nearer
  than what the beam saw; beams without a return (REP 117 +inf; the recording's codes are
  rewritten so) return from it too. The other people and the clutter of the positive scans
  are not carried over.
* **Annotations.** A person is annotated at its labelled position (two legs: their
  midpoint) in each scan where at least ``MIN_BEAMS`` beams return from its legs; hidden
  behind the building's own structure (or outside the field of view) it is not, and is
  written on ``annotations.HIDDEN_TOPIC`` instead, so that a track that follows it there is
  told apart from one on nothing.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from laser_tracker.core.geometry import pairwise_distances, points_in_frame, transform_points
from laser_tracker.core.scan import Scan
from laser_tracker.core.segmentation import segment
from laser_tracker.tools.leg_scenes import (SCENE_SCAN_TOPIC, link_people, people_of_legs,
                                            person_msg, read_labelled)

#: Scans of the driving recording before the first run (its ego-motion and static
#: background settle), and left out after each run (2.1 s at 7.5 Hz: more than the
#: tracker's ``max_gap``).
START, GAP = 20, 16
#: Scans further apart than this (s) start a new run (as people are linked).
MAX_GAP = 0.3
#: A labelled leg is the cluster whose centroid lies within this distance (m) of it.
MATCH_RADIUS = 0.1
#: A run ends at the first scan where one of its people is nearer than this (m) to the
#: driving scanner: the robot would have stopped, or run into them.
CLEARANCE = 0.5
#: Rays per beam across its width (the angle between beams), averaged.
SUB_RAYS = 5
#: A person is in view when at least this many beams return from its legs (a segment's
#: least number of points).
MIN_BEAMS = 3


def runs_of(stamps: np.ndarray) -> list[np.ndarray]:
    """The indices of ``stamps`` split where consecutive scans are more than ``MAX_GAP``
    apart."""
    if stamps.size == 0:
        return []
    return np.split(np.arange(stamps.size), np.flatnonzero(np.diff(stamps) > MAX_GAP) + 1)


def leg_outlines(scan: Scan, legs: np.ndarray) -> list[np.ndarray | None]:
    """Per labelled leg (rows of ``legs``, scanner frame): the returns of its cluster in
    beam order (n, 2), None when no cluster lies within ``MATCH_RADIUS``."""
    legs = np.asarray(legs, float).reshape(-1, 2)
    c = segment(scan)
    if not c.count or not legs.shape[0]:
        return [None] * legs.shape[0]
    points = np.column_stack((scan.ranges * np.cos(scan.angles),
                              scan.ranges * np.sin(scan.angles)))
    valid = scan.valid()
    out = []
    for leg in legs:
        d = np.hypot(*(c.xy - leg).T)
        k = int(np.argmin(d))
        if d[k] > MATCH_RADIUS:
            out.append(None)
            continue
        beams = np.arange(c.first[k], c.last[k] + 1)
        out.append(points[beams[valid[beams]]])
    return out


def carried(outline: np.ndarray, anchor: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``outline`` (standing scanner's frame, which sits at ``anchor`` in the world) in the
    frame of the scanner at ``pose``, turned about its centre so that it faces that scanner
    as it faced the standing one (its points keep their offsets along and across the line
    of sight)."""
    centre0 = outline.mean(axis=0)
    centre1 = points_in_frame(pose, transform_points(anchor, centre0[None, :]))[0]
    v0 = centre0 / max(np.hypot(*centre0), 1e-9)
    v1 = centre1 / max(np.hypot(*centre1), 1e-9)
    rel = outline - centre0
    along, across = rel @ v0, rel @ np.array([-v0[1], v0[0]])
    return centre1 + along[:, None] * v1 + across[:, None] * np.array([-v1[1], v1[0]])


def outline_ranges(outline: np.ndarray, scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    """The beams of ``scan`` that meet the polyline ``outline`` (scanner frame) and the range
    each returns from it: the mean over the beam's width (``SUB_RAYS`` rays spread over the
    angle between beams) of where those rays first meet it, when at least half of them
    do; a beam that mostly misses it returns what lies behind. A beam spreads over the
    surface as its spacing does, so a leg seen from farther returns as smooth an outline
    as a real one at that range, not the detail the nearer scanner saw."""
    if outline.shape[0] < 2:
        return np.zeros(0, np.intp), np.zeros(0)
    bearing = np.arctan2(outline[:, 1], outline[:, 0])
    if np.ptp(bearing) > math.pi:              # straddles the scanner's back: not in view
        return np.zeros(0, np.intp), np.zeros(0)
    inc = scan.angle_increment
    ends = (np.array([bearing.min(), bearing.max()]) - scan.angle_min) / inc
    lo, hi = int(math.floor(ends.min())), int(math.ceil(ends.max()))
    beams = np.arange(max(lo, 0), min(hi, scan.n_beams - 1) + 1)
    if not beams.size:
        return beams, np.zeros(0)
    spread = (np.arange(SUB_RAYS) + 0.5) / SUB_RAYS - 0.5
    angle = (scan.angle_min + (beams[:, None] + spread[None, :]) * inc).ravel()
    u = np.column_stack((np.cos(angle), np.sin(angle)))
    best = np.full(angle.size, np.inf)
    for p, q in zip(outline[:-1], outline[1:]):
        d = q - p
        den = u[:, 0] * d[1] - u[:, 1] * d[0]
        with np.errstate(divide='ignore', invalid='ignore'):
            t = (p[0] * d[1] - p[1] * d[0]) / den           # along the ray
            s = (p[0] * u[:, 1] - p[1] * u[:, 0]) / den     # along the outline's segment
        hit = (s >= 0.0) & (s <= 1.0) & (t > 0.0) & (t < best)
        best[hit] = t[hit]
    best = best.reshape(beams.size, SUB_RAYS)
    met = np.isfinite(best)
    mostly = met.sum(axis=1) * 2 >= SUB_RAYS
    mean = np.where(met, best, 0.0).sum(axis=1) / np.maximum(met.sum(axis=1), 1)
    return beams[mostly], mean[mostly]


def driving_poses(scans: list[Scan]) -> np.ndarray:
    """The scanner pose (x, y, theta; odometry frame) of each scan as a replay with the
    default parameters estimates it (the recording has no odometry); a scan without a pose
    keeps the previous one."""
    from laser_tracker import parameters
    from laser_tracker.core.pipeline import Pipeline

    pipeline = Pipeline(parameters.pipeline_config(parameters.load([])))
    poses, last = [], np.zeros(3)
    for scan in scans:
        pose = np.asarray(pipeline.step(scan).pose, float)
        last = pose if np.isfinite(pose).all() else last
        poses.append(last)
    return np.array(poses)


def write_driving_scene(positive: str | Path, negative: str | Path, topic: str,
                        dst: str | Path, poses: np.ndarray | None = None) -> dict:
    """The people of the positive recording ``positive`` in the scans of ``topic`` of the
    negative recording ``negative``, as an annotated rosbag2 at ``dst`` (``/scan`` and
    ``/ground_truth_people_tracks``; module docstring). ``poses``: the driving scanner's
    poses, one per scan (default: :func:`driving_poses`). Returns counts."""
    from laser_tracker.conversions import scan_to_msg
    from laser_tracker.tools.annotations import (ANNOTATION_TOPIC, HIDDEN_TOPIC,
                                                 register_person_type)
    from laser_tracker.tools.bag import FACTORY, TYPESTORE, BagWriter, read_scans

    standing, legs = read_labelled(positive)
    stamps = np.array([s.stamp for s in standing])
    people = link_people(stamps, people_of_legs(legs), max_gap=MAX_GAP)
    driving = [s.with_no_returns_as_inf() for s in read_scans(negative, topic)
               if isinstance(s, Scan)]
    poses = driving_poses(driving) if poses is None else np.asarray(poses, float)
    source = np.full(len(driving), -1, np.int64)      # the standing scan shown in each
    anchor = np.zeros(len(driving), np.int64)         # the driving scan of its run's start
    at, placed = START, 0
    for run in runs_of(stamps):
        if at + run.size > len(driving):
            break
        # the run ends where the driving robot would run into one of its people
        for n, k in enumerate(run):
            here = people.xy[people.scan == k]
            world = transform_points(poses[at], here)
            near = np.hypot(*points_in_frame(poses[at + n], world).T)
            if near.size and near.min() < CLEARANCE:
                run = run[:n]
                break
        if not run.size:
            continue
        source[at:at + run.size], anchor[at:at + run.size] = run, at
        at, placed = at + run.size + GAP, placed + 1
    register_person_type(TYPESTORE)
    annotated, hidden, shown = 0, 0, set()
    last = int(np.flatnonzero(source >= 0).max()) if placed else START - 1
    written = 0
    with BagWriter(dst) as bag:
        for j, scan in enumerate(driving[:last + 1]):
            k = source[j]
            if k < 0 and j >= START:
                continue
            ranges = scan.ranges.copy()
            t_ns = int(round(scan.stamp * 1e9))
            rows = np.flatnonzero(people.scan == k) if k >= 0 else np.zeros(0, np.intp)
            if rows.size:
                here = people.xy[rows]
                label = np.asarray(legs[k], float).reshape(-1, 2)
                owner = np.argmin(pairwise_distances(label, here), axis=1)
                from_person = np.full(scan.n_beams, -1, np.int64)
                for leg, outline in enumerate(leg_outlines(standing[k], label)):
                    if outline is None:
                        continue
                    beams, r = outline_ranges(carried(outline, poses[anchor[j]], poses[j]),
                                              scan)
                    old = ranges[beams]
                    with np.errstate(invalid='ignore'):   # what the beam saw stays if nearer
                        kept = (np.isfinite(old) & (old >= scan.range_min) & (old <= r)) \
                            | (old == -np.inf)
                    nearer = ~kept
                    ranges[beams[nearer]] = r[nearer]
                    from_person[beams[nearer]] = owner[leg]
                scan = dataclasses.replace(scan, ranges=ranges)
                seen = np.bincount(from_person[from_person >= 0], minlength=rows.size)
                world = transform_points(poses[anchor[j]], here)
                local = points_in_frame(poses[j], world)
            bag.write(SCENE_SCAN_TOPIC, scan_to_msg(FACTORY, scan), t_ns)
            written += 1
            for m in range(rows.size):
                in_view = seen[m] >= MIN_BEAMS
                bag.write(ANNOTATION_TOPIC if in_view else HIDDEN_TOPIC, person_msg(
                    FACTORY, TYPESTORE, local[m], int(people.person[rows[m]])), t_ns + 1000)
                if in_view:
                    annotated += 1
                    shown.add(int(people.person[rows[m]]))
                else:
                    hidden += 1
    return {'scans': written, 'runs': placed, 'annotations': annotated, 'hidden': hidden,
            'people': len(shown), 'area': None}
