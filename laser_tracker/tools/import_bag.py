"""``laser-tracker import-bag IN OUT``: a ROS 1 bag (or a rosbag2) to a rosbag2 recording.

Keeps the sensor_msgs/LaserScan, nav_msgs/Odometry and tf2_msgs/TFMessage topics (``/tf``,
``/tf_static``: the scanner's mount on the platform, which ``replay`` reads) — all of them, or
``--topics`` — each message converted through ``laser_tracker.conversions`` (``scan_from_msg``
/ ``scan_to_msg``, ``odometry_from_msg`` / ``odometry_to_msg``, ``tf_message_to_msg``) into
Jazzy definitions, under the same topic names and with the original receive times;
``/tf_static`` keeps tf2's latched QoS. What the pipeline uses survives
exactly: ranges (float32), intensities (when one per beam), the scan geometry and timing,
frame names, the planar pose and velocity, the covariance diagonals, every transform; receive
times exactly, header stamps to within a microsecond (they pass through float seconds). A scan that cannot be used (say, ranges
that disagree with its angles) is skipped with a logged warning and counted.

Bad input (a missing, unreadable, truncated or malformed bag) ends with one error line naming
the file and the byte offset or message where it broke, a non-zero exit status, and no output.
"""
from __future__ import annotations

import argparse
import logging
import struct
from pathlib import Path

import numpy as np

from laser_tracker.conversions import (odometry_from_msg, odometry_to_msg, scan_from_msg,
                                       scan_to_msg, tf_message_to_msg)
from laser_tracker.core.scan import ScanError
from laser_tracker.errors import InputFileError, LaserTrackerError
from laser_tracker.tools.atomic import check_output
from laser_tracker.tools.bag import (FACTORY, LATCHED_QOS, TF_STATIC_TOPIC, BagWriter,
                                     iter_messages, topics)

log = logging.getLogger(__name__)

SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
ODOM_TYPE = 'nav_msgs/msg/Odometry'
TF_TYPE = 'tf2_msgs/msg/TFMessage'
SUPPORTED = (SCAN_TYPE, ODOM_TYPE, TF_TYPE)
ROS1_MAGIC = b'#ROSBAG V2.0\n'


class ImportBagError(LaserTrackerError):
    """An import that cannot run as asked (no such topic, output in the way)."""


def _ros1_header_fields(data: bytes) -> dict[bytes, bytes]:
    fields, pos = {}, 0
    while pos + 4 <= len(data):
        (flen,) = struct.unpack_from('<I', data, pos)
        pos += 4
        if flen > len(data) - pos:
            raise ValueError('header field runs past the header')
        name, _, value = data[pos:pos + flen].partition(b'=')
        fields[name] = value
        pos += flen
    return fields


def check_ros1_bag(path: Path) -> int | None:
    """For a ROS 1 bag, check the bag header record and that the index it points to lies in
    the file; return the index's byte offset (None for anything that is not a ROS 1 bag).

    Raises InputFileError naming the offset for a truncated, unindexed or malformed bag.
    """
    if not path.is_file():
        return None
    size = path.stat().st_size
    with path.open('rb') as fh:
        magic = fh.read(len(ROS1_MAGIC))
        if magic != ROS1_MAGIC:
            return None
        offset = fh.tell()
        raw = fh.read(4)
        if len(raw) < 4:
            raise InputFileError(path, f'truncated: the file ends at byte {size} inside the '
                                 'bag header record', f'byte offset {offset}')
        (hlen,) = struct.unpack('<I', raw)
        header = fh.read(hlen)
        if len(header) < hlen:
            raise InputFileError(path, f'truncated: the bag header record needs {hlen} bytes '
                                 f'but the file ends at byte {size}', f'byte offset {offset}')
    try:
        fields = _ros1_header_fields(header)
        op = fields.get(b'op', b'')
        (index_pos,) = struct.unpack('<Q', fields[b'index_pos'])
    except (KeyError, ValueError, struct.error):
        raise InputFileError(path, 'malformed bag header record (no valid index_pos)',
                             f'byte offset {offset}') from None
    if op != b'\x03':
        raise InputFileError(path, f'malformed: the first record has op {op!r}, not a bag '
                             'header (0x03)', f'byte offset {offset}')
    if index_pos == 0:
        raise InputFileError(path, 'the bag has no index (recording interrupted?); '
                             'run `rosbag reindex` on it first', f'byte offset {offset}')
    if index_pos >= size:
        raise InputFileError(path, f'truncated: the index should start at byte {index_pos} but '
                             f'the file has only {size} bytes', f'byte offset {size}')
    return index_pos


