"""Node ``ego_motion``: the scanner's motion from odometry plus ICP scan matching.

Subscribes ``scan`` (sensor_msgs/LaserScan) and ``odom`` (nav_msgs/Odometry), best effort (so
reliable and best-effort publishers both reach it). For every scan that gets a pose it
publishes, stamped exactly as the scan:

* ``ego_motion`` (nav_msgs/Odometry, reliable): the scanner pose in ``odom_frame`` (child
  frame = the scan's frame) with its covariance, and the twist (motion since the previous
  scan per second, scanner frame) with its covariance: what Odometry means everywhere;
* ``ego_motion/status`` (diagnostic_msgs/DiagnosticArray, reliable): whether detection may
  trust the pose (source, motion variances, unmatched fraction, restart flag), the robot's
  body in the scan and whether the scan was turned over (``ego_motion.mount_upside_down``);
  layout in ``conversions.ego_motion_to_msgs`` and README.md.

One scanner per node: scans of another frame on the topic are skipped (the stage follows the
first scan's frame; see ``core.stages.EgoMotion``).

The node is convert -> ``core.stages.EgoMotion`` -> convert: the stage holds a scan until
the odometry covering it has arrived (at most ``odom_wait`` s of this node's clock; when
odometry stops, that is paid once) and owns the stream rules. Parameters: ``odom_frame``,
``odom_wait``, ``ego_motion.*`` and ``self_mask.*`` (the robot's own body in the scans), all
changeable at run time.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import LaserScan

from laser_tracker.conversions import (ego_motion_to_msgs, odometry_from_msg, ros_factory,
                                       scan_from_msg)
from laser_tracker.core.stages import EgoMotion
from laser_tracker.nodes import common
from laser_tracker.nodes.params import LiveParameters


class EgoMotionNode(Node):
    def __init__(self, **kwargs):
        super().__init__('ego_motion', **kwargs)
        self.params = LiveParameters(self, 'ego_motion', self.apply_parameters)
        node, section = self.params.sections[''], self.params.sections['ego_motion']
        self.stage = EgoMotion(section, node.odom_wait, node.odom_frame,
                               self.params.sections['self_mask'])
        self.factory = ros_factory()
        self._mount_checked = False
        self.pose_pub = self.create_publisher(Odometry, 'ego_motion', common.RELIABLE_OUT)
        self.status_pub = self.create_publisher(DiagnosticArray, 'ego_motion/status',
                                                common.RELIABLE_OUT)
        guard = common.guarded
        self.create_subscription(Odometry, 'odom', guard(self, 'odom')(self.on_odom),
                                 common.ODOMETRY_IN)
        scans = self.create_subscription(LaserScan, 'scan', guard(self, 'scan')(self.on_scan),
                                         common.SENSOR_IN)
        self.create_timer(0.05, guard(self, 'timer')(
            lambda: self.publish(self.stage.poll(self.now()))))
        self.scan_watch = common.ScanWatch.of(self, scans.topic_name)
        common.announce(self, f'poses of the scan frame in {node.odom_frame!r}; scanner mount '
                        f'x={section.mount_x:g} m y={section.mount_y:g} m '
                        f"yaw={section.mount_yaw:g} rad in the odometry's child frame "
                        '(ego_motion.mount_*)')

    def apply_parameters(self, sections: dict) -> None:
        node = sections['']
        self.stage.frame_id = node.odom_frame
        self.stage.reconfigure(sections['ego_motion'], node.odom_wait, sections['self_mask'])

    def now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_odom(self, msg: Odometry) -> None:
        odo = odometry_from_msg(msg)
        self.base_frame = odo.child_frame_id.lstrip('/')
        self.publish(self.stage.add_odometry(odo.stamp, odo.pose, self.now()))

    def on_scan(self, msg: LaserScan) -> None:
        self.scan_watch.seen()
        scan = scan_from_msg(msg)
        self._check_mount(scan.frame_id.lstrip('/'))
        self.publish(self.stage.add_scan(scan, self.now()))

    def _check_mount(self, scan_frame: str) -> None:
        """Warn once when the scans and the odometry are of different frames and no mount is
        configured: the scanner would silently be taken to sit at the platform's origin."""
        base = getattr(self, 'base_frame', None)
        if self._mount_checked or base is None or not scan_frame:
            return
        self._mount_checked = True
        c = self.stage.config
        if scan_frame != base and (c.mount_x, c.mount_y, c.mount_yaw) == (0.0, 0.0, 0.0):
            self.get_logger().warning(
                f'the scans are in frame {scan_frame!r} but the odometry is of {base!r} and '
                f'ego_motion.mount_x/mount_y/mount_yaw are 0: the scanner is taken to sit at '
                f'{base!r}; set the mount if it does not')

    def publish(self, ready) -> None:
        for _scan, _tag, pose in ready:
            if pose is None:
                continue
            odometry, status = ego_motion_to_msgs(self.factory, pose)
            self.status_pub.publish(status)
            self.pose_pub.publish(odometry)


def main(args=None) -> None:
    common.run(EgoMotionNode, args)


if __name__ == '__main__':
    main()
