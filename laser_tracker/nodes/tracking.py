"""Node ``tracking``: movement hypotheses with a Kalman filter each (paper Sec. 7-9).

Subscribes ``blobs`` (from the ``detection`` node: motion blobs, people and segments,
``core.detections.Detections``). Publishes ``tracks``: the confirmed
moving objects, and ``hypotheses``: every live hypothesis, both as
visualization_msgs/MarkerArray in the moving-object schema (README.md, "Topics and schemas";
``text`` carries ``weight``, ``confirmed``, ``samples``, ``kind``, ``moving`` and the position
``covariance``), in the odometry frame, stamped exactly as the scan; and ``tracks/markers``,
what RViz draws of them: a label (id, kind, speed) and a velocity arrow per hypothesis
(``conversions.track_markers``; ``laser-tracker replay --record`` writes the same).

The node is convert -> ``core.stages.Tracker`` -> convert; the stage owns the stream rules (a
duplicate blobs message, e.g. from a second publisher, is skipped; time going backwards or a
restarted pose chain starts afresh). Parameters ``hypotheses.*`` and ``kalman.*`` change at
run time.
"""
from __future__ import annotations

from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from laser_tracker.conversions import detections_from_marker_array, ros_factory, tracker_msgs
from laser_tracker.core.stages import Tracker
from laser_tracker.nodes import common
from laser_tracker.nodes.params import LiveParameters


class TrackingNode(Node):
    def __init__(self, **kwargs):
        super().__init__('tracking', **kwargs)
        self.params = LiveParameters(self, 'tracking', self.apply_parameters)
        s = self.params.sections
        self.stage = Tracker(s['hypotheses'], s['kalman'])
        self.factory = ros_factory()
        self.tracks_pub = self.create_publisher(MarkerArray, 'tracks', common.RELIABLE_OUT)
        self.hypotheses_pub = self.create_publisher(MarkerArray, 'hypotheses',
                                                    common.RELIABLE_OUT)
        self.markers_pub = self.create_publisher(MarkerArray, 'tracks/markers',
                                                 common.RELIABLE_OUT)
        self.create_subscription(MarkerArray, 'blobs',
                                 common.guarded(self, 'blobs')(self.on_blobs), 10)
        common.announce(self, 'tracks in the frame of the blobs')

    def apply_parameters(self, sections: dict) -> None:
        self.stage.reconfigure(sections['hypotheses'], sections['kalman'])

    def on_blobs(self, msg: MarkerArray) -> None:
        found = detections_from_marker_array(msg)
        if self.stage.update(found) is None:
            return
        tracks, hypotheses, markers = tracker_msgs(self.factory, self.stage.tracks(),
                                                   found.stamp, found.frame_id, found.stamp_ns)
        self.tracks_pub.publish(tracks)
        self.hypotheses_pub.publish(hypotheses)
        self.markers_pub.publish(markers)


def main(args=None) -> None:
    common.run(TrackingNode, args)


if __name__ == '__main__':
    main()
