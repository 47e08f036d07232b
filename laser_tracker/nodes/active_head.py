"""Node ``active_head``: point the pan/tilt cameras at tracked targets, leading them.

Subscribes ``tracks`` (MarkerArray, moving-object schema, odometry frame; confirmed tracks)
and ``ego_motion`` (nav_msgs/Odometry: the platform pose in the same frame). Publishes
``head/command`` (sensor_msgs/JointState: pan and tilt positions in rad) and ``head/target``
(geometry_msgs/PointStamped: the aim point, where the target will be after the lead time).

The node is convert -> ``core.stages.Head`` -> convert. Markers of other publishers on
``tracks`` that do not follow the schema are skipped with a throttled warning. Parameters
``pan_joint``, ``tilt_joint``, ``max_pose_age`` and ``head.*`` change at run time.
"""
from __future__ import annotations

from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from laser_tracker.conversions import (ego_motion_from_msgs, joint_state_msg, number,
                                       objects_from_marker_array, point_stamped_msg, restamp,
                                       ros_factory)
from laser_tracker.core.stages import Head
from laser_tracker.nodes import common
from laser_tracker.nodes.params import LiveParameters


class ActiveHeadNode(Node):
    def __init__(self, **kwargs):
        super().__init__('active_head', **kwargs)
        self.params = LiveParameters(self, 'active_head', self.apply_parameters)
        s = self.params.sections
        self.stage = Head(s['head'], s[''].max_pose_age)
        self.factory = ros_factory()
        self.command_pub = self.create_publisher(JointState, 'head/command',
                                                 common.RELIABLE_OUT)
        self.target_pub = self.create_publisher(PointStamped, 'head/target',
                                                common.RELIABLE_OUT)
        guard = common.guarded
        self.create_subscription(Odometry, 'ego_motion', guard(self, 'ego_motion')(
            lambda msg: self.stage.add_pose(ego_motion_from_msgs(msg))), common.SENSOR_IN)
        self.create_subscription(MarkerArray, 'tracks',
                                 guard(self, 'tracks')(self.on_tracks), 10)
        node = s['']
        common.announce(self, f'joints {node.pan_joint!r}, {node.tilt_joint!r}; aim points in '
                        'the frame of the tracks')

    def apply_parameters(self, sections: dict) -> None:
        self.stage.reconfigure(sections['head'], sections[''].max_pose_age)

    def on_tracks(self, msg: MarkerArray) -> None:
        stamp, frame_id, objects = objects_from_marker_array(msg)
        if not objects:
            return
        rows = []
        for o in objects:
            try:
                rows.append((o.id, o.x, o.y, o.vx, o.vy, number(o.extra, 'weight')))
            except ValueError as exc:
                common.throttled_warning(self, f'tracks: object {o.id} skipped: {exc}')
        command = self.stage.update(stamp, rows)
        if command is None:
            return
        names = [self.params.sections[''].pan_joint, self.params.sections[''].tilt_joint]
        exact = msg.markers[0].header.stamp
        self.command_pub.publish(restamp(joint_state_msg(
            self.factory, stamp, names, [command.pan, command.tilt]), exact))
        self.target_pub.publish(restamp(point_stamped_msg(
            self.factory, stamp, frame_id or 'odom', command.aim_x, command.aim_y), exact))


def main(args=None) -> None:
    common.run(ActiveHeadNode, args)


if __name__ == '__main__':
    main()
