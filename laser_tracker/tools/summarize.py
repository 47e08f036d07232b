"""``laser-tracker summarize BAG``: what a recording holds.

Topics with their types and counts, the duration, and for each LaserScan topic the scan rate,
beam count and geometry; for each Odometry topic its rate and the distance and rotation it
reports; for ``/ground_truth`` the moving objects (kind, time present, scans visible, speed).
Works on any rosbag2 or ROS 1 bag (a recording without ground truth just has no such part).
"""
from __future__ import annotations

import argparse
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from laser_tracker.conversions import (objects_from_marker_array, odometry_from_msg,
                                       stamp_to_sec)
from laser_tracker.tools.bag import GROUND_TRUTH_TOPIC, iter_messages, resolve_bag, topics

SCAN_TYPE = 'sensor_msgs/msg/LaserScan'
ODOM_TYPE = 'nav_msgs/msg/Odometry'
MARKERS_TYPE = 'visualization_msgs/msg/MarkerArray'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', metavar='BAG', help='a rosbag2 folder or a ROS 1 .bag file')


def _rate(stamps: list[float]) -> float:
    if len(stamps) < 2 or stamps[-1] <= stamps[0]:
        return math.nan
    return (len(stamps) - 1) / (stamps[-1] - stamps[0])


def summarize(path: str | Path) -> str:
    """The summary text of the recording at ``path``, or of the bundled recording of that
    name (raises InputFileError if unreadable)."""
    path = resolve_bag(path)
    info = topics(path)
    wanted = [t for t, (typ, _) in info.items() if typ in (SCAN_TYPE, ODOM_TYPE)]
    if GROUND_TRUTH_TOPIC in info and info[GROUND_TRUTH_TOPIC][0] == MARKERS_TYPE:
        wanted.append(GROUND_TRUTH_TOPIC)
    scans = defaultdict(lambda: {'stamps': [], 'beams': set(), 'geometry': None,
                                 'no_return': 0, 'total': 0})
    odoms = defaultdict(list)
    objects: dict[int, dict] = {}
    gt_frames = 0
    first_rx = last_rx = None
    for topic, t_ns, msg in iter_messages(path, wanted):
        first_rx = t_ns if first_rx is None else min(first_rx, t_ns)
        last_rx = t_ns if last_rx is None else max(last_rx, t_ns)
        typ = info[topic][0]
        if typ == SCAN_TYPE:
            s = scans[topic]
            s['stamps'].append(stamp_to_sec(msg.header.stamp))
            r = np.asarray(msg.ranges, dtype=float)
            s['beams'].add(r.size)
            s['geometry'] = (msg.angle_min, msg.angle_max, msg.angle_increment, msg.range_min,
                             msg.range_max, msg.time_increment, msg.scan_time,
                             msg.header.frame_id)
            with np.errstate(invalid='ignore'):
                s['no_return'] += int(np.count_nonzero(~np.isfinite(r) | (r >= msg.range_max)
                                                       | (r <= 0)))
            s['total'] += r.size
        elif typ == ODOM_TYPE:
            odoms[topic].append(odometry_from_msg(msg))
        elif topic == GROUND_TRUTH_TOPIC:
            gt_frames += 1
            stamp, _, objs = objects_from_marker_array(msg)
            for o in objs:
                e = objects.setdefault(o.id, {'kind': o.extra.get('kind', '?'), 'first': stamp,
                                              'last': stamp, 'frames': 0, 'visible': 0,
                                              'speeds': []})
                e['last'] = stamp
                e['frames'] += 1
                e['visible'] += bool(o.extra.get('visible', True))
                e['speeds'].append(math.hypot(o.vx, o.vy))

    lines = [f'{path}']
    size = sum(p.stat().st_size for p in path.rglob('*') if p.is_file()) if path.is_dir() \
        else path.stat().st_size
    duration = (last_rx - first_rx) * 1e-9 if first_rx is not None else 0.0
    lines.append(f'  {size / 1e6:.2f} MB, {sum(c for _, c in info.values())} messages, '
                 f'{duration:.1f} s (receive times)')
    width = max((len(t) for t in info), default=0)
    for topic, (typ, count) in sorted(info.items()):
        lines.append(f'  {topic:<{width}}  {typ:<34} {count:6d}')
    for topic, s in scans.items():
        st = s['stamps']
        a0, a1, inc, rmin, rmax, tinc, stime, frame = s['geometry']
        beams = ', '.join(str(b) for b in sorted(s['beams']))
        lines.append(f'  scans {topic}: {len(st)} over {st[-1] - st[0]:.1f} s, '
                     f'{_rate(st):.2f} Hz; {beams} beams, {math.degrees(a0):.1f} to '
                     f'{math.degrees(a1):.1f} deg at {math.degrees(inc):.2f} deg; range '
                     f'{rmin:.2f}-{rmax:.2f} m; frame {frame!r}; time_increment '
                     f'{tinc * 1e6:.1f} us, scan_time {stime * 1e3:.1f} ms; '
                     f'{100.0 * s["no_return"] / max(s["total"], 1):.1f} % no-return readings')
    for topic, msgs in odoms.items():
        st = [o.stamp for o in msgs]
        poses = np.array([o.pose for o in msgs])
        dist = float(np.sum(np.hypot(*np.diff(poses[:, :2], axis=0).T))) if len(msgs) > 1 \
            else 0.0
        turn = float(np.sum(np.abs(np.diff(np.unwrap(poses[:, 2]))))) if len(msgs) > 1 else 0.0
        lines.append(f'  odometry {topic}: {len(msgs)}, {_rate(st):.1f} Hz, '
                     f'{msgs[0].frame_id!r} -> {msgs[0].child_frame_id!r}; travelled '
                     f'{dist:.2f} m, turned {math.degrees(turn):.0f} deg')
    if GROUND_TRUTH_TOPIC in info:
        lines.append(f'  ground truth: {len(objects)} moving object(s) in {gt_frames} frames')
        for oid, e in sorted(objects.items()):
            sp = np.array(e['speeds'])
            moving = sp[sp > 0.05]
            lines.append(f'    id {oid:3d} {e["kind"]:<7} present {e["first"]:7.1f}-'
                         f'{e["last"]:7.1f} s, visible in {e["visible"]}/{e["frames"]} '
                         f'scans, speed mean {moving.mean() if moving.size else 0.0:.2f} max '
                         f'{sp.max() if sp.size else 0.0:.2f} m/s')
    return '\n'.join(lines)


def run(args: argparse.Namespace) -> int:
    print(summarize(args.bag))
    return 0
