"""``laser-tracker bench graph``: the node graph over DDS at the SICK's full 75 Hz.

Starts ``ego_motion``, ``detection`` and ``tracking`` as separate processes (as on a robot),
then publishes the scans of a bundled recording on ``scan`` at ``--rate`` Hz (restamped,
looping, with odometry at twice that rate) and listens on ``tracks``. Latency is the time
from publishing a scan to receiving the ``tracks`` message with its stamp; a scan whose
tracks never arrive (within 1 s) is dropped. Prints p50 / p99 / max latency and the drops.

Detection uses every scan (``difference.max_scan_rate: 0``, from a parameter file the
benchmark writes): the graph under its whole load, not the 10 scans a second it would thin
a 75 Hz scanner to.

``--one-process`` runs the same nodes in one process instead (``laser_tracker_all``, which
also starts ``active_head``): what the three processes' hops over DDS cost.
``--code DIR`` runs the nodes from another checkout of the package (to compare versions).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

NODES = ('ego_motion', 'detection', 'tracking')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', default='exp1_stationary_single_walker',
                        help='a bundled recording (its scans are looped)')
    parser.add_argument('--rate', type=float, default=75.0, help='scans per second (75)')
    parser.add_argument('--seconds', type=float, default=20.0, help='how long to publish')
    parser.add_argument('--one-process', action='store_true',
                        help='the nodes in one process (laser_tracker_all) instead of three')
    parser.add_argument('--code', metavar='DIR', help='run the nodes from this checkout')
    parser.add_argument('--domain', type=int, default=87, help='ROS_DOMAIN_ID to use')


def run(args: argparse.Namespace) -> int:
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import LaserScan
    from visualization_msgs.msg import MarkerArray

    from laser_tracker.conversions import (PlanarOdometry, odometry_to_msg, ros_factory,
                                           scan_from_msg, scan_to_msg, stamp_to_ns)
    from laser_tracker.tools.bag import iter_messages, resolve_bag

    bag = resolve_bag(args.bag)
    scans = [scan_from_msg(m) for _, _, m in iter_messages(bag, ['/scan'])]
    env = dict(os.environ)
    if args.code:
        env['PYTHONPATH'] = str(Path(args.code).resolve())
    modules = ('composed',) if args.one_process else NODES
    every_scan = tempfile.NamedTemporaryFile('w', suffix='.yaml', prefix='bench_graph_')
    every_scan.write('detection:\n  ros__parameters:\n    difference:\n'
                     '      max_scan_rate: 0.0\n')
    every_scan.flush()
    procs = [subprocess.Popen([sys.executable, '-m', f'laser_tracker.nodes.{n}']
                              + (['--ros-args', '--params-file', every_scan.name]
                                 if n in ('composed', 'detection') else []), env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for n in modules]
    rclpy.init()
    node = rclpy.create_node('bench_graph')
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    scan_pub = node.create_publisher(LaserScan, 'scan', best_effort)
    odom_pub = node.create_publisher(Odometry, 'odom', best_effort)
    sent: dict[int, float] = {}
    received: dict[int, float] = {}

    def on_tracks(msg):
        if msg.markers:
            received.setdefault(stamp_to_ns(msg.markers[0].header.stamp), time.perf_counter())

    node.create_subscription(MarkerArray, 'tracks', on_tracks, 100)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    factory = ros_factory()
    try:
        deadline = time.monotonic() + 30.0
        while scan_pub.get_subscription_count() < 2 or node.count_publishers('tracks') < 1:
            if time.monotonic() > deadline:
                print('the nodes did not come up within 30 s')
                return 1
            executor.spin_once(timeout_sec=0.1)
        time.sleep(1.0)
        period = 1.0 / args.rate
        n = int(args.seconds * args.rate)
        t0 = 1000.0
        start = time.perf_counter()
        for k in range(n):
            stamp = t0 + k * period
            for j in (0, 1):
                odom_pub.publish(odometry_to_msg(factory, PlanarOdometry(
                    stamp + j * period / 2, 0.0, 0.0, 0.0)))
            scan = scans[k % len(scans)]
            scan.stamp = stamp
            msg = scan_to_msg(factory, scan)
            sent[stamp_to_ns(msg.header.stamp)] = time.perf_counter()
            scan_pub.publish(msg)
            target = start + (k + 1) * period
            while True:
                left = target - time.perf_counter()
                if left <= 0:
                    break
                executor.spin_once(timeout_sec=min(left, 0.005))
        end = time.perf_counter() + 1.5
        while time.perf_counter() < end:
            executor.spin_once(timeout_sec=0.01)
    finally:
        for p in procs:
            p.send_signal(2)
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        every_scan.close()
    latency = np.array([received[k] - t for k, t in sent.items()
                        if k in received and received[k] - t < 1.0]) * 1e3
    drops = len(sent) - latency.size
    print(f'{len(sent)} scans at {args.rate:g} Hz from {bag.name} through '
          f'{", ".join(NODES)} '
          + ('(one process: laser_tracker_all)' if args.one_process else '(separate processes)')
          + (f' [code: {args.code}]' if args.code else ''))
    if latency.size:
        print(f'latency scan -> tracks: p50 {np.percentile(latency, 50):.1f} ms, '
              f'p99 {np.percentile(latency, 99):.1f} ms, max {latency.max():.1f} ms; '
              f'drops {drops} ({100 * drops / len(sent):.1f} %)')
    else:
        print(f'no tracks received: drops {drops}')
    return 0
