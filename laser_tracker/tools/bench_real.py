"""``laser-tracker bench real``: the tracker on the public real recordings, scored.

Replays each real recording found under ``$LASER_TRACKER_DATA`` (README.md, "Data") in three
modes: ``paper`` (``config/paper_reference.yaml``, the paper's method alone), ``motion`` (the
defaults without the person detector: what moves only) and ``defaults``; scores each replay
with ``laser-tracker evaluate`` and prints one table (``--markdown`` for README.md,
``--json`` for programs):

* ``person_following``: leg_tracker's annotated person-following recording (no odometry):
  following-mode counts as the leg_tracker benchmarks count them, CLEAR MOT over every
  annotated person and over the walking ones;
* ``freiburg_realistic`` / ``freiburg_poor``: freiburg-079 part 1, imported with its
  SLAM-corrected poses as the reference and a noisy copy as odometry (two noise models):
  false tracks per minute on static structure; ``freiburg_other_noise``: the same with three
  other draws of each noise model, six replays in one row (the defaults must not depend on
  one draw);
* ``mit_csail``: the raw mit-csail log with its own odometry: false tracks per minute on
  static structure mapped with the replay's poses;
* ``intel`` / ``aces``: the subsampled corrected logs of two other buildings (180 beams,
  1 deg apart), replayed at one scan a second (``SUBSAMPLED_PERIOD``) with realistic
  odometry noise: false tracks per minute on static structure;
* ``leg_demo``: leg_tracker's stationary demo (people walking and standing, no labels):
  confirmed tracks per minute, by kind;
* ``negative_2_left`` / ``_right`` / ``_rear``: leg_tracker's ``negative_2.bag``, one row per
  scanner: a robot driving 38 m with nobody in view, so every confirmed track is false; and
  ``..._inf``: the same scans with their no-return readings (0 and codes below ``range_min``)
  written as +inf, as REP 117 drivers write them; ``..._unseen``: the recorded scans with a
  person detector trained without that scanner (the shipped one was trained on all three:
  clutter it has not seen);
* ``leg_scenes`` (and ``leg_scenes_inf``, no-return readings as +inf): leg_tracker's six
  leg-labelled training recordings replayed as scenes (``tools.leg_scenes``): CLEAR MOT over
  the people of the labelled legs, pooled over the six, each replayed with a person detector
  trained without it (the shipped model was trained on all six);
* ``negative_2_inf_half_beams`` / ``_half_rate`` and ``leg_scenes_inf_half_beams`` /
  ``_half_rate``: the same (no-return readings as +inf) as two other scanners would have
  recorded them, every second beam (0.7 deg apart) or every second scan (3.75 Hz); the three
  scanners of ``negative_2`` in one row; ``person_following_half_beams`` / ``_half_rate``
  likewise (0.7 deg, 5 Hz), each annotation kept with its scan. What a default that counts
  beams or scans depends on;
* ``negative_2_inf_odometry``: the same three scanners (no-return readings as +inf) with
  wheel odometry on /tf and the scanner's mount on /tf_static, as a robot with odometry
  records them (the odometry: the scanner poses of a replay on scan matching alone, moved to
  a base the scanner sits on, with six draws of realistic noise: eighteen replays in one
  row); the odometry path and the mount, on real scans;
* ``leg_scenes_driving_inf``: the people of each positive recording put into the scans of
  one scanner of ``negative_2`` (``tools.driving_scenes``): real legs around a robot that
  drives through a real building, scored as the leg scenes, pooled over the six;
  ``leg_scenes_driving_inf_odometry``: the same scenes with wheel odometry and the mount on
  /tf (as ``negative_2_inf_odometry``; three draws, pooled).
* ``negative_2_inf_fast`` and ``leg_scenes_driving_inf_fast``: the same drive twice as fast
  (every second scan at the recorded rate), with nobody in view and among the people of the
  driving scenes.
* ``..._reversed``: ``person_following``, Freiburg (both noise models, four draws each), MIT,
  ``negative_2_inf`` and the people of the leg and driving scenes played backwards
  (``tools.reverse``): the robot drives in reverse with its scanners looking where it came
  from, people walk the other way; what of the defaults depends on the direction of time.

What is not present is reported as missing, never failed. It takes a few minutes
(``--jobs 2`` on a free 2-core machine halves it).
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import logging
import math
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from laser_tracker import parameters
from laser_tracker.tools.atomic import check_output
from laser_tracker.tools.data import real_recording

REPO = Path(__file__).resolve().parents[2]
MODES = ('paper', 'motion', 'defaults')
NEGATIVE_SCANNERS = ('left', 'right', 'rear')
#: Their scan topics in negative_2.bag.
NEGATIVE_TOPICS = tuple(f'/{s}_scan' for s in NEGATIVE_SCANNERS)
RECORDINGS = ('person_following', 'freiburg_realistic', 'freiburg_poor',
              'freiburg_other_noise', 'mit_csail', 'intel', 'aces', 'leg_demo') + tuple(
    f'negative_2_{s}{e}' for e in ('', '_inf') for s in NEGATIVE_SCANNERS) + tuple(
    f'negative_2_{s}_unseen' for s in NEGATIVE_SCANNERS) + ('leg_scenes', 'leg_scenes_inf')
#: Other scanners made of the recordings of one: name, keep every so many beams, keep every
#: so many scans. The leg_tracker robot's scanners (768 beams over 270 deg at 7.5 Hz; their
#: no-return readings as +inf) as one with half the beams (0.7 deg apart) and one at half
#: the rate (3.75 Hz), and the person-following robot's (245 beams 0.35 deg apart, 10 Hz)
#: at 0.7 deg and 5 Hz: what a default that counts scans or beams depends on.
OTHER_SCANNERS = (('half_beams', 2, 1), ('half_rate', 1, 2))
RECORDINGS += tuple(f'{base}_{name}' for base in ('negative_2_inf', 'leg_scenes_inf',
                                                 'person_following')
                    for name, _, _ in OTHER_SCANNERS) + (
    'negative_2_inf_odometry', 'leg_scenes_driving_inf', 'leg_scenes_driving_inf_odometry')
#: ``..._fast``: the robot of ``negative_2`` driving this many times faster (every so many
#: scans of its drive, at the recorded rate: 1.4 m/s and 0.55 rad/s median instead of 0.7 and
#: 0.28), with nobody in view and among the people of the driving scenes.
FASTER = 2
RECORDINGS += ('negative_2_inf_fast', 'leg_scenes_driving_inf_fast')
#: The subsampled corrected logs (Radish's intel and aces keep a scan every 0.6 to 1 m of the
#: drive, 3 s apart): replayed with their scans this many seconds apart, the corrected poses
#: with the Freiburg rows' realistic odometry noise (seed 0).
SUBSAMPLED_LOGS = {'intel': 'carmen/intel-corrected.log.gz',
                   'aces': 'carmen/aces-corrected.log.gz'}
SUBSAMPLED_PERIOD = 1.0
#: Recordings also replayed backwards (``tools.reverse``): ``<name>_reversed``.
REVERSED = ('person_following', 'freiburg', 'mit_csail', 'negative_2_inf', 'leg_scenes_inf',
            'leg_scenes_driving_inf')
RECORDINGS += tuple(f'{base}_reversed' for base in REVERSED)
#: ``negative_2_inf_odometry``: where each scanner is taken to sit on the base (x, y, yaw),
#: as on a robot with two front corner scanners turned outwards and one facing back, and the
#: rate (Hz), noise model and draws (one replay each) of the wheel odometry made for it.
ODOMETRY_MOUNTS = {'left': (0.25, 0.2, math.pi / 4), 'right': (0.25, -0.2, -math.pi / 4),
                   'rear': (-0.25, 0.0, math.pi)}
ODOMETRY_RATE, ODOMETRY_NOISE, ODOMETRY_SEEDS = 20.0, 'realistic', (0, 1, 2, 3, 4, 5)
#: The draws of ``leg_scenes_driving_inf_odometry`` (each its six scenes, pooled).
SCENE_ODOMETRY_SEEDS = (0, 1, 2)
#: The odometry noise models of the Freiburg rows, and the seeds of ``freiburg_other_noise``
#: (the single rows draw seed 0).
FREIBURG_NOISE = ('realistic', 'poor')
OTHER_NOISE_SEEDS = (1, 2, 3)
#: The counts of CLEAR MOT that pool over the parts of a recording made of several scenes.
POOLED = ('objects', 'misses', 'fp', 'switches', 'walking_objects', 'walking_misses',
          'walking_fp', 'walking_switches', 'confirmed', 'scans', 'outside_area')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--only', nargs='+', metavar='NAME',
                        help=' '.join(RECORDINGS) + ' (default: all)')
    parser.add_argument('--modes', nargs='+', default=list(MODES), choices=list(MODES),
                        help='configurations to run (default: all three)')
    parser.add_argument('--config', metavar='YAML', action='append', default=[],
                        help='a parameter file to run as well (mode "custom"; repeatable, '
                        'later files win)')
    parser.add_argument('--json', metavar='OUT', help='write the figures as JSON')
    parser.add_argument('--markdown', action='store_true',
                        help='print the table as Markdown (as in README.md)')
    parser.add_argument('--keep', metavar='DIR', help='keep the replays here')
    parser.add_argument('--jobs', type=int, default=1, help='replays run in parallel')


def mode_parameters(mode: str, files=(), overrides=None):
    """Loaded node parameters of a mode, with ``overrides``: ``paper`` the paper's file,
    ``motion`` the defaults without the person detector, ``defaults``, ``custom`` the given
    files (only ``custom`` reads them)."""
    overrides = dict(overrides or {})
    if mode == 'paper':
        files = [REPO / 'config' / 'paper_reference.yaml']
    elif mode != 'custom':
        files = []
    if mode == 'motion':
        overrides['person_detector.enabled'] = False
    return parameters.load(parameters.read_files(files), overrides=overrides)


def rewrite_scans(src: Path, dst: Path, scan_topics, beam_step: int = 1,
                  scan_step: int = 1, as_inf: bool = True, attached=(),
                  faster: bool = False) -> None:
    """A rosbag2 copy of ``scan_topics`` of ``src`` whose no-return readings (0 and codes below
    ``range_min``; -inf stays) read +inf, as a driver following REP 117 writes them (unless
    ``as_inf`` is false); with ``beam_step`` / ``scan_step``, only every so many beams of
    every so many scans of each topic: the recording as a scanner with fewer beams or a lower
    rate would have made it; ``faster``: the scans kept stamped ``scan_step`` times closer
    in time (from the first), so that they come at the recorded rate: the robot drove
    ``scan_step`` times faster. The messages of ``attached`` topics (annotations, which
    belong to the scan before them) are copied after the scans kept, not after those left
    out."""
    from laser_tracker.conversions import scan_from_msg, scan_to_msg
    from laser_tracker.tools.bag import FACTORY, BagWriter, iter_messages

    seen: dict[str, int] = {}
    kept = False
    start = None
    rate = scan_step if faster else 1
    with BagWriter(dst) as bag:
        for topic, t_ns, msg in iter_messages(src, [*scan_topics, *attached]):
            start = int(t_ns) if start is None else start
            t_ns = start + (int(t_ns) - start) // rate
            if topic in attached:
                if kept:
                    bag.write(topic, msg, t_ns)
                continue
            seen[topic] = seen.get(topic, -1) + 1
            kept = not seen[topic] % scan_step
            if not kept:
                continue
            scan = scan_from_msg(msg)
            if as_inf:
                scan = scan.with_no_returns_as_inf()
            if beam_step > 1:
                scan = scan.every_nth_beam(beam_step)
            if rate > 1:
                first = start * 1e-9
                scan = dataclasses.replace(scan, stamp=first + (scan.stamp - first) / rate,
                                           stamp_ns=None)
            bag.write(topic, scan_to_msg(FACTORY, scan), t_ns)


def _recordings(work: Path) -> dict:
    """name -> (bag, scan topic, scoring) for what is available (importing logs)."""
    found = {}
    pf = real_recording('leg_tracker/person_following_outdoor_1.bag')
    if pf.exists():
        found['person_following'] = (pf, '/scan_base2', 'annotated')
    freiburg = real_recording('carmen/freiburg-079-part1-corrected.log.gz')
    if freiburg.exists():
        for noise in FREIBURG_NOISE:
            found[f'freiburg_{noise}'] = (_freiburg(work, freiburg, noise, 0), '/scan',
                                          'reference')
    mit = real_recording('carmen/mit-csail.clf')
    if mit.exists():
        found['mit_csail'] = (_mit(work, mit), '/scan', 'ego')
    for name, relative in SUBSAMPLED_LOGS.items():
        log = real_recording(relative)
        if log.exists():
            found[name] = (_subsampled(work, log, name), '/scan', 'reference')
    demo = real_recording('leg_tracker/demo_stationary_simple_environment.bag')
    if demo.exists():
        found['leg_demo'] = (demo, '/scan', 'unlabelled')
    negative = real_recording('leg_tracker/training/negative_2.bag')
    if negative.exists():
        inf = _negative_inf(work, negative)
        for s, topic in zip(NEGATIVE_SCANNERS, NEGATIVE_TOPICS):
            found[f'negative_2_{s}'] = (negative, topic, 'negative')
            found[f'negative_2_{s}_inf'] = (inf, topic, 'negative')
    return found


def _negative_inf(work: Path, negative: Path) -> Path:
    """``negative_2``'s three scanners with their no-return readings as +inf (written once)."""
    inf = work / 'negative_2_inf'
    if not inf.exists():
        rewrite_scans(negative, inf, NEGATIVE_TOPICS)
    return inf


