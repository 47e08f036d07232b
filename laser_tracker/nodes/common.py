"""What the node shells share: running a node, declaring pipeline sections, pairing streams."""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable

import rclpy

from laser_tracker.conversions import scan_from_msg
from laser_tracker.core.scan import Scan, ScanError
from laser_tracker.nodes.params import declare_section
from laser_tracker.parameters import NODE_SECTIONS


def declare_node_parameters(node, node_name: str) -> dict:
    """Declare every parameter of ``node_name`` (``laser_tracker.parameters``); return
    ``{section prefix: section instance}`` ('' = the node's plain-named parameters)."""
    return {prefix: declare_section(node, cls, prefix)
            for prefix, cls in NODE_SECTIONS[node_name].items()}


def scan_or_warn(node, msg) -> Scan | None:
    """The Scan of a LaserScan message, or None after a throttled warning saying why."""
    try:
        return scan_from_msg(msg)
    except ScanError as exc:
        node.get_logger().warning(f'scan skipped: {exc}', throttle_duration_sec=5.0)
        return None


def run(node_factory: Callable[[], object], args=None) -> None:
    """``rclpy.init``, spin one node until Ctrl-C or shutdown, clean up."""
    rclpy.init(args=args)
    node = None
    try:
        node = node_factory()
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    except rclpy.executors.ExternalShutdownException:
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


class StampPairer:
    """Pairs two message streams by identical stamps (an exact-time synchroniser).

    Keeps at most ``depth`` unmatched items per side; the oldest are dropped first.
    """

    def __init__(self, on_pair: Callable[[object, object], None], depth: int = 20):
        self.on_pair = on_pair
        self.depth = depth
        self.left: OrderedDict[int, object] = OrderedDict()
        self.right: OrderedDict[int, object] = OrderedDict()
        self.dropped = 0

    def add_left(self, stamp_ns: int, item) -> None:
        self._add(stamp_ns, item, self.left, self.right, left_first=True)

    def add_right(self, stamp_ns: int, item) -> None:
        self._add(stamp_ns, item, self.right, self.left, left_first=False)

    def _add(self, stamp_ns, item, mine, other, left_first) -> None:
        match = other.pop(stamp_ns, None)
        if match is None:
            mine[stamp_ns] = item
            while len(mine) > self.depth:
                mine.popitem(last=False)
                self.dropped += 1
            return
        # Everything older than a matched stamp can no longer be matched in order.
        for buf in (mine, other):
            for old in [k for k in buf if k < stamp_ns]:
                del buf[old]
                self.dropped += 1
        self.on_pair(*((item, match) if left_first else (match, item)))
