"""``laser-tracker play BAG``: publish a recording into ROS 2, as ``ros2 bag play`` does.

For the node path on an install without the ros2 CLI (PyPI wheels). Every topic of a rosbag2
(sqlite3 or mcap) or ROS 1 recording, or ``--topics``, is published with rclpy at the
recording's receive-time spacing divided by ``--rate``, each message exactly as recorded
(its own header stamps). ``--clock`` also publishes ``/clock`` (rosgraph_msgs/Clock) with
the recording's receive times, before each message and at :data:`CLOCK_HZ` in between, so
nodes with ``use_sim_time`` follow the recording's time.

Messages are passed on serialized: a rosbag2 message as recorded, a ROS 1 message converted
to ROS 2 CDR, and a message whose definition differs from the Jazzy one migrated field by
field (``tools.bag.cdr_converter``). A topic whose message package has no Python module here
(``tf2_msgs`` is not among the PyPI wheels; a recording's custom types) is not played, and
the start line says so. Topics recorded as latched (transient local, e.g. ``/tf_static``) are
published transient local, so late subscribers get them.

Before the first message it waits up to ``--wait`` s for a subscriber on the LaserScan
topics (discovery takes a moment, and DDS does not keep what was published before it). One
line at the start (what, how long), one at the end; Ctrl-C stops at once (status 130).
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from laser_tracker.conversions import time_msg
from laser_tracker.errors import InputFileError, LaserTrackerError

CLOCK_HZ = 40.0          # /clock between messages (ros2 bag play's default)
NODE_NAME = 'laser_tracker_play'
LATCHED_DEPTH = 100      # a late subscriber gets up to this many messages of a latched topic
DEPTH = 100
SETTLE = 0.5             # s without a new subscription before the first message
LINGER = 0.3             # s the publishers stay after the last message


@dataclass
class Channel:
    """One topic to play: its type, message count, the rclpy class and how a record
    becomes the CDR rclpy publishes."""

    topic: str
    msgtype: str
    count: int
    latched: bool
    message_class: type
    convert: Callable[[bytes], bytes]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', metavar='BAG', help='a rosbag2 folder, a ROS 1 .bag file, or '
                        'the name of a bundled recording')
    parser.add_argument('--clock', action='store_true',
                        help='also publish /clock from the receive times (for nodes with '
                        'use_sim_time:=true)')
    parser.add_argument('--rate', type=float, default=1.0, metavar='R',
                        help='speed factor (default 1: as recorded; 2: twice as fast)')
    parser.add_argument('--topics', nargs='+', metavar='TOPIC',
                        help='topics to play (default: all; at least one LaserScan topic)')
    parser.add_argument('--start', type=float, default=0.0, metavar='S',
                        help='start S seconds into the recording (default 0)')
    parser.add_argument('--loop', action='store_true', help='play again and again until Ctrl-C')
    parser.add_argument('--wait', type=float, default=3.0, metavar='S',
                        help='wait up to S seconds for a subscriber on the LaserScan topics '
                        'before the first message (default 3; 0: start at once)')


def plan(reader, path: Path, topic_names=None) -> tuple[list[Channel], dict[str, str]]:
    """The channels to play from an open reader, and ``{topic: why it is not played}``.

    InputFileError: a ``topic_names`` entry the recording lacks, or no LaserScan topic.
    """
    from laser_tracker.conversions import ros_factory
    from laser_tracker.tools.bag import (SCAN_MSGTYPE, absolute_topic, cdr_converter,
                                         recorded_as_latched)

    by_topic: dict[str, list] = {}
    for conn in reader.connections:
        by_topic.setdefault(conn.topic, []).append(conn)
    if topic_names:
        wanted = [absolute_topic(t) for t in topic_names]
        missing = [t for t in wanted if t not in by_topic]
        if missing:
            raise InputFileError(path, f'--topics: no topic {", ".join(missing)}; it has: '
                                 f'{", ".join(sorted(by_topic))}')
        by_topic = {t: by_topic[t] for t in dict.fromkeys(wanted)}
    scans = sorted(t for t, conns in by_topic.items() if conns[0].msgtype == SCAN_MSGTYPE)
    if not scans:
        has = ', '.join(f'{t} ({conns[0].msgtype})' for t, conns in sorted(by_topic.items()))
        what = 'the topics given with --topics include' if topic_names else 'it has'
        raise InputFileError(path, f'no LaserScan topic to play ({what}: {has or "nothing"})')
    channels, skipped = [], {}
    for topic, conns in by_topic.items():
        msgtype = conns[0].msgtype
        if any(c.msgtype != msgtype for c in conns):
            skipped[topic] = 'recorded with several message types'
            continue
        try:
            cls = ros_factory().message_class(msgtype)
        except (ImportError, AttributeError):
            skipped[topic] = (f'{msgtype}: no Python module {msgtype.split("/")[0]} '
                              'installed here')
            continue
        convert = cdr_converter(reader, msgtype)
        if convert is None:
            skipped[topic] = f'{msgtype}: a ROS 1 type that ROS 2 Jazzy does not define'
            continue
        channels.append(Channel(topic, msgtype, sum(c.msgcount for c in conns),
                                any(recorded_as_latched(c) for c in conns), cls, convert))
    return channels, skipped


class Player:
    """Publishes records of a reader on ``node`` (publishers made once) at the recording's
    pace; ``play`` returns the number of messages published."""

    def __init__(self, node, channels: list[Channel], rate: float = 1.0, clock: bool = False):
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        self.node, self.rate = node, rate
        self.channels = {c.topic: c for c in channels}
        self.publishers = {}
        for c in channels:
            qos = QoSProfile(depth=min(max(c.count, 1), LATCHED_DEPTH) if c.latched else DEPTH,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL if c.latched
                             else DurabilityPolicy.VOLATILE)
            self.publishers[c.topic] = node.create_publisher(c.message_class, c.topic, qos)
        self.clock = None
        if clock:
            from rosgraph_msgs.msg import Clock

            from laser_tracker.conversions import ros_factory
            self.clock = node.create_publisher(Clock, '/clock', QoSProfile(
                depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
            self._clock_message, self._factory = Clock, ros_factory()
        self.published = 0
        self.played_ns = 0
        self.unconverted: Counter = Counter()

    def wait_for_subscribers(self, topics: list[str], timeout: float) -> bool:
        """Wait up to ``timeout`` s until each of ``topics`` has a subscriber, then until the
        subscriptions of every topic have stayed as they are for :data:`SETTLE` s (the other
        topics of the subscribing nodes are discovered a moment later)."""
        deadline = time.monotonic() + timeout
        counts, since = None, time.monotonic()
        while time.monotonic() < deadline:
            now = [p.get_subscription_count() for p in self.publishers.values()]
            if now != counts:
                counts, since = now, time.monotonic()
            if (all(self.publishers[t].get_subscription_count() > 0 for t in topics)
                    and time.monotonic() - since >= SETTLE):
                return True
            time.sleep(0.05)
        return False

    def play(self, records) -> int:
        """Publish ``(connection, receive ns, raw)`` records at their pace (``rate``)."""
        wall0 = bag0 = None
        count = 0
        for conn, t_ns, raw in records:
            channel = self.channels.get(conn.topic)
            if channel is None:
                continue
            if wall0 is None:
                wall0, bag0 = time.monotonic(), t_ns
            due = wall0 + (t_ns - bag0) * 1e-9 / self.rate
            self._wait_until(due, wall0, bag0, t_ns)
            self._publish_clock(t_ns)
            try:
                data = channel.convert(raw)
            except Exception as exc:  # noqa: BLE001 - a damaged message is skipped
                if not self.unconverted[conn.topic]:
                    print(f'{conn.topic}: a message that cannot be converted is skipped '
                          f'({type(exc).__name__}: {exc})', file=sys.stderr, flush=True)
                self.unconverted[conn.topic] += 1
                continue
            self.publishers[conn.topic].publish(data)
            count += 1
            self.published += 1
            self.played_ns = t_ns - bag0
        return count

    def _wait_until(self, due: float, wall0: float, bag0: int, next_ns: int) -> None:
        """Sleep until ``due`` (monotonic s), publishing /clock at CLOCK_HZ meanwhile."""
        while True:
            left = due - time.monotonic()
            if left <= 0:
                return
            if self.clock is not None:
                now_ns = bag0 + int((time.monotonic() - wall0) * self.rate * 1e9)
                self._publish_clock(min(now_ns, next_ns))
            time.sleep(min(left, 1.0 / CLOCK_HZ))

    def _publish_clock(self, t_ns: int) -> None:
        if self.clock is not None:
            self.clock.publish(self._clock_message(clock=time_msg(self._factory, t_ns)))

    def flush(self, timeout: float = 0.5) -> None:
        """Before the node goes: give reliable subscribers up to ``timeout`` s in all to
        acknowledge what was published, and best-effort ones (which never do) :data:`LINGER`
        s to take the last messages."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout
        for pub in self.publishers.values():
            left = deadline - time.monotonic()
            if left <= 0:
                break
            pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))
        time.sleep(LINGER)


