"""Node ``tracking``: movement hypotheses with a Kalman filter each (paper Sec. 7-9).

Subscribes ``blobs`` (from the ``detection`` node). Publishes ``tracks``: the confirmed
moving objects, and ``hypotheses``: every live hypothesis, both as
visualization_msgs/MarkerArray in the moving-object schema (README.md, "Topics and schemas";
``text`` carries ``weight``, ``confirmed`` and ``samples``), in the odometry frame.
"""
from __future__ import annotations

from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from laser_tracker.conversions import (blobs_from_marker_array, hypotheses_to_objects,
                                       objects_to_marker_array, restamp, ros_factory)
from laser_tracker.core.hypotheses import Tracker
from laser_tracker.nodes import common


class TrackingNode(Node):
    def __init__(self, **kwargs):
        super().__init__('tracking', **kwargs)
        sections = common.declare_node_parameters(self, 'tracking')
        self.tracker = Tracker(sections['hypotheses'], sections['kalman'])
        self.factory = ros_factory()
        self.last_stamp: float | None = None
        self.tracks_pub = self.create_publisher(MarkerArray, 'tracks', 10)
        self.hypotheses_pub = self.create_publisher(MarkerArray, 'hypotheses', 10)
        self.create_subscription(MarkerArray, 'blobs', self.on_blobs, 10)

    def on_blobs(self, msg: MarkerArray) -> None:
        try:
            blobs = blobs_from_marker_array(msg)
        except ValueError as exc:
            self.get_logger().warning(f'blobs message skipped: {exc}', throttle_duration_sec=5.0)
            return
        if self.last_stamp is not None and blobs.stamp <= self.last_stamp:
            self.get_logger().warning(f'time went backwards ({self.last_stamp:.3f} -> '
                                      f'{blobs.stamp:.3f} s): tracking restarts')
            self.tracker.reset()
        elif blobs.restarted:
            self.tracker.reset()
        self.last_stamp = blobs.stamp
        frame = self.tracker.update(blobs)
        if frame.bounded:
            self.get_logger().warning('hypothesis bound reached', throttle_duration_sec=5.0)
        f, stamp, frame_id = self.factory, blobs.stamp, blobs.frame_id
        exact = msg.markers[0].header.stamp     # the scan's stamp, bit for bit
        self.tracks_pub.publish(restamp(objects_to_marker_array(
            f, hypotheses_to_objects(frame.hypotheses, True), stamp, frame_id, 'tracks'), exact))
        self.hypotheses_pub.publish(restamp(objects_to_marker_array(
            f, hypotheses_to_objects(frame.hypotheses, False), stamp, frame_id, 'hypotheses',
            color=(0.6, 0.6, 0.6, 0.5)), exact))


def main(args=None) -> None:
    common.run(TrackingNode, args)


if __name__ == '__main__':
    main()
