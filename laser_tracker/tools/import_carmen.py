"""``laser-tracker import-carmen LOG OUT``: a CARMEN log (plain or gzip) to a rosbag2 recording.

Writes ``/scan`` (sensor_msgs/LaserScan, frame ``laser``) and ``/odom`` (nav_msgs/Odometry,
``odom`` -> ``base_link``), both stamped with the log's ipc time stamps, and ``/tf_static``
(the scanner at the platform's origin, ``base_link`` -> ``laser``: CARMEN's laser poses are
the robot's in these logs).

* Beam geometry and the no-return value: see :mod:`laser_tracker.tools.carmen`. No-return
  readings are written as ``+inf`` (REP 117) and ``range_max`` is the log's maximum reading, so
  ``Scan.valid()`` and ``Scan.free_ranges()`` read them as "nothing seen up to range_max".
* Messy time stamps (negative, not distinct, out of order; ODOM lines that disagree with the
  laser lines' odometry): repaired or dropped as :mod:`laser_tracker.tools.carmen` says, each
  kind reported once with its count; ``--strict`` refuses such a log instead.
* A raw log: odometry from the ODOM lines when the log has any (velocities tv, rv from the
  line), else the odometry pose of each FLASER / ROBOTLASER1 line (no velocity).
* A corrected log (``--corrected auto``: the log has NEFF lines, as the SLAM-corrected logs of
  Radish do, or its name says ``corrected``): its laser poses are the SLAM-corrected
  trajectory, not odometry. They are written as ``/ground_truth/platform`` (nav_msgs/Odometry,
  frame ``map``, child the scan frame: CARMEN's FLASER ``x y theta`` is the laser's pose), and
  ``/odom`` is a noisy copy of them, one sample per scan
  (``--odometry-noise {none,realistic,poor}``, default realistic, ``--seed``; the models of
  :mod:`laser_tracker.tools.odometry_noise`, the same as ``bench egomotion``); the log's own
  ODOM lines are not written. The scanner sits at the platform origin (mount 0), so the
  ego-motion needs no mounting parameters for it.
* Messages are written in time order (laser lines that go back in time in the log are sorted).
  ``--scan-period S`` stamps the scans ``S`` seconds apart in the log's order instead, from
  its first stamp: for a subsampled log (Radish's intel and aces keep every few seconds of
  the drive, and their stamps go back in places), replayed as a scanner of ``1 / S`` Hz.
  Its odometry must then come with the scans (a corrected log, or a raw log's FLASER poses).
* The output appears only when complete (io.bag.BagWriter): a malformed or truncated log
  gives one error naming the file and line, exit status 2, and no output folder.
"""
from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

import numpy as np

from laser_tracker.conversions import (PlanarOdometry, PlanarTransform, odometry_to_msg,
                                       scan_to_msg, transforms_to_msg)
from laser_tracker.errors import InputFileError, LaserTrackerError
from laser_tracker.tools import odometry_noise
from laser_tracker.tools.atomic import check_output
from laser_tracker.tools.bag import (FACTORY, LATCHED_QOS, ODOM_TOPIC, PLATFORM_TRUTH_TOPIC,
                                     SCAN_TOPIC, TF_STATIC_TOPIC, BagWriter)
from laser_tracker.tools.carmen import read_carmen

log = logging.getLogger(__name__)

DEFAULT_NOISE = 'realistic'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('log', help='CARMEN log (.log, .clf, optionally .gz)')
    parser.add_argument('out', help='output rosbag2 folder (must not exist unless --overwrite)')
    parser.add_argument('--max-reading', type=float, default=None,
                        help='reading that means "no return" (default: detected, the log\'s '
                             'repeated maximum, e.g. 81.91)')
    parser.add_argument('--storage', choices=('sqlite3', 'mcap'), default='sqlite3')
    parser.add_argument('--overwrite', action='store_true', help='replace OUT if it exists')
    parser.add_argument('--frame', default='laser', help='frame_id of /scan (default laser)')
    parser.add_argument('--strict', action='store_true',
                        help='refuse a log with negative, repeated or out-of-order time stamps '
                             '(default: repair or drop those lines and report each kind once)')
    parser.add_argument('--corrected', choices=('auto', 'yes', 'no'), default='auto',
                        help='the laser poses are a SLAM-corrected trajectory (auto: the log '
                             'has NEFF lines or its name says "corrected")')
    parser.add_argument('--odometry-noise', choices=odometry_noise.MODELS, default=None,
                        help='corrected logs: /odom is the corrected trajectory with this noise '
                             f'(default {DEFAULT_NOISE})')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the odometry noise (default 0)')
    parser.add_argument('--scan-period', type=float, default=None, metavar='S',
                        help='stamp the scans S seconds apart in the log\'s order (a '
                             'subsampled log; default: the log\'s own stamps)')