def _describe(channels: list[Channel], skipped: dict[str, str]) -> str:
    parts = [f'{c.topic} {c.count}' + (' (latched)' if c.latched else '') for c in channels]
    text = ', '.join(parts)
    if skipped:
        text += '; not played: ' + ', '.join(f'{t} ({why})' for t, why in skipped.items())
    return text


def run(args: argparse.Namespace) -> int:
    from laser_tracker.tools.bag import open_reader, resolve_bag

    if not args.rate > 0:
        raise LaserTrackerError(f'--rate must be above 0, got {args.rate}')
    if args.start < 0:
        raise LaserTrackerError(f'--start must be 0 or more, got {args.start}')
    bag = resolve_bag(args.bag)
    reader = open_reader(bag)
    try:
        channels, skipped = plan(reader, bag, args.topics)
        length = (reader.end_time - reader.start_time) * 1e-9 - args.start
        if length <= 0:
            raise InputFileError(bag, f'--start {args.start:g}: the recording lasts only '
                                 f'{length + args.start:.1f} s')
        start = (f'playing {bag.name}: {_describe(channels, skipped)}; {length:.1f} s'
                 + (f' from {args.start:g} s' if args.start else '')
                 + (f' at rate {args.rate:g} ({length / args.rate:.1f} s)' if args.rate != 1
                    else '')
                 + ('; /clock' if args.clock else '') + ('; looping' if args.loop else '')
                 + '; Ctrl-C stops')
        return _play(reader, bag, channels, args, start)
    finally:
        reader.close()


