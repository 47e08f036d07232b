"""Node ``detection``: occupancy grid, difference map (Eq. 1) and 4-connected blobs.

Subscribes ``scan`` (sensor_msgs/LaserScan), ``ego_motion`` (nav_msgs/Odometry: the scanner
pose per scan) and ``ego_motion/status`` (diagnostic_msgs/DiagnosticArray: may the pose be
trusted; ``status_topic``, '' to trust every pose, e.g. when another localisation publishes
``ego_motion``), joins them by identical header stamps, and publishes ``blobs``
(visualization_msgs/MarkerArray, schema in README.md): what detection found in each scan
(``core.detections.Detections``: motion blobs, people, segments) in the odometry frame,
stamped exactly as the scan.

The node is convert -> ``core.stages.Detector`` -> convert; the stage owns the stream rules
(time going backwards, duplicates, gaps, a restarted pose chain) and the pose gate, and turns
a scan over when its pose says so (an upside-down scanner, ``ego_motion/status``).
Parameters: ``grid.*``, ``difference.*``, ``blobs.*``, ``segments.*``, ``person_detector.*``
(changeable at run time) and ``status_topic`` (read-only). A person-detector model that
cannot be loaded is a warning: the motion method keeps running.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import MarkerArray

from laser_tracker.conversions import (detections_to_marker_array, ego_motion_from_msgs,
                                       restamp_ns, ros_factory, scan_from_msg, stamp_to_ns)
from laser_tracker.core.stages import Detector
from laser_tracker.core.stream import StampPairer
from laser_tracker.nodes import common
from laser_tracker.nodes.params import LiveParameters


class DetectionNode(Node):
    def __init__(self, **kwargs):
        super().__init__('detection', **kwargs)
        self.params = LiveParameters(self, 'detection', self.apply_parameters)
        s = self.params.sections
        self.stage = Detector(s['grid'], s['difference'], s['blobs'], s['person_detector'],
                              segments=s['segments'])
        self.factory = ros_factory()
        status_topic = s[''].status_topic
        streams = ('scan', 'pose', 'status') if status_topic else ('scan', 'pose')
        self.pairer = StampPairer(streams, common.guarded(self, 'blobs')(self.on_pair))
        self.blobs_pub = self.create_publisher(MarkerArray, 'blobs', common.RELIABLE_OUT)
        guard = common.guarded
        scans = self.create_subscription(LaserScan, 'scan', guard(self, 'scan')(self.on_scan),
                                         common.SENSOR_IN)
        self.scan_watch = common.ScanWatch.of(self, scans.topic_name)
        self.create_subscription(Odometry, 'ego_motion', guard(self, 'ego_motion')(
            lambda msg: self.pairer.add('pose', stamp_to_ns(msg.header.stamp), msg)),
            common.SENSOR_IN)
        if status_topic:
            self.create_subscription(DiagnosticArray, status_topic, guard(self, status_topic)(
                lambda msg: self.pairer.add('status', stamp_to_ns(msg.header.stamp), msg)),
                common.SENSOR_IN)
        common.announce(self, 'blobs in the frame of the ego_motion poses' + (
            '' if status_topic else '; every pose trusted (status_topic is empty)'))

    def apply_parameters(self, sections: dict) -> None:
        self.stage.reconfigure(sections['grid'], sections['difference'], sections['blobs'],
                               sections['person_detector'], sections['segments'])

    def on_scan(self, msg: LaserScan) -> None:
        self.scan_watch.seen()
        scan = scan_from_msg(msg)
        self.pairer.add('scan', scan.stamp_ns, scan)

    def on_pair(self, items: dict) -> None:
        pose = ego_motion_from_msgs(items['pose'], items.get('status'))
        detection = self.stage.update(items['scan'], pose)
        if detection is None:
            return
        found = detection.detections
        msg = detections_to_marker_array(self.factory, found)
        self.blobs_pub.publish(restamp_ns(self.factory, msg, found.stamp_ns))


def main(args=None) -> None:
    common.run(DetectionNode, args)


if __name__ == '__main__':
    main()
