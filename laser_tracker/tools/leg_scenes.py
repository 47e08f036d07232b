"""Leg-labelled training recordings replayed as annotated tracking scenes.

leg_tracker's ``positive_*_extracted.bag`` hold runs of consecutive scans (7.5 Hz, a few
seconds each) of people walking in front of a standing robot, with every scan cluster inside
the walking area labelled as a leg (``/leg_cluster_positions``, scanner frame). They were
recorded to train a leg detector, but they are also scenes to track: the same robot and
scanners as a Hokuyo robot driving through people, with every leg in the walking area
labelled. :func:`write_scene` turns one into an annotated recording that ``laser-tracker
evaluate`` scores (CLEAR MOT, README.md "Replay and evaluate offline"):

* the people of a scan are its labelled legs paired greedily, nearest first, within
  ``pair_distance`` (two legs of one person), at their midpoint; an unpaired leg is a person
  whose other leg is hidden or merged with it, at the leg;
* a person keeps an id from scan to scan when the nearest person of the previous scan lies
  within ``link_distance`` (a minimum-distance assignment) and the scans are less than
  ``max_gap`` apart; else a new id starts;
* only the area the legs were labelled in is scored (:func:`labelled_area`: someone
  walking elsewhere in the room, or a person who steps out of the area, is not labelled):
  a track outside it counts only where it is on a labelled person;
* scans are written at their header stamps (the extracted recordings were written in one
  burst: their receive times say nothing) with the annotations just after them.

The detector must not have been trained on the scene it is scored on: :func:`held_out_model`
trains one model per scene on every other positive recording and the negatives, as the
shipped model was trained (``laser-tracker train-detector``), and caches it; likewise a
model without one scanner of the negative recording, for clutter the detector has not seen.
"""
from __future__ import annotations

import glob
import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from laser_tracker.tools.annotations import ANNOTATION_TOPIC, PERSON_MSGTYPE, \
    register_person_type

log = logging.getLogger(__name__)

POSITIVE_GLOB = 'leg_tracker/training/positive_*_extracted.bag'
#: The augmentation and classifier the shipped model was trained with (README.md, "The
#: person detector"), so that a held-out model is that model without one recording.
TRAINING_ARGS = ('--augment-range', '2,3')
SCENE_SCAN_TOPIC = '/scan'
#: How far beyond the labelled legs (m) every person is taken to be labelled (the walking
#: area's edge: a person who leaves it is no longer labelled).
AREA_MARGIN = 0.0


@dataclass
class ScenePeople:
    """People of a scene: per annotation its scan index, id and position (scanner frame)."""

    scan: np.ndarray
    person: np.ndarray
    xy: np.ndarray


def people_of_legs(legs: list[np.ndarray], pair_distance: float = 0.6) -> list[np.ndarray]:
    """Per scan, the people (m, 2) of its labelled legs (n, 2) (module docstring)."""
    out = []
    for xy in legs:
        xy = np.asarray(xy, float).reshape(-1, 2)
        n = xy.shape[0]
        d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
        d[np.tril_indices(n)] = np.inf
        paired = np.zeros(n, bool)
        people = []
        for flat in np.argsort(d, axis=None, kind='stable'):
            i, j = divmod(int(flat), n)
            if not d[i, j] <= pair_distance:
                break
            if not (paired[i] or paired[j]):
                paired[i] = paired[j] = True
                people.append((xy[i] + xy[j]) / 2)
        people += [xy[i] for i in range(n) if not paired[i]]
        out.append(np.array(people, float).reshape(-1, 2))
    return out


def link_people(stamps: np.ndarray, people: list[np.ndarray], link_distance: float = 0.5,
                max_gap: float = 0.3) -> ScenePeople:
    """Ids for the people of consecutive scans (module docstring)."""
    scan, person, xy = [], [], []
    prev_xy, prev_id, next_id = np.zeros((0, 2)), np.zeros(0, np.int64), 0
    for k, now in enumerate(people):
        ids = np.full(now.shape[0], -1, np.int64)
        if k and stamps[k] - stamps[k - 1] <= max_gap and now.shape[0] and prev_xy.shape[0]:
            d = np.hypot(*(now[:, None, :] - prev_xy[None, :, :]).transpose(2, 0, 1))
            rows, cols = linear_sum_assignment(np.where(d <= link_distance, d, 1e6))
            ok = d[rows, cols] <= link_distance
            ids[rows[ok]] = prev_id[cols[ok]]
        fresh = ids < 0
        ids[fresh] = next_id + np.arange(int(fresh.sum()))
        next_id += int(fresh.sum())
        scan += [k] * now.shape[0]
        person += ids.tolist()
        xy.append(now)
        prev_xy, prev_id = now, ids
    return ScenePeople(np.asarray(scan, np.int64), np.asarray(person, np.int64),
                       np.concatenate(xy) if xy else np.zeros((0, 2)))


def read_labelled(path: str | Path):
    """(scans, leg labels per scan) of a positive recording, in header-stamp order."""
    from laser_tracker.tools.train_detector import read_positive

    items = read_positive(path)
    order = np.argsort([i.scan.stamp for i in items], kind='stable')
    return [items[k].scan for k in order], [items[k].legs for k in order]