def is_corrected(carmen, log_path) -> bool:
    """A SLAM-corrected log: NEFF lines (the particle filter's effective sample size) or a
    name that says so."""
    return bool(carmen.skipped.get('NEFF')) or 'corrected' in Path(log_path).name.lower()


def convert(log_path, out, max_reading=None, storage='sqlite3', overwrite=False,
            frame_id='laser', strict=False, corrected='auto', odometry_noise_model=None,
            seed=0, scan_period=None) -> dict:
    """Convert; returns counts ``{'scans': N, 'odometry': M, 'odometry_source': ...}``."""
    check_output(out, overwrite)
    if scan_period is not None and not (math.isfinite(scan_period) and scan_period > 0):
        raise LaserTrackerError(f'--scan-period must be a positive number of seconds, not '
                                f'{scan_period}')
    carmen = read_carmen(log_path, max_reading=max_reading, strict=strict)
    reference = corrected == 'yes' or (corrected == 'auto' and is_corrected(carmen, log_path))
    if odometry_noise_model is not None and not reference:
        raise InputFileError(log_path, '--odometry-noise is for corrected logs (this one '
                             'carries raw odometry; use --corrected yes if it is corrected)')
    if scan_period is None:
        s_order = np.argsort(carmen.stamps, kind='stable')
        stamps = carmen.stamps[s_order]
    else:
        if not reference and carmen.odom_stamps.size:
            raise InputFileError(log_path, '--scan-period needs the odometry in the laser lines '
                                 '(this log has ODOM lines of their own time stamps)')
        s_order = np.arange(len(carmen))
        stamps = (carmen.stamps[0] if len(carmen) else 0.0) + scan_period * s_order
    truth = None
    if reference:
        noise = odometry_noise_model or DEFAULT_NOISE
        truth = carmen.laser_poses[s_order]
        o_stamps = stamps
        o_poses = odometry_noise.noisy_odometry(truth, noise, seed)
        o_vel = np.zeros((stamps.size, 2))
        source = f'the corrected poses with {noise} noise (seed {seed})'
    else:
        o_stamps, o_poses, o_vel, kind = carmen.odometry()
        if scan_period is not None:
            o_stamps = stamps
        source = f'{kind} lines'
    ranges = carmen.scan_ranges()
    # Merge the streams by time so the bag's receive times are monotonic.
    events = [(float(stamps[k]), 0, int(i)) for k, i in enumerate(s_order)]
    events += [(float(o_stamps[j]), 1, int(j)) for j in range(o_stamps.size)]
    if truth is not None:
        events += [(float(stamps[k]), 2, k) for k in range(stamps.size)]
    events.sort(key=lambda e: (e[0], e[1]))
    with BagWriter(out, storage=storage, overwrite=overwrite) as bag:
        mount = PlanarTransform(0.0, 'base_link', frame_id, 0.0, 0.0, 0.0)
        bag.write(TF_STATIC_TOPIC, transforms_to_msg(FACTORY, [mount]),
                  events[0][0] if events else 0.0, qos=LATCHED_QOS)
        for stamp, what, idx in events:
            if what == 0:
                scan = carmen.scan(idx, frame_id=frame_id, ranges=ranges, stamp=stamp)
                bag.write(SCAN_TOPIC, scan_to_msg(FACTORY, scan), stamp)
            elif what == 1:
                x, y, th = o_poses[idx]
                odom = PlanarOdometry(stamp=stamp, x=float(x), y=float(y),
                                      theta=float(th), vx=float(o_vel[idx, 0]),
                                      omega=float(o_vel[idx, 1]))
                bag.write(ODOM_TOPIC, odometry_to_msg(FACTORY, odom), stamp)
            else:
                x, y, th = truth[idx]
                pose = PlanarOdometry(stamp=stamp, x=float(x), y=float(y), theta=float(th),
                                      frame_id='map', child_frame_id=frame_id)
                bag.write(PLATFORM_TRUTH_TOPIC, odometry_to_msg(FACTORY, pose), stamp)
    return {'scans': len(carmen), 'odometry': int(o_stamps.size), 'odometry_source': source,
            'ground_truth': 0 if truth is None else int(truth.shape[0]),
            'beams': carmen.n_beams, 'range_max': carmen.range_max,
            'issues': dict(carmen.issues)}


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    counts = convert(args.log, args.out, max_reading=args.max_reading, storage=args.storage,
                     overwrite=args.overwrite, frame_id=args.frame, strict=args.strict,
                     corrected=args.corrected, odometry_noise_model=args.odometry_noise,
                     seed=args.seed, scan_period=args.scan_period)
    print(f'{args.out}: {counts["scans"]} scans ({counts["beams"]} beams, no return = '
          f'{counts["range_max"]:g} m written as inf) on {SCAN_TOPIC}, {counts["odometry"]} '
          f'odometry messages from {counts["odometry_source"]} on {ODOM_TOPIC}'
          + (f', {counts["ground_truth"]} corrected poses on {PLATFORM_TRUTH_TOPIC}'
             if counts['ground_truth'] else ''))
    return 0
