"""A recording played backwards: the same scans and building, another run through them.

Played backwards, a robot that drove ahead with its scanner looking ahead drives in reverse
with the scanner looking where it came from, as a rear scanner sees a drive; whoever walked
into view walks out of it, whoever walked up to the robot walks away from it, and people who
stood at the end of a run stand there from its start. The defaults are tuned on the
recordings as they were made; their reversed copies (``laser-tracker bench real``, the
``_reversed`` rows) show what of that depends on the direction of time.

Each message is written at the mirrored receive time (``first + last - t``) and header
stamp (``first + last - stamp``, over the header stamps of the reversed messages): scans
(LaserScan), odometry (Odometry, its velocities negated; the covariances are not carried)
and /tf (TFMessage). /tf_static is written once, at the start. The messages of ``attached``
topics (annotations: they belong to the scan before them) keep their offset after that scan.
Any other topic is left out (counted in the result).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from laser_tracker.conversions import (odometry_from_msg, odometry_to_msg, scan_from_msg,
                                       scan_to_msg, sec_to_ns, stamp_to_ns, tf_message_to_msg,
                                       time_msg)
from laser_tracker.core.scan import ScanError
from laser_tracker.errors import InputFileError
from laser_tracker.tools.bag import (FACTORY, LATCHED_QOS, TF_STATIC_TOPIC, BagWriter,
                                     iter_messages, topics)

SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'
TF_TYPE = 'tf2_msgs/msg/TFMessage'
TIMED_TYPES = (SCAN_TYPE, ODOMETRY_TYPE, TF_TYPE)


def _header_stamps(topic_type: str, msg) -> list[int]:
    """The header stamps (ns) a message carries."""
    if topic_type == TF_TYPE:
        return [stamp_to_ns(t.header.stamp) for t in msg.transforms]
    return [stamp_to_ns(msg.header.stamp)]


def write_reversed(src: str | Path, dst: str | Path, attached=()) -> dict:
    """Write ``src`` played backwards to ``dst`` (see the module docstring); returns counts:
    ``{'messages': written, 'left_out': {topic: count}, 'bad_scans': skipped}``.

    Raises InputFileError when ``src`` has no LaserScan topic or an ``attached`` topic is
    not in it.
    """
    src = Path(src)
    info = topics(src)
    missing = [t for t in attached if t not in info]
    if missing:
        raise InputFileError(src, f'no topic {", ".join(missing)} to carry along')
    kinds = {name: kind for name, (kind, _) in info.items()}
    timed = [n for n, k in kinds.items() if k in TIMED_TYPES and n != TF_STATIC_TOPIC]
    if not any(kinds[n] == SCAN_TYPE for n in timed):
        raise InputFileError(src, 'no LaserScan topic: nothing to play backwards')
    static = [n for n in kinds if n == TF_STATIC_TOPIC]
    left_out = {n: info[n][1] for n in kinds
                if n not in timed and n not in attached and n not in static}
    messages = list(iter_messages(src, timed + list(attached) + static))
    times = [t for topic, t, _ in messages if topic in timed]
    stamps = [s for topic, _, msg in messages if topic in timed
              for s in _header_stamps(kinds[topic], msg)]
    receive_mirror = min(times) + max(times)
    stamp_mirror = min(stamps) + max(stamps)

    out: list[tuple[int, int, str, object]] = []    # (receive time, order, topic, message)
    bad_scans = 0
    scan_time = None                  # receive time of the latest scan so far
    for order, (topic, t, msg) in enumerate(messages):
        kind = kinds[topic]
        if topic in static:
            continue
        if topic in attached:
            if scan_time is not None:
                out.append((receive_mirror - scan_time + (t - scan_time), order, topic, msg))
            continue
        mirrored = receive_mirror - t
        if kind == SCAN_TYPE:
            scan_time = t
            try:
                scan = scan_from_msg(msg)
            except ScanError:
                bad_scans += 1
                continue
            stamp_ns = stamp_mirror - stamp_to_ns(msg.header.stamp)
            scan = dataclasses.replace(scan, stamp=stamp_ns * 1e-9, stamp_ns=stamp_ns)
            new = scan_to_msg(FACTORY, scan)
        elif kind == ODOMETRY_TYPE:
            odom = odometry_from_msg(msg)
            odom = dataclasses.replace(odom, stamp=(stamp_mirror - sec_to_ns(odom.stamp)) * 1e-9,
                                       vx=-odom.vx, vy=-odom.vy, omega=-odom.omega)
            new = odometry_to_msg(FACTORY, odom)
        else:
            new = tf_message_to_msg(FACTORY, msg)
            for transform in new.transforms:
                transform.header.stamp = time_msg(
                    FACTORY, stamp_mirror - stamp_to_ns(transform.header.stamp))
        out.append((mirrored, order, topic, new))
    # Played backwards, what came last now comes first; ties keep a scan before what was
    # attached to it.
    out.sort(key=lambda item: (item[0], -item[1] if item[2] not in attached else item[1]))
    with BagWriter(dst) as bag:
        start = min(times)
        for topic, _, msg in messages:
            if topic in static:
                bag.write(topic, tf_message_to_msg(FACTORY, msg), start, qos=LATCHED_QOS)
        for t, _, topic, msg in out:
            bag.write(topic, msg, int(t))
    return {'messages': len(out), 'left_out': left_out, 'bad_scans': bad_scans}