def _negative_fast(work: Path, negative: Path) -> Path:
    """``negative_2_inf`` driven ``FASTER`` times faster (written once)."""
    fast = work / 'negative_2_inf_fast'
    if not fast.exists():
        rewrite_scans(negative, fast, NEGATIVE_TOPICS, scan_step=FASTER, faster=True)
    return fast


def _mit(work: Path, log: Path) -> Path:
    """The MIT CSAIL log imported (once), with its own odometry."""
    from laser_tracker.tools.import_carmen import convert

    out = work / 'mit_csail'
    if not out.exists():
        convert(log, out)
    return out


def _subsampled(work: Path, log: Path, name: str) -> Path:
    """A subsampled corrected log imported (once) at ``SUBSAMPLED_PERIOD``."""
    from laser_tracker.tools.import_carmen import convert

    out = work / name
    if not out.exists():
        convert(log, out, odometry_noise_model='realistic', scan_period=SUBSAMPLED_PERIOD)
    return out


def _freiburg(work: Path, log: Path, noise: str, seed: int) -> Path:
    """Freiburg part 1 imported (once) with odometry of ``noise`` drawn with ``seed``."""
    from laser_tracker.tools.import_carmen import convert

    out = work / (f'freiburg_{noise}' if seed == 0 else f'freiburg_{noise}_seed{seed}')
    if not out.exists():
        convert(log, out, odometry_noise_model=noise, seed=seed)
    return out