def import_bag(src: str | Path, dst: str | Path, topic_names=None, storage: str = 'sqlite3',
               overwrite: bool = False) -> dict[str, int]:
    """Convert ``src`` into the rosbag2 folder ``dst``; return ``{topic: messages written}``
    (and ``'skipped'``: unusable scans left out)."""
    src, dst = Path(src), Path(dst)
    check_output(dst, overwrite)
    index_pos = check_ros1_bag(src)
    try:
        info = topics(src)
    except InputFileError as exc:
        if index_pos is None:
            raise
        raise InputFileError(src, exc.reason, f'index at byte offset {index_pos}') from None
    available = {t: typ for t, (typ, _) in info.items() if typ in SUPPORTED}
    if topic_names:
        for t in topic_names:
            if t not in info:
                raise ImportBagError(f'{src}: no topic {t!r}; it has: {", ".join(sorted(info))}')
            if t not in available:
                raise ImportBagError(f'{src}: topic {t!r} is {info[t][0]}; only LaserScan, '
                                     'Odometry and TFMessage topics can be imported')
        selected = list(dict.fromkeys(topic_names))
    else:
        selected = sorted(available)
    if not selected:
        has = ', '.join(f'{t} ({typ})' for t, (typ, _) in sorted(info.items())) or 'nothing'
        raise ImportBagError(f'{src}: no LaserScan, Odometry or TFMessage topic (it has: '
                             f'{has})')
    counts = {t: 0 for t in selected}
    counts['skipped'] = 0
    with BagWriter(dst, storage=storage, overwrite=overwrite) as bag:
        for topic, t_ns, msg in iter_messages(src, selected):
            if available[topic] == SCAN_TYPE:
                try:
                    scan = scan_from_msg(msg)
                except ScanError as exc:
                    counts['skipped'] += 1
                    log.warning('%s: %s at t=%d ns: skipped scan: %s', src, topic, t_ns, exc)
                    continue
                intensities = np.asarray(msg.intensities, dtype=np.float32)
                out = scan_to_msg(FACTORY, scan, intensities
                                  if intensities.size == scan.n_beams else None)
            elif available[topic] == TF_TYPE:
                out = tf_message_to_msg(FACTORY, msg)
            else:
                odo = odometry_from_msg(msg)
                out = odometry_to_msg(FACTORY, odo,
                                      np.asarray(msg.pose.covariance, dtype=float)[::7],
                                      np.asarray(msg.twist.covariance, dtype=float)[::7])
            bag.write(topic, out, int(t_ns),
                      qos=LATCHED_QOS if topic == TF_STATIC_TOPIC else ())
            counts[topic] += 1
    return counts


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('input', metavar='IN', help='a ROS 1 .bag file or a rosbag2 folder')
    parser.add_argument('out', metavar='OUT', help='the rosbag2 folder to write')
    parser.add_argument('--topics', nargs='+', metavar='TOPIC',
                        help='topics to keep (default: every LaserScan, Odometry and '
                             'TFMessage topic)')
    parser.add_argument('--storage', choices=('sqlite3', 'mcap'), default='sqlite3',
                        help='rosbag2 storage plugin (default sqlite3)')
    parser.add_argument('--overwrite', action='store_true',
                        help='replace an existing output folder')


def run(args: argparse.Namespace) -> int:
    counts = import_bag(args.input, args.out, args.topics, args.storage, args.overwrite)
    skipped = counts.pop('skipped')
    parts = ', '.join(f'{t}: {n}' for t, n in counts.items())
    print(f'{args.out}: {parts}' + (f'; {skipped} unusable scan(s) skipped' if skipped else ''))
    return 0
