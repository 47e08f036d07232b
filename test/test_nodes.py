"""The node graph (ego_motion -> detection -> tracking -> active_head) replays a bundled
recording and publishes what the offline pipeline computes from the same messages."""
import math
import time
from pathlib import Path

import numpy as np
import pytest

from ros_env import spin_until


ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / 'bags' / 'exp1_stationary_single_walker'


def _bag_messages(bag=BAG):
    from laser_tracker.tools.bag import iter_messages
    return list(iter_messages(bag, ['/scan', '/odom']))


def _offline_tracks(messages):
    """Confirmed tracks per scan stamp from the offline pipeline fed in bag order, as the
    tracking stage reports them (a coasting track whose place the scan sees empty, or whose
    position it shows hidden, is not: ``hypotheses.seen_empty_radius``, ``report_hidden``)."""
    from laser_tracker.conversions import odometry_from_msg, scan_from_msg
    from laser_tracker.core.pipeline import Pipeline

    pipeline = Pipeline()
    out = {}
    for topic, _, msg in messages:
        if topic == '/odom':
            odo = odometry_from_msg(msg)
            pipeline.add_odometry(odo.stamp, odo.pose)
        else:
            res = pipeline.step(scan_from_msg(msg))
            t = pipeline.tracker.tracks()
            keep = t.confirmed
            out[round(res.stamp, 6)] = sorted(
                zip(t.track_id[keep].tolist(), t.position[keep, 0].tolist(),
                    t.position[keep, 1].tolist()))
    return out