def _other_noise(work: Path, names) -> dict:
    """``freiburg_other_noise`` -> [its replays]: each noise model with each of
    ``OTHER_NOISE_SEEDS``."""
    log = real_recording('carmen/freiburg-079-part1-corrected.log.gz')
    if 'freiburg_other_noise' not in names or not log.exists():
        return {}
    return {'freiburg_other_noise': [_freiburg(work, log, noise, seed)
                                     for noise in FREIBURG_NOISE
                                     for seed in OTHER_NOISE_SEEDS]}


def _unseen_negatives(names, with_detector: bool) -> dict:
    """name -> (negative_2, scanner topic, extras: a detector trained without that scanner)
    for the ``negative_2_*_unseen`` rows asked for."""
    from laser_tracker.tools import leg_scenes

    negative = real_recording('leg_tracker/training/negative_2.bag')
    found = {}
    for s in NEGATIVE_SCANNERS:
        name = f'negative_2_{s}_unseen'
        if name in names and negative.exists() and leg_scenes.positive_recordings():
            extra = {'model': str(leg_scenes.held_out_model(negative_topic=f'/{s}_scan'))} \
                if with_detector else {}
            found[name] = (negative, f'/{s}_scan', extra)
    return found


def _scene_parts(work: Path, suffix: str, write, with_detector: bool) -> list:
    """[(scene bag, scoring extras)] of the positive recordings, each written once by
    ``write(k, recording, scene)`` (which returns the scene's counts) into ``work`` under the
    recording's name and ``suffix``; with the detector trained without that recording (once,
    cached) when ``with_detector``."""
    from laser_tracker.tools import leg_scenes

    parts = []
    for k, src in enumerate(leg_scenes.positive_recordings()):
        scene = work / f'{src.stem}{suffix}'
        info_file = scene.with_suffix('.json')
        if not scene.exists():
            info_file.write_text(json.dumps(write(k, src, scene)))
        extra = json.loads(info_file.read_text())
        if with_detector:
            extra['model'] = str(leg_scenes.held_out_model(src))
        parts.append((scene, extra))
    return parts


