"""``laser-tracker simulate SCENARIO OUT``: write a scenario's recording as a rosbag2 folder.

``laser-tracker simulate all bags/`` regenerates every bundled recording (bags/<name>/);
``--list`` lists the scenarios. The same scenario and seed always give the same messages.

Topics (README.md, "Bundled recordings"): ``/scan`` (sensor_msgs/LaserScan, frame ``laser``,
stamp = first beam, received ``receive_delay`` later), ``/odom`` (nav_msgs/Odometry
``odom`` -> ``base_link``, received at its stamp), ``/ground_truth`` (visualization_msgs/
MarkerArray, the moving-object schema in frame ``map``, one per scan at the scan's stamp) and
``/ground_truth/platform`` (nav_msgs/Odometry ``map`` -> ``base_link``, the true pose at each
scan's stamp) and ``/tf_static`` (tf2_msgs/TFMessage, one transform ``base_link`` ->
``laser``: the scanner mount, at the origin unless the scenario mounts it elsewhere), written
once at time 0 with tf2's latched (transient local) QoS.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from laser_tracker.conversions import (PlanarTransform, objects_to_marker_array,
                                       odometry_to_msg, scan_to_msg, transforms_to_msg)
from laser_tracker.errors import LaserTrackerError
from laser_tracker.tools.atomic import check_output
from laser_tracker.tools.bag import (FACTORY, GROUND_TRUTH_TOPIC, LATCHED_QOS, ODOM_TOPIC,
                                     PLATFORM_TRUTH_TOPIC, SCAN_TOPIC, TF_STATIC_TOPIC, BagWriter)
from laser_tracker.tools.sim.recorder import WORLD_FRAME, Recording, record
from laser_tracker.tools.sim.scenarios import SCENARIOS, build

GROUND_TRUTH_NS = 'ground_truth'


class SimulateError(LaserTrackerError):
    """A simulate command that cannot run (unknown scenario, output in the way)."""


def mount_transform(recording: Recording) -> PlanarTransform:
    """The scanner mount, ``odometry.child_frame_id`` (base_link) -> the scans' frame, as
    /tf_static carries it (stamped 0: valid at all times)."""
    sc = recording.scenario
    x, y, yaw = sc.mount
    return PlanarTransform(0.0, sc.odometry.child_frame_id, sc.lidar.frame_id, x, y, yaw)


def recording_messages(recording: Recording):
    """``[(receive time s, topic, message)]`` of a recording, in the order they are written:
    by receive time, then /tf_static, /ground_truth/platform, /ground_truth, /scan, /odom."""
    f = FACTORY
    rows = []
    if recording.scenario.publish_mount:
        rows.append((0.0, -1, 0, TF_STATIC_TOPIC,
                     transforms_to_msg(f, [mount_transform(recording)])))
    for i, (scan, rx) in enumerate(zip(recording.scans, recording.scan_receive_times)):
        rows.append((float(rx), 2, i, SCAN_TOPIC, scan_to_msg(f, scan)))
    for i, odo in enumerate(recording.odometry_messages()):
        rows.append((odo.stamp, 3, i, ODOM_TOPIC, odometry_to_msg(f, odo)))
    for i, gt in enumerate(recording.truth):
        rows.append((gt.stamp, 1, i, GROUND_TRUTH_TOPIC,
                     objects_to_marker_array(f, gt.objects, gt.stamp, WORLD_FRAME,
                                             GROUND_TRUTH_NS)))
        rows.append((gt.stamp, 0, i, PLATFORM_TRUTH_TOPIC, odometry_to_msg(f, gt.platform)))
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    return [(t, topic, msg) for t, _, _, topic, msg in rows]


def write_recording(recording: Recording, path: str | Path, storage: str = 'sqlite3',
                    overwrite: bool = False) -> Path:
    """Write ``recording`` as the rosbag2 folder ``path`` (atomically)."""
    path = Path(path)
    with BagWriter(path, storage=storage, overwrite=overwrite) as bag:
        for t, topic, msg in recording_messages(recording):
            bag.write(topic, msg, t, qos=LATCHED_QOS if topic == TF_STATIC_TOPIC else ())
    return path


def folder_size(path: Path) -> int:
    return sum(p.stat().st_size for p in Path(path).rglob('*') if p.is_file())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('scenario', nargs='?', metavar='SCENARIO',
                        help="a scenario name (see --list) or 'all'")
    parser.add_argument('out', nargs='?', metavar='OUT',
                        help="the rosbag2 folder to write; with 'all', the folder that "
                             'receives one recording per scenario')
    parser.add_argument('--seed', type=int, default=None,
                        help="random seed (default: the scenario's own, as bundled)")
    parser.add_argument('--storage', choices=('sqlite3', 'mcap'), default='sqlite3',
                        help='rosbag2 storage plugin (default sqlite3)')
    parser.add_argument('--overwrite', action='store_true',
                        help='replace an existing output folder')
    parser.add_argument('--list', action='store_true', help='list the scenarios and exit')


def run(args: argparse.Namespace) -> int:
    if args.list:
        width = max(len(n) for n in SCENARIOS)
        for name, info in SCENARIOS.items():
            print(f'{name:<{width}}  seed {info.default_seed:<3d} {info.summary}')
        return 0
    if not args.scenario or not args.out:
        raise SimulateError('give SCENARIO and OUT (or --list to see the scenarios)')
    if args.scenario == 'all':
        jobs = [(name, Path(args.out) / name) for name in SCENARIOS]
    elif args.scenario in SCENARIOS:
        jobs = [(args.scenario, Path(args.out))]
    else:
        raise SimulateError(f'unknown scenario {args.scenario!r}; known: '
                            f'{", ".join(SCENARIOS)}, all')
    for _, target in jobs:
        check_output(target, args.overwrite)
    for name, target in jobs:
        scenario = build(name, args.seed)
        rec = record(scenario)
        write_recording(rec, target, storage=args.storage, overwrite=args.overwrite)
        size = folder_size(target)
        print(f'{target}: {name} seed {scenario.seed}, {len(rec.scans)} scans, '
              f'{len(rec.odometry.stamps)} odometry, {len(scenario.agents)} moving objects, '
              f'{size / 1e6:.2f} MB', flush=True)
    return 0
