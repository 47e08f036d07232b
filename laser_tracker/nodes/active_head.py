"""Node ``active_head``: point the pan/tilt cameras at tracked targets, leading them.

Subscribes ``tracks`` (MarkerArray, moving-object schema, odometry frame; confirmed tracks)
and ``ego_motion`` (nav_msgs/Odometry: the platform pose in the same frame). Publishes
``head/command`` (sensor_msgs/JointState: pan and tilt positions in rad) and ``head/target``
(geometry_msgs/PointStamped: the aim point, where the target will be after the lead time).
"""
from __future__ import annotations

from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from laser_tracker.conversions import (joint_state_msg, objects_from_marker_array,
                                       odometry_from_msg, point_stamped_msg, restamp,
                                       ros_factory)
from laser_tracker.core.head import HeadPointer
from laser_tracker.nodes import common


class ActiveHeadNode(Node):
    def __init__(self, **kwargs):
        super().__init__('active_head', **kwargs)
        params = common.declare_node_parameters(self, 'active_head')
        self.node_config = params['']
        self.pointer = HeadPointer(params['head'])
        self.factory = ros_factory()
        self.pose = None
        self.command_pub = self.create_publisher(JointState, 'head/command', 10)
        self.target_pub = self.create_publisher(PointStamped, 'head/target', 10)
        self.create_subscription(Odometry, 'ego_motion', self.on_pose, qos_profile_sensor_data)
        self.create_subscription(MarkerArray, 'tracks', self.on_tracks, 10)

    def on_pose(self, msg: Odometry) -> None:
        self.pose = odometry_from_msg(msg)

    def on_tracks(self, msg: MarkerArray) -> None:
        stamp, frame_id, objects = objects_from_marker_array(msg)
        if not objects:
            return
        if self.pose is None or abs(stamp - self.pose.stamp) > self.node_config.max_pose_age:
            self.get_logger().warning('no recent ego_motion pose: not aiming the head',
                                      throttle_duration_sec=5.0)
            return
        tracks = [(o.id, o.x, o.y, o.vx, o.vy, float(o.extra.get('weight', 0.0)))
                  for o in objects]
        cmd = self.pointer.update(stamp, self.pose.pose, tracks)
        if cmd is None:
            return
        cfg, exact = self.node_config, msg.markers[0].header.stamp
        self.command_pub.publish(restamp(joint_state_msg(
            self.factory, stamp, [cfg.pan_joint, cfg.tilt_joint], [cmd.pan, cmd.tilt]), exact))
        self.target_pub.publish(restamp(point_stamped_msg(
            self.factory, stamp, frame_id or 'odom', cmd.aim_x, cmd.aim_y), exact))


def main(args=None) -> None:
    common.run(ActiveHeadNode, args)


if __name__ == '__main__':
    main()