def _leg_scenes(work: Path, names, with_detector: bool) -> dict:
    """name -> [(scene bag, scoring extras)] for the leg-labelled scenes asked for (also as
    the ``OTHER_SCANNERS``)."""
    from laser_tracker.tools import leg_scenes

    if not leg_scenes.positive_recordings():
        return {}
    variants = [('leg_scenes', False, '', 1, 1), ('leg_scenes_inf', True, '_inf', 1, 1)] + [
        (f'leg_scenes_inf_{v}', True, f'_inf_{v}', beams, scans)
        for v, beams, scans in OTHER_SCANNERS]
    found = {}
    for name, inf, suffix, beam_step, scan_step in variants:
        if name in names:
            write = functools.partial(_write_scene, inf=inf, beam_step=beam_step,
                                      scan_step=scan_step)
            found[name] = _scene_parts(work, suffix, write, with_detector)
    return found


def _write_scene(k: int, src: Path, scene: Path, **variant) -> dict:
    """The leg scene of the ``k``-th positive recording ``src``, written to ``scene``."""
    from laser_tracker.tools import leg_scenes

    return leg_scenes.write_scene(src, scene, variant.pop('inf'), **variant)


def _driving_scenes(work: Path, names, with_detector: bool) -> dict:
    """``leg_scenes_driving_inf`` -> [(scene bag, scoring extras)]: the people of each
    positive recording in the scans of one scanner of ``negative_2`` (in turn: left, right,
    rear; ``tools.driving_scenes``); ``leg_scenes_driving_inf_odometry``: the same scenes
    with wheel odometry and the mount on /tf, as ``negative_2_inf_odometry``;
    ``leg_scenes_driving_inf_fast``: the people in the scans of the robot driving
    ``FASTER`` times faster."""
    from laser_tracker.tools import driving_scenes, leg_scenes

    negative = real_recording('leg_tracker/training/negative_2.bag')
    if not {'leg_scenes_driving_inf', 'leg_scenes_driving_inf_odometry',
            'leg_scenes_driving_inf_fast'} & set(names) \
            or not negative.exists() or not leg_scenes.positive_recordings():
        return {}

    def write(k, src, scene, drive=negative):
        topic = NEGATIVE_TOPICS[k % len(NEGATIVE_TOPICS)]
        return driving_scenes.write_driving_scene(src, drive, topic, scene)

    def with_odometry(k, src, scene, seed):
        plain, _ = parts[k]
        s = NEGATIVE_SCANNERS[k % len(NEGATIVE_SCANNERS)]
        write_with_wheel_odometry(plain, '/scan', scene, ODOMETRY_MOUNTS[s],
                                  plain.with_name(plain.name + '_icp'), seed)
        return json.loads(plain.with_suffix('.json').read_text())

    parts = _scene_parts(work, '_driving_inf', write, with_detector)
    found = {'leg_scenes_driving_inf': parts} if 'leg_scenes_driving_inf' in names else {}
    if 'leg_scenes_driving_inf_odometry' in names:
        found['leg_scenes_driving_inf_odometry'] = [
            part for seed in SCENE_ODOMETRY_SEEDS for part in _scene_parts(
                work, f'_driving_inf_odometry_seed{seed}',
                functools.partial(with_odometry, seed=seed), with_detector)]
    if 'leg_scenes_driving_inf_fast' in names:
        found['leg_scenes_driving_inf_fast'] = _scene_parts(
            work, '_driving_inf_fast',
            functools.partial(write, drive=_negative_fast(work, negative)), with_detector)
    return found


