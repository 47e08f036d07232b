"""Node ``detection``: occupancy grid, difference map (Eq. 1) and 4-connected blobs.

Subscribes ``scan`` (sensor_msgs/LaserScan) and ``ego_motion`` (nav_msgs/Odometry, the
scanner pose per scan from the ``ego_motion`` node), pairs them by identical stamps, and
publishes ``blobs`` (visualization_msgs/MarkerArray, schema in ``core/pipeline.py`` and
README.md): the moving-object candidates of each scan in the odometry frame.

The pose quality comes from the ``ego_motion`` message's pose covariance (layout in the
``ego_motion`` node's docstring, ``core.difference.quality_from_pose_variance``): a scan whose
pose is not trusted (``difference.pose_gate``: ICP refused, or too few points matched) gets an
empty blob array, as the offline pipeline does. A pose message with an all-zero covariance
(another publisher) is trusted; one whose covariance cannot be read is not (warned).
"""
from __future__ import annotations

from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import MarkerArray

from laser_tracker.conversions import (blobs_to_marker_array, odometry_from_msg,
                                       pose_variance_from_msg, restamp, ros_factory,
                                       stamp_to_ns)
from laser_tracker.core.difference import FAILED_VARIANCE, PoseQuality, \
    quality_from_pose_variance
from laser_tracker.core.pipeline import Detector
from laser_tracker.nodes import common


class DetectionNode(Node):
    def __init__(self, **kwargs):
        super().__init__('detection', **kwargs)
        sections = common.declare_node_parameters(self, 'detection')
        self.detector = Detector(sections['grid'], sections['difference'], sections['blobs'])
        self.factory = ros_factory()
        self.last_stamp: float | None = None
        self.pairer = common.StampPairer(self.on_pair)
        self.blobs_pub = self.create_publisher(MarkerArray, 'blobs', 10)
        self.create_subscription(LaserScan, 'scan', self.on_scan, qos_profile_sensor_data)
        self.create_subscription(Odometry, 'ego_motion', self.on_pose, qos_profile_sensor_data)

    def on_scan(self, msg: LaserScan) -> None:
        scan = common.scan_or_warn(self, msg)
        if scan is None:
            return
        # Paired by the exact header stamps (integers): floats cannot hold epoch stamps.
        self.pairer.add_left(stamp_to_ns(msg.header.stamp), (scan, msg.header.stamp))

    def on_pose(self, msg: Odometry) -> None:
        pose = odometry_from_msg(msg)
        try:
            quality = quality_from_pose_variance(pose_variance_from_msg(msg))
        except ValueError as exc:
            self.get_logger().warning(f'ego-motion pose quality unreadable ({exc}): the scan '
                                      f'at {pose.stamp:.3f} s is not trusted',
                                      throttle_duration_sec=5.0)
            quality = PoseQuality((FAILED_VARIANCE,) * 3, 1.0)
        self.pairer.add_right(stamp_to_ns(msg.header.stamp), (pose, quality))

    def on_pair(self, scan_stamp, pose_quality) -> None:
        (scan, stamp), (pose, quality) = scan_stamp, pose_quality
        if self.last_stamp is not None and scan.stamp <= self.last_stamp:
            self.get_logger().warning(f'time went backwards ({self.last_stamp:.3f} -> '
                                      f'{scan.stamp:.3f} s): detection restarts')
            self.detector.reset()
        restarted = quality.restarted and self.last_stamp is not None
        if restarted:   # as Pipeline.step: the odometry-frame history is void
            self.get_logger().warning(f'ego-motion restarted at {scan.stamp:.3f} s: detection '
                                      f'and tracking restart')
            self.detector.reset()
        self.last_stamp = scan.stamp
        self.detector.frame_id = pose.frame_id or self.detector.frame_id
        detection = self.detector.detect(scan, pose.pose, quality=quality)
        detection.blobs.restarted = restarted
        self.blobs_pub.publish(restamp(blobs_to_marker_array(self.factory, detection.blobs),
                                       stamp))


def main(args=None) -> None:
    common.run(DetectionNode, args)


if __name__ == '__main__':
    main()
