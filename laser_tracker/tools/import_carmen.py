"""``laser-tracker import-carmen LOG OUT``: a CARMEN log (plain or gzip) to a rosbag2 recording.

Writes ``/scan`` (sensor_msgs/LaserScan, frame ``laser``) and ``/odom`` (nav_msgs/Odometry,
``odom`` -> ``base_link``), both stamped with the log's ipc time stamps.

* Beam geometry and the no-return value: see :mod:`laser_tracker.tools.carmen`. No-return
  readings are written as ``+inf`` (REP 117) and ``range_max`` is the log's maximum reading, so
  ``Scan.valid()`` and ``Scan.free_ranges()`` read them as "nothing seen up to range_max".
* Odometry: the ODOM lines when the log has any (velocities tv, rv from the line), else the
  odometry pose of each FLASER / ROBOTLASER1 line (no velocity). Messages are written in time
  order (ODOM lines that go back in time in the log are sorted; a warning says how many).
* The output appears only when complete (io.bag.BagWriter): a malformed or truncated log
  gives one error naming the file and line, exit status 2, and no output folder.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from laser_tracker.conversions import PlanarOdometry, odometry_to_msg, scan_to_msg
from laser_tracker.errors import InputFileError
from laser_tracker.tools.bag import FACTORY, ODOM_TOPIC, SCAN_TOPIC, BagWriter
from laser_tracker.tools.carmen import read_carmen

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('log', help='CARMEN log (.log, .clf, optionally .gz)')
    parser.add_argument('out', help='output rosbag2 folder (must not exist unless --overwrite)')
    parser.add_argument('--max-reading', type=float, default=None,
                        help='reading that means "no return" (default: detected, the log\'s '
                             'repeated maximum, e.g. 81.91)')
    parser.add_argument('--storage', choices=('sqlite3', 'mcap'), default='sqlite3')
    parser.add_argument('--overwrite', action='store_true', help='replace OUT if it exists')
    parser.add_argument('--frame', default='laser', help='frame_id of /scan (default laser)')


def convert(log_path, out, max_reading=None, storage='sqlite3', overwrite=False,
            frame_id='laser') -> dict:
    """Convert; returns counts ``{'scans': N, 'odometry': M, 'odometry_source': ...}``."""
    if Path(out).exists() and not overwrite:
        raise InputFileError(out, 'output already exists (use --overwrite or another name)')
    carmen = read_carmen(log_path, max_reading=max_reading)
    o_stamps, o_poses, o_vel, source = carmen.odometry()
    order = np.argsort(o_stamps, kind='stable')
    n_back = int(np.count_nonzero(np.diff(o_stamps) < 0))
    if n_back:
        log.warning('%s: %d odometry lines go back in time; written in time order',
                    log_path, n_back)
    s_order = np.argsort(carmen.stamps, kind='stable')
    n_back_scans = int(np.count_nonzero(np.diff(carmen.stamps) < 0))
    if n_back_scans:
        log.warning('%s: %d laser lines go back in time; written in time order', log_path,
                    n_back_scans)
    ranges = carmen.scan_ranges()
    # Merge both streams by time so the bag's receive times are monotonic.
    events = [(float(carmen.stamps[i]), 0, int(i)) for i in s_order]
    events += [(float(o_stamps[j]), 1, int(j)) for j in order]
    events.sort(key=lambda e: (e[0], e[1]))
    try:
        with BagWriter(out, storage=storage, overwrite=overwrite) as bag:
            for stamp, what, idx in events:
                if what == 0:
                    scan = carmen.scan(idx, frame_id=frame_id, ranges=ranges)
                    bag.write(SCAN_TOPIC, scan_to_msg(FACTORY, scan), stamp)
                else:
                    x, y, th = o_poses[idx]
                    odom = PlanarOdometry(stamp=stamp, x=float(x), y=float(y),
                                          theta=float(th), vx=float(o_vel[idx, 0]),
                                          omega=float(o_vel[idx, 1]))
                    bag.write(ODOM_TOPIC, odometry_to_msg(FACTORY, odom), stamp)
    except FileExistsError as exc:
        raise InputFileError(out, 'output already exists (use --overwrite or another name)') \
            from exc
    return {'scans': len(carmen), 'odometry': int(o_stamps.size), 'odometry_source': source,
            'beams': carmen.n_beams, 'range_max': carmen.range_max}


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    counts = convert(args.log, args.out, max_reading=args.max_reading, storage=args.storage,
                     overwrite=args.overwrite, frame_id=args.frame)
    print(f'{args.out}: {counts["scans"]} scans ({counts["beams"]} beams, no return = '
          f'{counts["range_max"]:g} m written as inf) on {SCAN_TOPIC}, {counts["odometry"]} '
          f'odometry messages from {counts["odometry_source"]} lines on {ODOM_TOPIC}')
    return 0