def _reversed(work: Path, names, with_detector: bool) -> dict:
    """name -> [(bag, scan topic, scoring, extras)] for the ``_reversed`` rows asked for:
    each recording played backwards (``tools.reverse``), written once: the followed person
    of ``person_following`` (its annotations after their scan), Freiburg with both
    noise models and the draws of ``freiburg_other_noise`` too (eight replays), MIT, the
    three scanners of ``negative_2_inf``, and the people of the leg-labelled scenes and of
    the driving scenes, each scene's annotations after their scan."""
    from laser_tracker.tools.annotations import (ANNOTATION_TOPIC, HIDDEN_TOPIC,
                                                 register_person_type)
    from laser_tracker.tools.bag import TYPESTORE, topics
    from laser_tracker.tools.reverse import write_reversed

    def backwards(bag: Path, attached=()) -> Path:
        out = work / f'{bag.name}_reversed'
        if not out.exists():
            write_reversed(bag, out, attached)
        return out

    wanted = {f'{base}_reversed' for base in REVERSED} & set(names)
    found: dict = {}
    register_person_type(TYPESTORE)
    pf = real_recording('leg_tracker/person_following_outdoor_1.bag')
    if 'person_following_reversed' in wanted and pf.exists():
        found['person_following_reversed'] = [
            (backwards(pf, (ANNOTATION_TOPIC,)), '/scan_base2', 'annotated', None)]
    log = real_recording('carmen/freiburg-079-part1-corrected.log.gz')
    if 'freiburg_reversed' in wanted and log.exists():
        found['freiburg_reversed'] = [
            (backwards(_freiburg(work, log, noise, seed)), '/scan', 'reference', None)
            for noise in FREIBURG_NOISE for seed in (0,) + OTHER_NOISE_SEEDS]
    mit = real_recording('carmen/mit-csail.clf')
    if 'mit_csail_reversed' in wanted and mit.exists():
        found['mit_csail_reversed'] = [(backwards(_mit(work, mit)), '/scan', 'ego', None)]
    negative = real_recording('leg_tracker/training/negative_2.bag')
    if 'negative_2_inf_reversed' in wanted and negative.exists():
        bag = backwards(_negative_inf(work, negative))
        found['negative_2_inf_reversed'] = [(bag, t, 'negative', None) for t in NEGATIVE_TOPICS]
    scenes = _leg_scenes(work, ['leg_scenes_inf'] * ('leg_scenes_inf_reversed' in wanted),
                         with_detector)
    scenes.update(_driving_scenes(
        work, ['leg_scenes_driving_inf'] * ('leg_scenes_driving_inf_reversed' in wanted),
        with_detector))
    for name, parts in scenes.items():
        found[f'{name}_reversed'] = [
            (backwards(bag, [t for t in (ANNOTATION_TOPIC, HIDDEN_TOPIC) if t in topics(bag)]),
             '/scan', 'scene', extra) for bag, extra in parts]
    return found


def _other_scanners(work: Path, names) -> dict:
    """name -> [(bag, scan topic, scoring)] for the ``negative_2_inf`` and
    ``person_following`` rows of the ``OTHER_SCANNERS`` asked for, and for
    ``negative_2_inf_fast``: the three scanners of ``negative_2``, pooled in one row; the
    followed person's annotations after the scans kept."""
    from laser_tracker.tools.annotations import ANNOTATION_TOPIC, register_person_type
    from laser_tracker.tools.bag import TYPESTORE

    negative = real_recording('leg_tracker/training/negative_2.bag')
    following = real_recording('leg_tracker/person_following_outdoor_1.bag')
    found = {}
    for v, beam_step, scan_step in OTHER_SCANNERS:
        name = f'person_following_{v}'
        if name in names and following.exists():
            register_person_type(TYPESTORE)
            bag = work / name
            if not bag.exists():
                rewrite_scans(following, bag, ['/scan_base2'], beam_step, scan_step,
                              as_inf=False, attached=(ANNOTATION_TOPIC,))
            found[name] = [(bag, '/scan_base2', 'annotated')]
    for v, beam_step, scan_step in OTHER_SCANNERS:
        name = f'negative_2_inf_{v}'
        if name in names and negative.exists():
            bag = work / name
            if not bag.exists():
                rewrite_scans(negative, bag, NEGATIVE_TOPICS, beam_step, scan_step)
            found[name] = [(bag, t, 'negative') for t in NEGATIVE_TOPICS]
    if 'negative_2_inf_fast' in names and negative.exists():
        found['negative_2_inf_fast'] = [(_negative_fast(work, negative), t, 'negative')
                                        for t in NEGATIVE_TOPICS]
    return found