def write_scene(src: str | Path, dst: str | Path, no_return_as_inf: bool = False,
                beam_step: int = 1, scan_step: int = 1) -> dict:
    """The annotated scene of the positive recording ``src`` as a rosbag2 at ``dst``
    (``/scan`` and ``/ground_truth_people_tracks``); ``no_return_as_inf``: readings of 0 and
    below ``range_min`` written as +inf, as a REP 117 driver writes them; ``beam_step`` /
    ``scan_step``: every so many beams of every so many scans, as a scanner with fewer beams
    or a lower rate would have seen the scene (the people are linked over every scan first,
    so they keep their ids). Returns counts."""
    from laser_tracker.conversions import scan_to_msg
    from laser_tracker.tools.bag import FACTORY, TYPESTORE, BagWriter

    scans, legs = read_labelled(src)
    stamps = np.array([s.stamp for s in scans])
    people = link_people(stamps, people_of_legs(legs))
    register_person_type(TYPESTORE)
    kept = range(0, len(scans), scan_step)
    with BagWriter(dst) as bag:
        for k in kept:
            scan = scans[k]
            if no_return_as_inf:
                scan = scan.with_no_returns_as_inf()
            if beam_step > 1:
                scan = scan.every_nth_beam(beam_step)
            t_ns = int(round(scan.stamp * 1e9))
            bag.write(SCENE_SCAN_TOPIC, scan_to_msg(FACTORY, scan), t_ns)
            for m in np.flatnonzero(people.scan == k):
                bag.write(ANNOTATION_TOPIC, person_msg(FACTORY, TYPESTORE, people.xy[m],
                                                       int(people.person[m])), t_ns + 1000)
    written = np.isin(people.scan, np.asarray(kept))
    return {'scans': len(kept), 'annotations': int(written.sum()),
            'people': int(np.unique(people.person[written]).size),
            'legs': int(sum(np.asarray(legs[k]).reshape(-1, 2).shape[0] for k in kept)),
            'area': labelled_area(legs)}


def labelled_area(legs: list[np.ndarray], margin: float = AREA_MARGIN) -> list[float]:
    """The box of the scanner frame (xmin, xmax, ymin, ymax) that the labelled legs span,
    ``margin`` wider on each side: only there are people labelled."""
    xy = np.concatenate([np.asarray(x, float).reshape(-1, 2) for x in legs])
    lo, hi = xy.min(axis=0) - margin, xy.max(axis=0) + margin
    return [float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])]


def person_msg(factory, typestore, xy, oid: int):
    """An annotation message (leg_tracker's Person) of the person ``oid`` at ``xy``."""
    pose = factory.make('geometry_msgs/msg/Pose',
                        position=factory.make('geometry_msgs/msg/Point', x=float(xy[0]),
                                              y=float(xy[1]), z=0.0),
                        orientation=factory.make('geometry_msgs/msg/Quaternion', x=0.0, y=0.0,
                                                 z=0.0, w=1.0))
    return typestore.types[PERSON_MSGTYPE](pose=pose, id=oid)


def positive_recordings() -> list[Path]:
    """The positive training recordings of the public data folder (may be none)."""
    from laser_tracker.tools.data import real_recording

    return [Path(p) for p in sorted(glob.glob(str(real_recording(POSITIVE_GLOB))))]


def held_out_model(scene: Path | None = None, negative_topic: str | None = None,
                   cache: Path | None = None) -> Path:
    """A person detector model trained as the shipped one but without the positive
    recording ``scene``, or without the scanner ``negative_topic`` of the negative recording
    (every other recording and topic used), cached in ``cache`` (default: the user's cache
    folder) under a key of the training code and data, so that it is trained once."""
    import contextlib
    import io

    from laser_tracker.tools.bag import scan_topics
    from laser_tracker.tools.cli import main as cli_main
    from laser_tracker.tools.data import real_recording
    from laser_tracker.tools.import_bag import import_bag
    from laser_tracker.tools.train_detector import DEFAULT_NEGATIVE

    positives = [p for p in positive_recordings() if scene is None or p.name != scene.name]
    negative = real_recording(DEFAULT_NEGATIVE)
    folder = Path(cache) if cache else _cache_folder()
    folder.mkdir(parents=True, exist_ok=True)
    key = _training_key(positives + [negative], negative_topic)
    without = scene.stem if scene is not None else negative_topic.strip('/')
    out = folder / f'legs_without_{without}_{key}.npz'
    if out.exists():
        return out
    if negative_topic is not None:
        kept = [t for t in scan_topics(negative) if t != negative_topic]
        copy = folder / f'negative_without_{without}_{key}'
        if not copy.exists():
            import_bag(negative, copy, kept)
        negative = copy
    args = ['train-detector', *TRAINING_ARGS, '--output', str(out), '--negative', str(negative)]
    for p in positives:
        args += ['--positive', str(p)]
    log.info('training a person detector without %s (once): %s', without, out)
    with contextlib.redirect_stdout(io.StringIO()):
        cli_main(args)
    return out


def _cache_folder() -> Path:
    base = os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache'
    return Path(base) / 'laser_tracker' / 'held_out_models'


def _training_key(recordings: list[Path], without_topic: str | None = None) -> str:
    """A hash of what a trained model depends on: the training, feature and classifier code,
    the training arguments, the recordings (names and sizes) and a topic left out."""
    import laser_tracker.core.person_detector as detector
    import laser_tracker.core.segmentation as segmentation
    import laser_tracker.tools.train_detector as train

    h = hashlib.sha256()
    for module in (train, detector, segmentation):
        h.update(Path(module.__file__).read_bytes())
    h.update(repr(TRAINING_ARGS).encode())
    for p in recordings:
        h.update(f'{p.name}:{p.stat().st_size}'.encode())
    h.update(repr(without_topic).encode())
    return h.hexdigest()[:12]