class _Graph:
    """The nodes plus a feeder and a listener in one executor; ``node_kwargs`` go to each
    node (e.g. ``parameter_overrides``)."""

    def __init__(self, context, **node_kwargs):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_sensor_data
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import JointState, LaserScan
        from visualization_msgs.msg import MarkerArray

        from laser_tracker.nodes.active_head import ActiveHeadNode
        from laser_tracker.nodes.detection import DetectionNode
        from laser_tracker.nodes.ego_motion import EgoMotionNode
        from laser_tracker.nodes.tracking import TrackingNode

        class CountingEgoMotion(EgoMotionNode):
            odom_received = 0

            def on_odom(self, msg):
                self.odom_received += 1
                super().on_odom(msg)

        self.ego = CountingEgoMotion(context=context, **node_kwargs)
        self.nodes = [self.ego] + [cls(context=context, **node_kwargs) for cls in
                                   (DetectionNode, TrackingNode, ActiveHeadNode)]
        self.io = rclpy.create_node('test_feeder', context=context)
        self.scan_pub = self.io.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
        self.odom_pub = self.io.create_publisher(Odometry, 'odom', qos_profile_sensor_data)
        self.tracks, self.commands = [], []
        self.io.create_subscription(MarkerArray, 'tracks', self.tracks.append, 100)
        self.io.create_subscription(JointState, 'head/command', self.commands.append, 100)
        self.executor = SingleThreadedExecutor(context=context)
        for node in self.nodes + [self.io]:
            self.executor.add_node(node)
        self.publishers = [self.scan_pub, self.odom_pub] + [
            p for n in self.nodes for p in n.publishers if p.topic_name not in
            ('/rosout', '/parameter_events', '/head/target', '/hypotheses',
             '/tracks/markers')]

    def wait_connected(self, timeout=10.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(p.get_subscription_count() > 0 for p in self.publishers):
                return
            self.executor.spin_once(timeout_sec=0.05)
        missing = [p.topic_name for p in self.publishers if p.get_subscription_count() == 0]
        raise AssertionError(f'no subscriber on {missing}')

    def spin_until(self, predicate, timeout=5.0):
        spin_until(self.executor, predicate, timeout)

    def play(self, messages, outputs=()) -> None:
        """Publish a recording's ``messages``: odometry in order, each scan once the
        odometry before it was received, the next once the scan's ``tracks`` (and one more
        message on each list of ``outputs``) came back, as the offline pipeline sees them."""
        sent_odom = 0
        for topic, _, msg in messages:
            if topic == '/odom':
                self.odom_pub.publish(_to_ros(msg, topic))
                sent_odom += 1
                continue
            self.spin_until(lambda: self.ego.odom_received >= sent_odom)
            before = [len(out) for out in (self.tracks, *outputs)]
            self.scan_pub.publish(_to_ros(msg, topic))
            self.spin_until(lambda: all(len(out) > n for out, n in
                                        zip((self.tracks, *outputs), before)))

    def close(self):
        self.executor.shutdown()
        for node in self.nodes + [self.io]:
            node.destroy_node()


def assert_tracks_equal(arrays, expected: dict, atol: float) -> None:
    """The ``tracks`` MarkerArrays a graph published hold, scan by scan, the ``expected``
    ``{stamp rounded to 1 us: sorted [(id, x, y)]}``."""
    from laser_tracker.conversions import objects_from_marker_array

    published = {}
    for array in arrays:
        stamp, _, objects = objects_from_marker_array(array)
        if not math.isnan(stamp):
            published[round(stamp, 6)] = sorted((o.id, o.x, o.y) for o in objects)
    assert published.keys() == expected.keys()
    for stamp, tracks in expected.items():
        got = published[stamp]
        assert [t[0] for t in got] == [t[0] for t in tracks], stamp
        np.testing.assert_allclose(np.reshape([t[1:] for t in got], (-1, 2)),
                                   np.reshape([t[1:] for t in tracks], (-1, 2)), atol=atol,
                                   err_msg=str(stamp))


def _to_ros(msg, topic):
    from laser_tracker.conversions import (odometry_from_msg, odometry_to_msg, ros_factory,
                                           scan_from_msg, scan_to_msg)
    if topic == '/scan':
        return scan_to_msg(ros_factory(), scan_from_msg(msg))
    return odometry_to_msg(ros_factory(), odometry_from_msg(msg))


@pytest.mark.skipif(not BAG.exists(), reason=f'{BAG} not generated')
def test_node_graph_publishes_the_offline_tracks(ros_context):
    messages = _bag_messages()
    expected = _offline_tracks(messages)
    assert any(expected.values()), 'the recording should yield confirmed tracks'
    graph = _Graph(ros_context)
    try:
        graph.wait_connected()
        graph.play(messages)
        assert_tracks_equal(graph.tracks, expected, atol=1e-6)
        # The head was aimed whenever there was a confirmed track to aim at.
        graph.spin_until(lambda: len(graph.commands) > 0)
        cmd = graph.commands[-1]
        assert list(cmd.name) == ['head_pan_joint', 'head_tilt_joint']
        assert all(math.isfinite(v) for v in cmd.position)
    finally:
        graph.close()


def test_a_scanner_whose_beam_count_changes_every_scan_crosses_the_graph_as_offline(
        ros_context, tmp_path):
    """The robot's drive seen by a scanner whose driver publishes 765 to 771 beams a scan:
    the body that ego_motion learns on one scan's beams and carries to the next reaches
    detection for the beams of each scan (``self_mask`` in ``ego_motion/status``), and the
    graph publishes the offline tracks (the first 12 s of the drive)."""
    from laser_tracker.tools.bench_sims import simulate_scanner

    bag = simulate_scanner('driving_past_people', tmp_path / 'jitter', beam_count_jitter=3)
    messages = _bag_messages(bag)
    first = messages[0][2].header.stamp.sec
    messages = [m for m in messages if m[2].header.stamp.sec < first + 12]
    assert len({len(m.ranges) for t, _, m in messages if t == '/scan'}) > 1
    expected = _offline_tracks(messages)
    assert any(expected.values()), 'the recording should yield confirmed tracks'
    from diagnostic_msgs.msg import DiagnosticArray
    from laser_tracker.conversions import decode_body

    beams = {round(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, 6): len(m.ranges)
             for t, _, m in messages if t == '/scan'}
    graph = _Graph(ros_context)
    status = []
    graph.io.create_subscription(DiagnosticArray, 'ego_motion/status', status.append, 100)
    try:
        graph.wait_connected()
        graph.play(messages, outputs=(status,))
        assert_tracks_equal(graph.tracks, expected, atol=1e-6)
    finally:
        graph.close()
    sizes = set()
    for msg in status:
        body = decode_body({kv.key: kv.value for kv in msg.status[0].values}['self_mask'])
        if body is not None:
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            assert body.size == beams[round(stamp, 6)]           # the beams of its own scan
            sizes.add(body.size)
    assert len(sizes) >= 3                  # the learnt body, on scans of several counts


def test_bad_scans_are_skipped_and_tracking_continues(ros_context):
    from laser_tracker.conversions import ros_factory, scan_to_msg
    from laser_tracker.core.scan import Scan

    graph = _Graph(ros_context)
    try:
        graph.wait_connected()
        angles = np.deg2rad(np.arange(-90, 90.5, 0.5))
        ranges = np.full(angles.size, 4.0)

        def scan(stamp, r):
            return scan_to_msg(ros_factory(), Scan(stamp=stamp, ranges=r,
                                                   angle_min=-math.pi / 2,
                                                   angle_increment=math.radians(0.5),
                                                   range_min=0.01, range_max=8.0))

        bad = scan(1.0, ranges)
        bad.ranges = bad.ranges[:100]          # wrong length for its angle fields
        graph.scan_pub.publish(bad)
        nan_scan = ranges.copy()
        nan_scan[::3] = np.nan
        nan_scan[1::3] = -1.0
        graph.scan_pub.publish(scan(1.2, nan_scan))
        graph.spin_until(lambda: len(graph.tracks) >= 1)
        graph.scan_pub.publish(scan(1.4, ranges))
        graph.spin_until(lambda: len(graph.tracks) >= 2)
        graph.scan_pub.publish(scan(0.5, ranges))   # time goes backwards: restart, no crash
        graph.spin_until(lambda: len(graph.tracks) >= 3)
        for _ in range(5):
            graph.executor.spin_once(timeout_sec=0.02)
        assert len(graph.tracks) == 3               # the malformed scan produced nothing
    finally:
        graph.close()


def test_a_second_scanner_on_the_scan_topic_is_skipped(ros_context):
    """Two scanners on one topic: the graph follows the first scan's frame; the other
    scanner's scans give no pose and no tracks."""
    from nav_msgs.msg import Odometry

    from laser_tracker.conversions import ros_factory, scan_to_msg
    from laser_tracker.core.scan import Scan

    graph = _Graph(ros_context)
    poses = []
    graph.io.create_subscription(Odometry, 'ego_motion', poses.append, 100)
    try:
        graph.wait_connected()
        ranges = np.full(361, 4.0)

        def scan(stamp, frame):
            return scan_to_msg(ros_factory(), Scan(
                stamp=stamp, ranges=ranges, angle_min=-math.pi / 2,
                angle_increment=math.radians(0.5), range_min=0.01, range_max=8.0,
                frame_id=frame))

        for k, frame in enumerate(['laser_front', 'laser_rear'] * 3):
            before = len(graph.tracks)
            graph.scan_pub.publish(scan(1.0 + 0.1 * k, frame))
            if frame == 'laser_front':
                graph.spin_until(lambda: len(graph.tracks) > before)
            else:
                for _ in range(10):
                    graph.executor.spin_once(timeout_sec=0.02)
        assert len(graph.tracks) == 3
        assert [p.child_frame_id for p in poses] == ['laser_front'] * 3
        assert graph.ego.stage.events.counts['scan of another scanner skipped'] == 3
    finally:
        graph.close()


def test_out_of_range_parameter_is_refused_with_its_name(ros_context):
    from rclpy.parameter import Parameter

    from laser_tracker.config import ConfigError
    from laser_tracker.nodes.tracking import TrackingNode

    with pytest.raises(ConfigError, match='node tracking: parameter hypotheses.w_inc: -5.0 '
                                          'is below the minimum'):
        TrackingNode(context=ros_context,
                     parameter_overrides=[Parameter('hypotheses.w_inc', value=-5.0)])
    with pytest.raises(ConfigError, match="no node has a parameter 'hypotheses.w_extra'"):
        TrackingNode(context=ros_context,
                     parameter_overrides=[Parameter('hypotheses.w_extra', value=1.0)])
    node = TrackingNode(context=ros_context,          # an integer is a fine float
                        parameter_overrides=[Parameter('hypotheses.w_inc', value=40)])
    try:
        assert node.stage.config.w_inc == 40.0
        assert isinstance(node.stage.config.w_inc, float)
    finally:
        node.destroy_node()


def test_pose_and_its_quality_cross_the_ego_motion_topics_unchanged():
    """What the ego_motion node publishes (Odometry + status), the detection node reads back
    unchanged, with rclpy and rosbags messages alike; the Odometry means what Odometry
    means (pose, covariance, twist)."""
    from laser_tracker.conversions import (bag_factory, ego_motion_from_msgs,
                                           ego_motion_to_msgs, odometry_from_msg, ros_factory)
    from laser_tracker.core.difference import (FAILED_VARIANCE, DifferenceConfig, PoseQuality,
                                               pose_trusted)
    from laser_tracker.core.stages import StampedPose
    from laser_tracker.tools.bag import TYPESTORE

    gate = DifferenceConfig()
    qualities = {PoseQuality((2.5e-5, 1.3e-4, 7.1e-6), 1.0 - 0.93): True,
                 PoseQuality((2.5e-5, 1.3e-4, 7.1e-6), 1.0 - 0.45): False,   # poor overlap
                 PoseQuality((FAILED_VARIANCE,) * 3, 1.0 - 0.8): False,      # ICP refused
                 PoseQuality(restarted=True): True}                          # first scan
    cov = np.array([[4e-4, 1e-5, 0.0], [1e-5, 9e-4, 2e-6], [0.0, 2e-6, 1e-4]])
    for factory in (ros_factory(), bag_factory(TYPESTORE)):
        for q, trusted in qualities.items():
            pose = StampedPose(stamp=12.5, pose=np.array([1.0, -2.0, 0.3]),
                               motion=np.array([0.1, 0.0, 0.02]), dt=0.2,
                               motion_covariance=np.diag([1e-4, 1e-4, 1e-5]),
                               pose_covariance=cov, quality=q, source='icp', reason='test',
                               child_frame_id='laser', stamp_ns=12_500_000_001)
            odometry, status = ego_motion_to_msgs(factory, pose)
            back = ego_motion_from_msgs(odometry, status)
            assert back.quality == q and pose_trusted(back.quality, gate) is trusted
            assert back.stamp_ns == 12_500_000_001
            np.testing.assert_allclose(back.pose, pose.pose)
            np.testing.assert_allclose(back.pose_covariance, cov)
            odo = odometry_from_msg(odometry)
            assert odo.child_frame_id == 'laser'
            assert odo.vx == pytest.approx(0.5, abs=0.01) and odo.omega == pytest.approx(0.1)
        alone = ego_motion_from_msgs(odometry)        # no status: another publisher
        assert pose_trusted(alone.quality, gate) and not alone.quality.restarted


def _starts_with(monkeypatch, module, name: str, parameters: dict) -> None:
    """``module.name`` (a node class) starts with ``parameters`` set, for this test."""
    from rclpy.parameter import Parameter

    class Configured(getattr(module, name)):
        def __init__(self, **kwargs):
            super().__init__(parameter_overrides=[Parameter(key, value=value)
                                                  for key, value in parameters.items()],
                             **kwargs)

    monkeypatch.setattr(module, name, Configured)


def _offline_gated(messages, config):
    """Per scan stamp: blob positions and confirmed tracks of the offline pipeline."""
    from laser_tracker.conversions import odometry_from_msg, scan_from_msg
    from laser_tracker.core.pipeline import Pipeline

    pipeline = Pipeline(config)
    blobs, tracks = {}, {}
    for topic, _, msg in messages:
        if topic == '/odom':
            odo = odometry_from_msg(msg)
            pipeline.add_odometry(odo.stamp, odo.pose)
            continue
        res = pipeline.step(scan_from_msg(msg))
        h = res.hypotheses
        keep = h.confirmed
        stamp = round(res.stamp, 6)
        blobs[stamp] = res.detections.blobs.xy.copy()
        tracks[stamp] = sorted(zip(h.track_id[keep].tolist(), h.position[keep, 0].tolist(),
                                   h.position[keep, 1].tolist()))
    return blobs, tracks, pipeline.events()['detection'].get('gated', 0)


@pytest.mark.skipif(not BAG.exists(), reason=f'{BAG} not generated')
def test_node_graph_applies_the_pose_gate_as_the_offline_pipeline(ros_context, monkeypatch):
    """With a strict inlier-ratio gate some scans of the recording are not trusted: the
    quality crosses ego_motion -> detection in the message and the graph withholds the same
    scans' blobs as ``Pipeline.step``."""
    from visualization_msgs.msg import MarkerArray

    import laser_tracker.nodes.detection as detection
    from laser_tracker.conversions import detections_from_marker_array, objects_from_marker_array
    from laser_tracker.core.pipeline import PipelineConfig

    strict = 0.85          # exp1's matches explain 79-95 % of the points
    config = PipelineConfig().replace(difference={'pose_min_inlier_ratio': strict})
    messages = _bag_messages()
    blobs, tracks, gated = _offline_gated(messages, config)
    assert gated > 0, 'the strict gate should withhold some scans'
    assert sum(len(b) == 0 for b in blobs.values()) >= gated

    _starts_with(monkeypatch, detection, 'DetectionNode',
                 {'difference.pose_min_inlier_ratio': strict})
    graph = _Graph(ros_context)
    published_blobs = []
    graph.io.create_subscription(MarkerArray, 'blobs', published_blobs.append, 100)
    try:
        assert graph.nodes[1].stage.difference_config.pose_min_inlier_ratio == strict
        graph.wait_connected()
        graph.play(messages, outputs=(published_blobs,))
        got_blobs = {}
        for array in published_blobs:
            d = detections_from_marker_array(array)
            got_blobs[round(d.stamp, 6)] = d.blobs.xy
        assert got_blobs.keys() == blobs.keys()
        for stamp, xy in blobs.items():
            np.testing.assert_allclose(got_blobs[stamp], xy, atol=1e-6, err_msg=str(stamp))
        got_tracks = {}
        for array in graph.tracks:
            stamp, _, objects = objects_from_marker_array(array)
            if not math.isnan(stamp):
                got_tracks[round(stamp, 6)] = sorted((o.id, o.x, o.y) for o in objects)
        for stamp, expected in tracks.items():
            assert [t[0] for t in got_tracks[stamp]] == [t[0] for t in expected], stamp
    finally:
        graph.close()


@pytest.mark.skipif(not BAG.exists(), reason=f'{BAG} not generated')
def test_an_upside_down_scanner_is_turned_over_by_the_ego_motion_parameter(ros_context,
                                                                          monkeypatch):
    """``ego_motion.mount_upside_down``: the graph fed the scans of a scanner hung upside
    down publishes the tracks of the level scanner; detection turns the scans over as the
    pose's status says."""
    import laser_tracker.nodes.ego_motion as ego_motion
    from laser_tracker.conversions import ros_factory, scan_from_msg, scan_to_msg

    messages = _bag_messages()
    expected = _offline_tracks(messages)
    assert any(expected.values())
    upside_down = [(topic, t, scan_to_msg(ros_factory(), scan_from_msg(msg).mirrored())
                    if topic == '/scan' else msg) for topic, t, msg in messages]

    _starts_with(monkeypatch, ego_motion, 'EgoMotionNode', {'ego_motion.mount_upside_down': True})
    graph = _Graph(ros_context)
    try:
        assert graph.ego.stage.config.mount_upside_down
        graph.wait_connected()
        graph.play(upside_down)
        assert_tracks_equal(graph.tracks, expected, atol=1e-4)
    finally:
        graph.close()


def test_ego_motion_restart_crosses_to_detection_and_tracking(ros_context):
    """A restarted pose chain voids the odometry-frame history downstream too, as the offline
    pipeline does: the flag rides on ego_motion/status and then in the blobs."""
    from laser_tracker.conversions import (detections_from_marker_array,
                                           detections_to_marker_array, ros_factory)
    from laser_tracker.core.detections import Blobs, Detections
    from laser_tracker.nodes.tracking import TrackingNode

    node = TrackingNode(context=ros_context)
    try:
        def blobs(stamp, x, restart=False):
            d = Detections(stamp=stamp, origin=np.zeros(3), restarted=restart,
                           blobs=Blobs(xy=np.array([[x, 2.0]]), cells=np.array([3]),
                                       extent=np.array([0.2]), structure=np.array([np.nan])))
            msg = detections_to_marker_array(ros_factory(), d)
            assert detections_from_marker_array(msg).restarted == restart
            return msg

        for k in range(6):                      # a blob walking at 1 m/s: hypotheses live
            node.on_blobs(blobs(0.2 * k, 0.2 * k))
        assert len(node.stage.hypotheses.hyp) > 0
        node.on_blobs(blobs(1.2, 1.2, restart=True))
        assert len(node.stage.hypotheses.hyp) == 0   # reset, then one lone blob: nothing yet
    finally:
        node.destroy_node()


def test_epoch_stamps_pair_exactly_and_outputs_keep_the_scan_stamp(ros_context):
    """Stamps at today's epoch (1.7e9 s) do not survive a float round trip: pairing and
    output stamps must use the header integers, or the graph silently publishes nothing."""
    from builtin_interfaces.msg import Time

    from laser_tracker.conversions import ros_factory, scan_to_msg, stamp_to_ns
    from laser_tracker.core.scan import Scan

    graph = _Graph(ros_context)
    try:
        graph.wait_connected()
        sent = []
        for k in range(8):
            msg = scan_to_msg(ros_factory(), Scan(
                stamp=0.0, ranges=np.full(361, 4.0), angle_min=-math.pi / 2,
                angle_increment=math.radians(0.5), range_min=0.01, range_max=8.0))
            msg.header.stamp = Time(sec=1_700_000_000 + k // 5,
                                    nanosec=123_456_789 + 200_000_001 * (k % 5))
            sent.append(stamp_to_ns(msg.header.stamp))
            graph.scan_pub.publish(msg)
            graph.spin_until(lambda: len(graph.tracks) > k)
        got = [stamp_to_ns(a.markers[0].header.stamp) for a in graph.tracks]
        assert got == sent
    finally:
        graph.close()
