"""Node ``ego_motion``: the scanner's motion from odometry plus ICP scan matching.

Subscribes ``scan`` (sensor_msgs/LaserScan) and ``odom`` (nav_msgs/Odometry), both on the
sensor-data QoS. Publishes ``ego_motion`` (nav_msgs/Odometry): for every scan that yields a
pose, the scanner pose in the odometry frame stamped with the scan's stamp (child frame = the
scan's frame). A scan that yields no pose (the match failed its checks and there is no usable
odometry) is skipped with the estimator's reason logged: no pose is published from a failed
match. Scans wait up to ``odom_wait`` for their odometry (``core/sync.py``), as in replay.

Pose quality, in the message's ``pose.covariance`` (6 x 6 row-major, x y z roll pitch yaw;
written by ``core.difference.quality_to_pose_variance``, read back by the ``detection``
node with ``quality_from_pose_variance``, which gates scans on it, ``difference.pose_gate``):

* x, y, yaw diagonal terms: the estimate's covariance of the motion since the previous scan
  (scanner frame; m^2, m^2, rad^2): ICP fused with the odometry prior, or the odometry prior
  alone when no match could be tried (too few points); 0 on the first scan; ``1e6`` each
  when the match was tried, failed its checks and odometry was used instead (source
  ``odometry``): the pose is then not trusted;
* z diagonal term: the fraction of the scan's points ICP left unmatched (1 - inlier ratio;
  0 on the first scan and without a match): a planar estimate has no z, and as an *un*matched
  fraction an all-zero covariance (other publishers) means nothing is known against the pose;
* roll diagonal term: 1 when the ego-motion (re)started its pose chain at this scan (source
  ``init``): detection and tracking forget their odometry-frame history, as offline;
* everything else: 0. The twist is not estimated (zeros).
"""
from __future__ import annotations

import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import LaserScan

from laser_tracker.conversions import (PlanarOdometry, odometry_from_msg, odometry_to_msg,
                                       restamp, ros_factory)
from laser_tracker.core.difference import pose_quality, quality_to_pose_variance
from laser_tracker.core.egomotion import EgoMotionEstimator
from laser_tracker.core.sync import OdometryWait
from laser_tracker.nodes import common


class EgoMotionNode(Node):
    def __init__(self, **kwargs):
        super().__init__('ego_motion', **kwargs)
        params = common.declare_node_parameters(self, 'ego_motion')
        self.node_config, self.section = params[''], params['ego_motion']
        self.estimator = EgoMotionEstimator(self.section)
        self.factory = ros_factory()
        self.waiting: OdometryWait = OdometryWait(self.node_config.odom_wait)
        self.pose_pub = self.create_publisher(Odometry, 'ego_motion', qos_profile_sensor_data)
        # Odometry comes in bursts at a higher rate than scans: a deeper best-effort queue.
        odom_qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.create_subscription(Odometry, 'odom', self.on_odom, odom_qos)
        self.create_subscription(LaserScan, 'scan', self.on_scan, qos_profile_sensor_data)
        self.create_timer(0.05, lambda: self.process(self.waiting.release(self.now())))

    def now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_odom(self, msg: Odometry) -> None:
        odo = odometry_from_msg(msg)
        pose = odo.pose
        if not (np.isfinite(pose).all() and np.isfinite(odo.stamp)):
            self.get_logger().warning('non-finite odometry skipped', throttle_duration_sec=5.0)
            return
        self.estimator.add_odometry(odo.stamp, pose)
        self.process(self.waiting.add_odometry(self.now(), odo.stamp))

    def on_scan(self, msg: LaserScan) -> None:
        scan = common.scan_or_warn(self, msg)
        if scan is None:
            return
        self.process(self.waiting.add_scan(self.now(), scan.stamp, (scan, msg.header.stamp)))

    def process(self, items) -> None:
        for scan, stamp in items:
            self.estimate(scan, stamp)

    def estimate(self, scan, stamp) -> None:
        """Estimate and publish the pose of ``scan``, stamped exactly as the scan was."""
        # The estimator resets itself when time goes backwards (a bag replayed in a loop).
        est = self.estimator.update(scan)
        pose = np.asarray(est.pose, dtype=float)
        if not est.ok or not np.isfinite(pose).all():
            self.get_logger().warning(f'no pose for the scan at {scan.stamp:.3f} s: '
                                      f'{est.reason}', throttle_duration_sec=5.0)
            return
        odom = PlanarOdometry(stamp=scan.stamp, x=pose[0], y=pose[1], theta=pose[2],
                              frame_id=self.node_config.odom_frame, child_frame_id=scan.frame_id)
        variance = quality_to_pose_variance(pose_quality(est))
        out = odometry_to_msg(self.factory, odom, pose_variance=variance)
        self.pose_pub.publish(restamp(out, stamp))


def main(args=None) -> None:
    common.run(EgoMotionNode, args)


if __name__ == '__main__':
    main()