def _play(reader, bag: Path, channels: list[Channel], args: argparse.Namespace,
          start_line: str) -> int:
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from laser_tracker.tools.bag import SCAN_MSGTYPE, iter_records

    start_ns = reader.start_time + int(round(args.start * 1e9))
    node = player = None
    try:
        print(start_line, flush=True)
        rclpy.init(args=['laser-tracker'], signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node(NODE_NAME)
        player = Player(node, channels, args.rate, args.clock)
        scans = [c.topic for c in channels if c.msgtype == SCAN_MSGTYPE]
        if args.wait > 0 and not player.wait_for_subscribers(scans, args.wait):
            print(f'no subscriber on {", ".join(scans)} after {args.wait:g} s: playing anyway',
                  flush=True)
        wall0, loops = time.monotonic(), 0
        conns = [c for c in reader.connections if c.topic in player.channels]
        while not loops or args.loop:
            player.play(iter_records(reader, bag, conns, start_ns))
            loops += 1
        wall = time.monotonic() - wall0
        player.flush()
        unconverted = sum(player.unconverted.values())
        print(f'played {player.published} messages ({player.played_ns * 1e-9:.1f} s of the '
              f'recording' + (f', {loops} times' if loops > 1 else '') + f') in {wall:.1f} s'
              + (f'; {unconverted} that could not be converted skipped' if unconverted else ''))
        return 0
    except KeyboardInterrupt:
        print(f'stopped (Ctrl-C) after {player.published if player else 0} messages',
              flush=True)
        return 130
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