def _with_odometry(work: Path, names) -> dict:
    """``negative_2_inf_odometry`` -> [(bag, scan topic)]: each scanner of ``negative_2``
    (no-return readings as +inf) as a robot with wheel odometry records it: the scanner
    poses of a replay on scan matching alone, as the poses of a base it sits on at
    ``ODOMETRY_MOUNTS``, with ``ODOMETRY_NOISE`` odometry noise at ``ODOMETRY_RATE`` on /tf
    (odom -> base_link, one recording per draw of ``ODOMETRY_SEEDS``) and the mount on
    /tf_static."""
    name = 'negative_2_inf_odometry'
    negative = real_recording('leg_tracker/training/negative_2.bag')
    if name not in names or not negative.exists():
        return {}
    inf = _negative_inf(work, negative)
    parts = []
    for s, topic in zip(NEGATIVE_SCANNERS, NEGATIVE_TOPICS):
        for seed in ODOMETRY_SEEDS:
            bag = work / f'{name}_{s}_seed{seed}'
            if not bag.exists():
                write_with_wheel_odometry(inf, topic, bag, ODOMETRY_MOUNTS[s],
                                          work / f'{name}_{s}_icp', seed)
            parts.append((bag, '/scan'))
    return {name: parts}


def write_with_wheel_odometry(src: Path, topic: str, dst: Path, mount, reference: Path,
                              seed: int = 0) -> None:
    """``src``'s scans on ``topic`` as ``/scan`` in ``dst`` (with its topics that are not
    scans, odometry or transforms: annotations), and wheel odometry on /tf made from the
    scanner poses a replay on scan matching alone finds (kept in ``reference``): the base
    the scanner sits on at ``mount`` follows them, and its odometry (``ODOMETRY_NOISE``,
    drawn with ``seed``) is sampled at ``ODOMETRY_RATE``, received 5 ms after its stamp; the
    mount is on /tf_static."""
    from laser_tracker.conversions import PlanarTransform, transforms_to_msg
    from laser_tracker.core.geometry import compose, inverse
    from laser_tracker.tools.annotations import register_person_type
    from laser_tracker.tools.bag import (FACTORY, LATCHED_QOS, ODOMETRY_MSGTYPE,
                                         SCAN_MSGTYPE, TYPESTORE, BagWriter, iter_messages,
                                         topics)
    from laser_tracker.tools.mount import TF_TYPES
    from laser_tracker.tools.odometry_noise import noisy_odometry
    from laser_tracker.tools.replay import replay_bag

    if not (reference / 'ego_motion.csv').exists():
        replay_bag(src, config=mode_parameters('defaults'), out_dir=reference,
                   scan_topic=topic, progress=False)
    poses = np.loadtxt(reference / 'ego_motion.csv', delimiter=',', skiprows=1, ndmin=2)
    poses = poses[np.isfinite(poses).all(axis=1)]
    stamps = np.arange(poses[0, 0], poses[-1, 0], 1.0 / ODOMETRY_RATE)
    heading = np.unwrap(poses[:, 3])
    scanner = np.column_stack([np.interp(stamps, poses[:, 0], v)
                               for v in (poses[:, 1], poses[:, 2], heading)])
    to_base = inverse(np.asarray(mount, float))
    odometry = noisy_odometry(np.array([compose(p, to_base) for p in scanner]),
                              ODOMETRY_NOISE, seed)
    register_person_type(TYPESTORE)
    replaced = (SCAN_MSGTYPE, ODOMETRY_MSGTYPE) + TF_TYPES
    kept = [topic] + [t for t, (kind, _) in topics(src).items() if kind not in replaced]
    messages = list(iter_messages(src, kept))
    frame = next(str(msg.header.frame_id) for t, _, msg in messages if t == topic)
    events = [(t_ns, '/scan' if t == topic else t, msg) for t, t_ns, msg in messages] + [
        (int(round((t + 0.005) * 1e9)), '/tf', transforms_to_msg(
            FACTORY, [PlanarTransform(float(t), 'odom', 'base_link', *pose)]))
        for t, pose in zip(stamps, odometry)]
    events.sort(key=lambda e: e[0])
    with BagWriter(dst) as bag:
        bag.write('/tf_static', transforms_to_msg(
            FACTORY, [PlanarTransform(0.0, 'base_link', frame, *mount)]), events[0][0] - 1,
            qos=LATCHED_QOS)
        for t_ns, name, msg in events:
            bag.write(name, msg, t_ns)


