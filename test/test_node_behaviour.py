"""What a ROS user touches on the running nodes: live parameters (validated, applied from the
next message), nodes that never die on a message, standard QoS, standard Odometry."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest

from ros_env import spin_until
from test_stages import ring_scan

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / 'bags' / 'exp1_stationary_single_walker'


def _scan_msg(stamp: float, mover_y: float | None = None):
    from laser_tracker.conversions import ros_factory, scan_to_msg
    return scan_to_msg(ros_factory(), ring_scan(stamp, mover_y))


class Graph:
    """ego_motion -> detection -> tracking -> active_head and a test node, one executor."""

    def __init__(self, context):
        import rclpy
        from geometry_msgs.msg import PointStamped
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import JointState, LaserScan
        from visualization_msgs.msg import MarkerArray

        from laser_tracker.nodes.active_head import ActiveHeadNode
        from laser_tracker.nodes.detection import DetectionNode
        from laser_tracker.nodes.ego_motion import EgoMotionNode
        from laser_tracker.nodes.tracking import TrackingNode

        self.ego = EgoMotionNode(context=context)
        self.detection = DetectionNode(context=context)
        self.tracking = TrackingNode(context=context)
        self.head = ActiveHeadNode(context=context)
        self.nodes = [self.ego, self.detection, self.tracking, self.head]
        self.io = rclpy.create_node('test_io', context=context)
        io = self.io
        # Default QoS (reliable) everywhere on the test side: what RViz or a user's node does.
        self.pub = {'scan': io.create_publisher(LaserScan, 'scan', 10),
                    'odom': io.create_publisher(Odometry, 'odom', 10),
                    'blobs': io.create_publisher(MarkerArray, 'blobs', 10),
                    'tracks': io.create_publisher(MarkerArray, 'tracks', 10),
                    'ego_motion': io.create_publisher(Odometry, 'ego_motion', 10)}
        self.got = {'ego_motion': [], 'blobs': [], 'tracks': [], 'head': [], 'target': [],
                    'hypotheses': [], 'markers': []}
        io.create_subscription(Odometry, 'ego_motion', self.got['ego_motion'].append, 10)
        io.create_subscription(MarkerArray, 'hypotheses', self.got['hypotheses'].append, 10)
        io.create_subscription(MarkerArray, 'tracks/markers', self.got['markers'].append, 10)
        io.create_subscription(MarkerArray, 'blobs', self.got['blobs'].append, 10)
        io.create_subscription(MarkerArray, 'tracks', self.got['tracks'].append, 10)
        io.create_subscription(JointState, 'head/command', self.got['head'].append, 10)
        io.create_subscription(PointStamped, 'head/target', self.got['target'].append, 10)
        self.executor = SingleThreadedExecutor(context=context)
        for node in self.nodes + [io]:
            self.executor.add_node(node)

    def wait_connected(self, timeout=10.0):
        pubs = [self.pub['scan']] + [p for n in self.nodes for p in n.publishers
                                     if p.topic_name in ('/ego_motion', '/blobs', '/tracks')]
        self.spin_until(lambda: all(p.get_subscription_count() > 0 for p in pubs), timeout)

    def spin_until(self, predicate, timeout=5.0):
        spin_until(self.executor, predicate, timeout)

    def spin(self, seconds=0.3):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)

    def scan(self, stamp, mover_y=None):
        n = len(self.got['tracks'])
        self.pub['scan'].publish(_scan_msg(stamp, mover_y))
        self.spin_until(lambda: len(self.got['tracks']) > n)

    def set(self, node, name, value):
        from rclpy.parameter import Parameter
        return node.set_parameters([Parameter(name, value=value)])[0]

    def close(self):
        self.executor.shutdown()
        for node in self.nodes + [self.io]:
            node.destroy_node()


@pytest.fixture
def graph(ros_context):
    g = Graph(ros_context)
    g.wait_connected()
    yield g
    g.close()


def _confirmed(array) -> list[int]:
    from laser_tracker.conversions import objects_from_marker_array
    return [o.id for o in objects_from_marker_array(array)[2]]


def walk(graph, start, n, dt=0.2):
    for k in range(n):
        t = start + k * dt
        graph.scan(t, -2.0 + 1.0 * (t - start))


def test_tracking_publishes_what_rviz_draws_of_every_hypothesis(graph):
    """tracks/markers: a label (id, kind, speed) and a velocity arrow per hypothesis, opaque
    once confirmed, stamped as its tracks."""
    from laser_tracker.conversions import (MARKER_ARROW, MARKER_TEXT, TENTATIVE_ALPHA,
                                           objects_from_marker_array, stamp_to_ns)
    walk(graph, 1.0, 10)
    graph.spin_until(lambda: len(graph.got['markers']) >= len(graph.got['tracks']))
    by_stamp = {stamp_to_ns(m.markers[0].header.stamp): m for m in graph.got['markers']}
    seen_confirmed = False
    for hyp in graph.got['hypotheses']:
        stamp = stamp_to_ns(hyp.markers[0].header.stamp)
        markers = by_stamp[stamp].markers
        labels = {m.id: m for m in markers if m.type == MARKER_TEXT}
        arrows = {m.id: m for m in markers if m.type == MARKER_ARROW}
        for o in objects_from_marker_array(hyp)[2]:
            label, arrow = labels[o.id], arrows[o.id]
            speed = math.hypot(o.vx, o.vy)
            assert label.text.split() == [f'{o.id}' + ('' if o.extra['confirmed'] else '?'),
                                          o.extra['kind'], f'{speed:.1f}', 'm/s']
            assert label.color.a == pytest.approx(1.0 if o.extra['confirmed']
                                                  else TENTATIVE_ALPHA)
            tip = arrow.points[1]
            assert (tip.x, tip.y) == pytest.approx((o.x + o.vx, o.y + o.vy), abs=1e-6)
            seen_confirmed |= o.extra['confirmed']
    assert seen_confirmed


def test_live_parameters_take_effect_from_the_next_message(graph):
    # tracking: the paper's m = 4 confirms the walker; 1000 samples confirms nothing.
    walk(graph, 1.0, 10)
    assert any(_confirmed(a) for a in graph.got['tracks'])
    assert graph.set(graph.tracking, 'hypotheses.confirm_samples', 1000).successful
    assert graph.tracking.stage.config.confirm_samples == 1000
    n = len(graph.got['tracks'])
    walk(graph, 10.0, 10)                  # after a gap: a new walker, never confirmed now
    assert not any(_confirmed(a) for a in graph.got['tracks'][n:])
    # refused, with the reason, and nothing changes
    bad = graph.set(graph.tracking, 'kalman.mode', 'bogus')
    assert not bad.successful and "'bogus' is not one of" in bad.reason
    assert graph.tracking.stage.hypotheses.filter.config.mode == 'paper'
    assert not graph.set(graph.tracking, 'hypotheses.gate', 'wide').successful
    assert graph.set(graph.tracking, 'hypotheses.gate', 1).successful     # int: fine float
    assert graph.tracking.stage.config.gate == 1.0
    assert graph.set(graph.tracking, 'kalman.mode', 'cv').successful
    assert graph.tracking.stage.hypotheses.filter.dim == 4
    # ego_motion: the frame of the published poses
    assert graph.set(graph.ego, 'odom_frame', 'my_odom').successful
    graph.scan(30.0)
    assert graph.got['ego_motion'][-1].header.frame_id == 'my_odom'
    # detection: blobs smaller than 10000 cells are dropped -> no blobs from a walker
    assert graph.set(graph.detection, 'blobs.min_cells', 10000).successful
    n = len(graph.got['blobs'])
    walk(graph, 40.0, 4)
    from laser_tracker.conversions import detections_from_marker_array
    assert all(detections_from_marker_array(a).blobs.count == 0
               for a in graph.got['blobs'][n:])
    # a read-only parameter says why
    ro = graph.set(graph.detection, 'status_topic', 'other')
    assert not ro.successful and 'read-only' in ro.reason.lower()


def test_active_head_joint_names_change_live(graph):
    assert graph.set(graph.head, 'pan_joint', 'camera_pan').successful
    walk(graph, 1.0, 12)
    graph.spin_until(lambda: graph.got['head'])
    assert graph.got['head'][-1].name[0] == 'camera_pan'


def _flood(graph):
    """Everything another publisher on our topics could send that we cannot use."""
    from builtin_interfaces.msg import Time
    from nav_msgs.msg import Odometry
    from visualization_msgs.msg import Marker, MarkerArray

    bad_scans = []
    neg = _scan_msg(1.0)
    neg.header.stamp = Time(sec=-5, nanosec=0)                   # negative stamp
    bad_scans.append(neg)
    short = _scan_msg(1.0)
    short.ranges = short.ranges[:100]                             # wrong length
    bad_scans.append(short)
    zero = _scan_msg(1.0)
    zero.header.stamp = Time(sec=-1, nanosec=5)
    zero.angle_increment = 0.0
    bad_scans.append(zero)
    for msg in bad_scans:
        graph.pub['scan'].publish(msg)
    odo = Odometry()
    odo.header.stamp = Time(sec=1, nanosec=0)
    odo.pose.pose.position.x = float('nan')
    graph.pub['odom'].publish(odo)
    odo2 = Odometry()
    odo2.header.stamp = Time(sec=-3, nanosec=0)
    odo2.pose.pose.orientation.w = 1.0
    graph.pub['odom'].publish(odo2)
    graph.pub['ego_motion'].publish(odo)                         # NaN pose on ego_motion
    # Markers of another publisher: wrong types in the JSON, not JSON, no scanner marker.
    for text in ('{"weight": "x"}', 'not json', '[1, 2]', '{"weight": null}'):
        m = Marker()
        m.header.stamp = Time(sec=2, nanosec=0)
        m.header.frame_id = 'odom'
        m.ns, m.id, m.type, m.action, m.text = 'tracks', 3, Marker.ARROW, Marker.ADD, text
        m.pose.orientation.w = 1.0
        graph.pub['tracks'].publish(MarkerArray(markers=[m]))
        b = Marker()
        b.header.stamp = Time(sec=2, nanosec=0)
        b.ns, b.type, b.action, b.text = 'blobs', Marker.CYLINDER, Marker.ADD, text
        graph.pub['blobs'].publish(MarkerArray(markers=[b]))
    graph.pub['blobs'].publish(MarkerArray())
    graph.spin(0.5)


def test_no_message_kills_a_node_and_the_graph_stays_correct(graph):
    """A flood of unusable messages on every input topic: each node warns (throttled),
    counts, and carries on; afterwards the graph computes exactly what a fresh offline
    pipeline computes from the good messages."""
    from laser_tracker.conversions import objects_from_marker_array, scan_from_msg
    from laser_tracker.core.pipeline import Pipeline

    _flood(graph)
    assert sum(graph.ego.dropped.values()) >= 3
    assert sum(graph.tracking.dropped.values()) >= 4
    assert sum(graph.head.dropped.values()) + sum(graph.detection.dropped.values()) >= 1
    before = len(graph.got['tracks'])
    pipeline = Pipeline()
    expected = {}
    for k in range(12):
        t = 5.0 + 0.2 * k
        msg = _scan_msg(t, -2.0 + (t - 5.0))
        res = pipeline.step(scan_from_msg(msg))
        h = res.hypotheses
        expected[round(t, 6)] = sorted(h.track_id[h.confirmed].tolist())
        n = len(graph.got['tracks'])
        graph.pub['scan'].publish(msg)
        graph.spin_until(lambda: len(graph.got['tracks']) > n)
    got = {}
    for array in graph.got['tracks'][before:]:
        stamp, _, objects = objects_from_marker_array(array)
        if not math.isnan(stamp):
            got[round(stamp, 6)] = sorted(o.id for o in objects)
    assert got == expected
    assert any(expected.values())


def test_ego_motion_reaches_default_qos_subscribers_as_standard_odometry(graph):
    from laser_tracker.conversions import odometry_from_msg
    for k in range(3):
        graph.scan(1.0 + 0.2 * k)
    graph.spin_until(lambda: len(graph.got['ego_motion']) >= 3)
    odo = graph.got['ego_motion'][-1]
    assert odo.header.frame_id == 'odom' and odo.child_frame_id == 'laser'
    cov = np.array(odo.pose.covariance).reshape(6, 6)
    assert np.allclose(cov, cov.T) and (np.diag(cov) >= 0).all()
    assert odometry_from_msg(odo).x == pytest.approx(0.0, abs=0.05)   # a standing scanner


def test_tracks_carry_kind_moving_and_covariance(graph):
    walk(graph, 1.0, 10)
    arrays = [a for a in graph.got['tracks'] if _confirmed(a)]
    assert arrays
    marker = arrays[-1].markers[1]
    extra = json.loads(marker.text)
    assert extra['kind'] in ('person', 'object') and extra['moving'] is True
    xx, xy, yy = extra['covariance']
    assert xx > 0 and yy > 0 and xx * yy >= xy * xy
    assert {'weight', 'confirmed', 'samples'} <= set(extra)


def test_two_pipelines_in_one_namespace_are_told_apart_from_one(ros_context):
    """Two tracking nodes publishing in one namespace (a pipeline per scanner without a
    namespace each): each says once that another node publishes on its outputs; in a
    namespace each, they say nothing."""
    from rclpy.executors import SingleThreadedExecutor

    from laser_tracker.nodes.tracking import TrackingNode

    nodes = [TrackingNode(context=ros_context), TrackingNode(context=ros_context),
             TrackingNode(context=ros_context, namespace='/left'),
             TrackingNode(context=ros_context, namespace='/right')]
    executor = SingleThreadedExecutor(context=ros_context)
    for node in nodes:
        executor.add_node(node)
    try:
        outputs = {'/tracks', '/hypotheses', '/tracks/markers'}

        def checked():
            for node in nodes:
                node.output_watch.check()
            # the namespaced nodes have discovered the others' outputs too
            return all(n.output_watch.warned == outputs for n in nodes[:2]) \
                and nodes[2].count_publishers('/right/tracks') == 1 \
                and nodes[3].count_publishers('/tracks') == 2

        spin_until(executor, checked, 10.0)
        assert not nodes[2].output_watch.warned and not nodes[3].output_watch.warned
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
