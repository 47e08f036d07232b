"""``laser_tracker_all``: ego-motion, detection, tracking and the active head in one process.

The nodes are the same classes as the separate executables, sharing one executor (they still
talk over their topics). The SICK driver stays a process of its own (``sick_lms_driver``), so
a serial fault never stalls tracking.
"""
from __future__ import annotations

from laser_tracker.nodes import common
from laser_tracker.nodes.active_head import ActiveHeadNode
from laser_tracker.nodes.detection import DetectionNode
from laser_tracker.nodes.ego_motion import EgoMotionNode
from laser_tracker.nodes.tracking import TrackingNode

NODE_CLASSES = (EgoMotionNode, DetectionNode, TrackingNode, ActiveHeadNode)


def main(args=None) -> None:
    common.run(NODE_CLASSES, args, name='laser_tracker_all')


if __name__ == '__main__':
    main()