def score(name: str, bag: Path, scan_topic: str, scoring: str, config, out: Path,
          extra: dict | None = None) -> dict:
    """Replay ``bag`` into ``out`` with ``config`` and score it; the figures of the table."""
    from laser_tracker.tools.evaluate import evaluate_recording, report_unlabelled
    from laser_tracker.tools.replay import replay_bag

    t0 = time.perf_counter()
    summary = replay_bag(bag, config=config, out_dir=out, scan_topic=scan_topic,
                         progress=False)
    row = {'scans': summary['scans'], 'confirmed': summary['confirmed_tracks'],
           'replay_s': round(time.perf_counter() - t0, 1)}
    if scoring == 'scene':
        ev = evaluate_recording(out, bag, scan_topic=scan_topic, area=extra['area']).result
        for key, part in (('', 'all'), ('walking_', 'walking')):
            m = ev['clear_mot'][part]
            row.update({f'{key}objects': m['num_objects'], f'{key}misses': m['num_misses'],
                        f'{key}fp': m['num_false_positives'],
                        f'{key}switches': m['num_switches']})
        row['outside_area'] = ev['tracks_outside_area']
        if ev['false_positives_on_hidden'] is not None:
            row['fp_hidden'] = ev['false_positives_on_hidden']
        return row
    if scoring == 'annotated':
        ev = evaluate_recording(out, bag, scan_topic=scan_topic).result
        f = ev['following_all_annotations']
        row.update(tracked=f['tracked'], annotated=f['objects'], switches=f['id_switches'],
                   misses=f['misses'],
                   mota_all=ev['clear_mot']['all']['mota'],
                   mota_walking=ev['clear_mot']['walking']['mota'],
                   fp=ev['clear_mot']['all']['num_false_positives'])
    elif scoring in ('reference', 'ego'):
        st = evaluate_recording(out, bag, static=scoring, scan_topic=scan_topic)
        s = st.result['static_structure']
        row.update(minutes=round(s['duration_s'] / 60, 2), false=s['false_tracks'],
                   false_per_minute=s['false_per_minute'],
                   confirmed_per_minute=s['confirmed_per_minute'])
    else:
        r = report_unlabelled(out).result
        row.update(minutes=round(r['duration_s'] / 60, 2),
                   confirmed_per_minute=r['confirmed_per_minute'])
        if scoring == 'negative':     # nobody in view: every confirmed track is false
            row.update(false=row['confirmed'],
                       false_per_minute=r['confirmed_per_minute'])
    row.update(_kinds(out / 'tracks.csv', out / 'ego_motion.csv'))
    return row


def _kinds(tracks: Path, ego: Path) -> dict:
    """Confirmed tracks by kind (person / object), how many were ever standing, and how many
    stayed within 1 m of the scanner while confirmed (the robot's own body)."""
    import csv
    poses = np.loadtxt(ego, delimiter=',', skiprows=1, ndmin=2)
    where = {round(float(s), 6): i for i, s in enumerate(poses[:, 0])} if poses.size else {}
    kind, standing, far = {}, set(), set()
    with open(tracks, newline='') as fh:
        for r in csv.DictReader(fh):
            if r['confirmed'] != '1':
                continue
            tid = r['track_id']
            kind[tid] = r.get('kind', 'object')
            if r.get('moving') == '0':
                standing.add(tid)
            i = where.get(round(float(r['stamp']), 6))
            if i is None or math.hypot(float(r['x']) - poses[i, 1],
                                       float(r['y']) - poses[i, 2]) > 1.0:
                far.add(tid)
    return {'person_tracks': sum(1 for k in kind.values() if k == 'person'),
            'object_tracks': sum(1 for k in kind.values() if k != 'person'),
            'ever_standing': len(standing), 'within_1m': len(set(kind) - far)}


def _run_one(job) -> tuple[str, str, dict]:
    name, mode, bag, topic, scoring, files, out, extra = job
    logging.basicConfig(level=logging.ERROR)
    overrides = {}
    if extra and 'model' in extra and mode != 'paper':
        overrides['person_detector.model'] = extra['model']
    return name, mode, score(name, bag, topic, scoring, mode_parameters(mode, files, overrides),
                             out, extra)


