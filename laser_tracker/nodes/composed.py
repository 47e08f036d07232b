"""``laser_tracker_all``: ego-motion, detection, tracking and the active head in one process.

The nodes are the same classes as the separate executables, sharing one executor (they still
talk over their topics). The SICK driver stays a process of its own (``sick_lms_driver``), so
a serial fault never stalls tracking.
"""
from __future__ import annotations

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from laser_tracker.nodes.active_head import ActiveHeadNode
from laser_tracker.nodes.detection import DetectionNode
from laser_tracker.nodes.ego_motion import EgoMotionNode
from laser_tracker.nodes.tracking import TrackingNode

NODE_CLASSES = (EgoMotionNode, DetectionNode, TrackingNode, ActiveHeadNode)


def main(args=None) -> None:
    rclpy.init(args=args)
    nodes = []
    executor = SingleThreadedExecutor()
    try:
        for cls in NODE_CLASSES:
            nodes.append(cls())
            executor.add_node(nodes[-1])
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