def pooled(parts: list[dict]) -> dict:
    """One row of the rows of a recording's parts: for scenes, counts added, CLEAR MOT's MOTA
    and the recall of the pooled counts; for scanners with nobody in view or replays scored
    on static structure, the false tracks added (and each part's), per minute of all of
    them."""
    if 'objects' not in parts[0]:
        row = {k: sum(p[k] for p in parts) for k in ('scans', 'confirmed', 'false')}
        row['replay_s'] = round(sum(p['replay_s'] for p in parts), 1)
        row['minutes'] = round(sum(p['minutes'] for p in parts), 2)
        row['false_per_minute'] = row['false'] / max(row['minutes'], 1e-9)
        row['false_by_part'] = [p['false'] for p in parts]
        return row
    row = {k: sum(p[k] for p in parts) for k in POOLED}
    if all('fp_hidden' in p for p in parts):
        row['fp_hidden'] = sum(p['fp_hidden'] for p in parts)
    row['replay_s'] = round(sum(p['replay_s'] for p in parts), 1)
    row['scenes'] = len(parts)
    for key in ('', 'walking_'):
        n = max(row[f'{key}objects'], 1)
        row[f'{key}mota'] = 1.0 - (row[f'{key}misses'] + row[f'{key}fp']
                                   + row[f'{key}switches']) / n
        row[f'{key}recall'] = 1.0 - row[f'{key}misses'] / n
    return row


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.ERROR)
    if args.json:
        check_output(args.json, overwrite=True)
    modes = list(args.modes) + (['custom'] if args.config else [])
    if args.config:
        mode_parameters('custom', args.config)      # a bad file fails before any work
    with tempfile.TemporaryDirectory(prefix='laser_tracker_bench_real_') as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        names = args.only or list(RECORDINGS)
        found = {n: [(bag, topic, scoring, None)]
                 for n, (bag, topic, scoring) in _recordings(work).items()}
        detector = any(m != 'paper' for m in modes)
        scenes = _leg_scenes(work, names, detector)
        scenes.update(_driving_scenes(work, names, detector))
        found.update({n: [(bag, '/scan', 'scene', extra) for bag, extra in parts]
                      for n, parts in scenes.items()})
        found.update({n: [(bag, topic, 'negative', extra)]
                      for n, (bag, topic, extra) in _unseen_negatives(names, detector).items()})
        found.update({n: [(bag, topic, scoring, None) for bag, topic, scoring in parts]
                      for n, parts in _other_scanners(work, names).items()})
        found.update({n: [(bag, topic, 'negative', None) for bag, topic in parts]
                      for n, parts in _with_odometry(work, names).items()})
        found.update({n: [(bag, '/scan', 'reference', None) for bag in parts]
                      for n, parts in _other_noise(work, names).items()})
        found.update(_reversed(work, names, detector))
        jobs = []
        for name in names:
            if name not in found:
                print(f'{name}: not found under $LASER_TRACKER_DATA (README.md, "Data")')
                continue
            for k, (bag, topic, scoring, extra) in enumerate(found[name]):
                part = f'_{k}' if len(found[name]) > 1 else ''
                jobs += [(name, mode, bag, topic, scoring, args.config,
                          work / f'{name}{part}_{mode}', extra) for mode in modes]
        results: dict = {}
        parts: dict = {}
        with ProcessPoolExecutor(args.jobs) if args.jobs > 1 else _Serial() as pool:
            for name, mode, row in pool.map(_run_one, jobs):
                if len(found[name]) > 1:
                    parts.setdefault((name, mode), []).append(row)
                    if len(parts[(name, mode)]) < len(found[name]):
                        continue
                    row = pooled(parts[(name, mode)])
                results.setdefault(name, {})[mode] = row
                _print_row(name, mode, row, args.markdown)
    if args.markdown:
        print(markdown_table(results, modes))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + '\n')
    return 0


class _Serial:
    """``map`` in this process (``--jobs 1``), as a context like ProcessPoolExecutor."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    @staticmethod
    def map(fn, items):
        return map(fn, items)


def _print_row(name: str, mode: str, row: dict, quiet: bool) -> None:
    if not quiet:
        print(f'{name:<24} {mode:<9} ' + ', '.join(f'{k} {_fmt(v)}' for k, v in row.items()),
              flush=True)


def headline(row: dict) -> str:
    """The one figure that judges a recording's row (README.md, "Real recordings")."""
    if 'scenes' in row:
        return (f"MOTA {row['mota']:.3f}, recall {row['recall']:.3f} "
                f"(walking {row['walking_recall']:.3f}), {row['fp']:,} false positives"
                + (f" ({row['fp_hidden']:,} on people out of sight)" if 'fp_hidden' in row
                   else '') + f", {row['switches']} switches")
    if 'tracked' in row:
        return (f"{row['tracked']:,} of {row['annotated']:,} "
                f"({100 * row['tracked'] / max(row['annotated'], 1):.1f} %), "
                f"{row['switches']} switches, MOTA {row['mota_all']:.3f}")
    if 'false_by_part' in row:
        return (f"{row['false']:,} false ({row['false_per_minute']:.2f}/min; "
                + ' / '.join(map(str, row['false_by_part'])) + ')')
    if 'false_per_minute' in row and 'false' in row:
        return f"{row['false']:,} false ({row['false_per_minute']:.2f}/min)"
    return f"{row['confirmed']} tracks ({row['confirmed_per_minute']:.2f}/min)"


def markdown_table(results: dict, modes) -> str:
    lines = ['| recording | ' + ' | '.join(modes) + ' |',
             '|---|' + '---|' * len(modes)]
    for name, rows in results.items():
        lines.append(f'| `{name}` | ' + ' | '.join(
            headline(rows[m]) if m in rows else '-' for m in modes) + ' |')
    return '\n'.join(lines)


def _fmt(v) -> str:
    return f'{v:.3f}' if isinstance(v, float) else str(v)
