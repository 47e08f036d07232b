"""What the node shells share: running nodes, guarded callbacks, QoS profiles, start-up
and no-scan messages.

* :func:`run` starts one or more nodes in one executor and stops them within a second or two
  of Ctrl-C or SIGTERM, every time: rclpy's own signal handling is replaced by a flag that
  the spin loop checks (and a node's ``request_stop()``, if it has one, is called so that a
  long callback such as a lifecycle configure gives up), cleanup runs under a watchdog, a
  Ctrl-C while the nodes are still being made (imports, loading or compiling the kernels)
  ends the process at once (nothing runs yet that needs stopping), and a start-up
  configuration error is one line on stderr with exit status 2 (no traceback):
  the ROS arguments are checked before ``rclpy.init`` (:func:`check_ros_arguments`: parameter
  files, ``-p`` and ``-r`` rules, log levels), and whatever rcl or a node constructor still
  refuses is caught and said in one line.
* :func:`announce` logs a node's start-up line (resolved topics, frames) and starts its
  :class:`OutputWatch` (another node publishing on one of its outputs); :class:`ScanWatch`
  warns, rarely, when no scan arrives.
* :func:`guarded` wraps a subscription callback so that no message can kill a node: anything
  a publisher on the same topic can send that the conversions or the stage cannot use is a
  throttled warning (with a count) and the node carries on.
"""
from __future__ import annotations

import functools
import os
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from laser_tracker.config import ConfigError
from laser_tracker.nodes import params

#: Sensor streams we read: best effort, so both best-effort and reliable publishers reach us.
SENSOR_IN = qos_profile_sensor_data
#: What we publish: reliable, so default-QoS subscribers (RViz, users' nodes) receive it too.
RELIABLE_OUT = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: Odometry in: best effort, deeper (it comes in bursts at a higher rate than scans).
ODOMETRY_IN = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)

STOP_TIMEOUT = 1.5   # s: cleanup after a stop request never takes longer than this
WARNING_PERIOD = 5.0  # s between two warnings of the same kind from one node
NO_SCAN_WARNING = 5.0  # s without a scan before ScanWatch warns (then 10, 20, 40, ... s)
OUTPUT_CHECK_PERIOD = 5.0  # s between two looks for other publishers on a node's outputs
ROS_OWN_TOPICS = ('/rosout', '/parameter_events')
#: Topics that many nodes publish by design.
SHARED_TOPICS = ROS_OWN_TOPICS + ('/diagnostics',)
LOG_LEVELS = ('DEBUG', 'INFO', 'WARN', 'ERROR', 'FATAL', 'UNSET')


def guarded(node, what: str):
    """Decorator: exceptions of the callback become a throttled warning naming ``what``;
    ``node.dropped[what]`` counts them."""
    if not hasattr(node, 'dropped'):
        node.dropped = Counter()

    def wrap(callback: Callable):
        @functools.wraps(callback)
        def safe(*args, **kwargs):
            try:
                return callback(*args, **kwargs)
            except Exception as exc:  # noqa: BLE001 - a node never dies on a message
                node.dropped[what] += 1
                node.get_logger().warning(
                    f'{what}: message dropped ({type(exc).__name__}: {exc}); '
                    f'{node.dropped[what]} dropped so far', throttle_duration_sec=WARNING_PERIOD)
        return safe
    return wrap


def throttled_warning(node, text: str) -> None:
    node.get_logger().warning(text, throttle_duration_sec=WARNING_PERIOD)


def topics_line(node) -> str:
    """``subscribes A, B; publishes C, D``: the node's topics as resolved (namespace and
    remapping applied), ROS's own (/rosout, /parameter_events) left out."""
    def names(endpoints):
        found = [e.topic_name for e in endpoints]
        return ', '.join(t for t in dict.fromkeys(found) if t not in ROS_OWN_TOPICS) or 'nothing'
    return f'subscribes {names(node.subscriptions)}; publishes {names(node.publishers)}'


def announce(node, frames: str) -> None:
    """The start-up line: the node's resolved topics and its frames; its outputs watched
    from now on (:class:`OutputWatch`)."""
    node.get_logger().info(f'started as {node.get_fully_qualified_name()}: '
                           f'{topics_line(node)}; {frames}')
    node.output_watch = OutputWatch(node)


class OutputWatch:
    """Warns, once per topic, when another node publishes on one of this node's outputs
    (checked every :data:`OUTPUT_CHECK_PERIOD` s of wall time): two pipelines in one
    namespace, one per scanner, would mix their poses, blobs or tracks, and every subscriber
    would take them for one stream."""

    def __init__(self, node):
        self.node = node
        self.warned: set[str] = set()
        node.create_timer(OUTPUT_CHECK_PERIOD, self.check,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def check(self) -> None:
        own = Counter(p.topic_name for p in self.node.publishers)
        for topic, count in own.items():
            if topic in SHARED_TOPICS or topic in self.warned:
                continue
            others = self.node.count_publishers(topic) - count
            if others > 0:
                self.warned.add(topic)
                self.node.get_logger().warning(
                    f'{others} other publisher(s) on {topic}, an output of this node: its '
                    'subscribers get both streams mixed. Two pipelines (one per scanner) need '
                    'a namespace each (-r __ns:=/left); `ros2 topic info -v '
                    f'{topic}` lists the publishers')


class ScanWatch:
    """Warns when no scan arrived on the node's scan subscription for
    :data:`NO_SCAN_WARNING` s (wall time, so it works with use_sim_time and no /clock), and
    again each time the silence doubles: rarely, never a flood. Call :meth:`seen` per scan.

    Nodes of one process that read the same topic share one watch (:meth:`of`), so
    ``laser_tracker_all`` says it once."""

    _shared: dict[str, ScanWatch] = {}

    @classmethod
    def of(cls, node, topic: str) -> ScanWatch:
        watch = cls._shared.get(topic)
        if watch is None or watch.node.context is not node.context or not watch.node.context.ok():
            watch = cls._shared[topic] = cls(node, topic)
        return watch

    def __init__(self, node, topic: str):
        self.node, self.topic = node, topic
        self.last = time.monotonic()
        self.received = False
        self.next_warning = NO_SCAN_WARNING
        node.create_timer(1.0, self.check, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def seen(self) -> None:
        self.last = time.monotonic()
        self.received = True
        self.next_warning = NO_SCAN_WARNING

    def check(self) -> None:
        silent = time.monotonic() - self.last
        if silent < self.next_warning:
            return
        self.next_warning *= 2
        when = 'the last one' if self.received else 'none since start-up'
        self.node.get_logger().warning(
            f'no scan on {self.topic} for {silent:.0f} s ({when}): is the scanner driver '
            f'(or `laser-tracker play BAG`) publishing it? `ros2 topic info -v {self.topic}` '
            'shows its publishers; fix with -r scan:=YOUR_TOPIC, the namespace (-r __ns:=...) '
            'or ROS_DOMAIN_ID')


def check_ros_arguments(args: Iterable[str] | None) -> list[str]:
    """Check the ROS command-line arguments that rcl would refuse with an rcl error and a
    traceback (parameter files, ``-p`` and ``-r`` rules, log levels), so the user gets one
    line naming the argument and the fix (ConfigError); returns the ``--params-file``
    paths."""
    from laser_tracker import parameters as registry

    args = list(sys.argv if args is None else args)
    files, in_ros = [], False
    for i, arg in enumerate(args):
        value = args[i + 1] if i + 1 < len(args) else None
        if arg == '--ros-args':
            in_ros = True
        elif arg == '--':
            in_ros = False
        elif not in_ros:
            continue
        elif arg == '--params-file' and value is not None:
            try:
                registry.read_files([value])
            except ConfigError as exc:
                hint = (f'; check it with `laser-tracker config --check {value}`'
                        if os.path.isfile(value) else '')
                raise ConfigError(f'--params-file {exc}{hint}') from None
            files.append(value)
        elif arg in ('-p', '--param') and value is not None:
            _check_parameter_rule(arg, value)
        elif arg in ('-r', '--remap') and value is not None:
            _check_remap_rule(arg, value)
        elif arg == '--log-level' and value is not None:
            if value.rpartition(':=')[2].upper() not in LOG_LEVELS:
                raise ConfigError(f'--log-level {value}: not a log level (one of '
                                  f'{", ".join(LOG_LEVELS).lower()}; or LOGGER:=LEVEL)')
    return files


def _split_rule(option: str, rule: str, form: str) -> tuple[str, str]:
    name, sep, value = rule.partition(':=')
    if not sep or not name:
        raise ConfigError(f'{option} {rule}: expected {form}')
    return name.rpartition(':')[2], value      # 'node:name:=value' addresses one node


def _check_parameter_rule(option: str, rule: str) -> None:
    import yaml

    _, value = _split_rule(option, rule, 'NAME:=VALUE (e.g. -p hypotheses.gate:=1.0)')
    try:
        yaml.safe_load(value)
    except yaml.YAMLError as exc:
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        raise ConfigError(f'{option} {rule}: the value is not valid YAML ({problem}); a '
                          'value is a number, true/false, a string (quote it if it has '
                          "special characters: -p 'NAME:=\"a: b\"') or a list [1.0, 2.0]") \
            from None


def _check_remap_rule(option: str, rule: str) -> None:
    from rclpy.exceptions import (InvalidNamespaceException, InvalidNodeNameException,
                                  InvalidTopicNameException)
    from rclpy.validate_namespace import validate_namespace
    from rclpy.validate_node_name import validate_node_name
    from rclpy.validate_topic_name import validate_topic_name

    source, target = _split_rule(option, rule, 'FROM:=TO (e.g. -r scan:=front_scan)')
    if source == '__ns':
        names, check = [target], validate_namespace
    elif source in ('__node', '__name'):
        names, check = [target], validate_node_name
    elif source.startswith('__'):
        return                                  # rcl's other special rules: rcl decides
    else:
        names, check = [source, target], validate_topic_name
    try:
        for name in names:
            check(name)
    except (InvalidNamespaceException, InvalidNodeNameException,
            InvalidTopicNameException) as exc:
        raise ConfigError(f'{option} {rule}: {" ".join(str(exc).split()).rstrip(" ^")}') \
            from None


def _init_error(exc: Exception) -> ConfigError:
    """rclpy.init's refusal of the command line as one line."""
    if type(exc).__name__ == 'UnknownROSArgsError':     # its message: "['--bogus']"
        unknown = str(exc).strip('[]').replace("'", '')
        return ConfigError(f'{unknown}: not a ROS argument (after --ros-args come -p '
                           'NAME:=VALUE, -r FROM:=TO, --params-file FILE, --log-level LEVEL; '
                           "end them with -- before the program's own arguments)")
    text = ' '.join(str(exc).split())
    return ConfigError(f'the ROS arguments were refused: {text.split(", at ")[0]}')


def run(factories: Callable | Iterable[Callable], args=None, name: str | None = None) -> None:
    """Run the nodes made by ``factories`` in one executor until Ctrl-C, SIGTERM or an
    external shutdown; exit status 0, or 2 after a configuration error (one line)."""
    factories = [factories] if callable(factories) else list(factories)
    name = name or os.path.basename(sys.argv[0] or 'laser_tracker')
    stop = threading.Event()
    spinning = threading.Event()
    nodes = []

    def on_signal(signum, frame):
        if stop.is_set():            # a second Ctrl-C: leave at once
            os._exit(130)
        stop.set()
        if not spinning.is_set():    # still starting (imports, compiled kernels): leave now,
            _leave(0)                # not at whatever line of numba or rcl runs at this moment
        for node in nodes:           # a callback in progress (e.g. a configure) gives up
            try:
                getattr(node, 'request_stop', lambda: None)()
            except Exception:  # noqa: BLE001 - stopping regardless
                pass

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    status = 0
    from rclpy.signals import SignalHandlerOptions
    executor = None
    try:
        params.PARAMETER_FILES[:] = check_ros_arguments(args)
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        except Exception as exc:  # noqa: BLE001 - RCLError, UnknownROSArgsError, ...
            raise _init_error(exc) from None
        executor = SingleThreadedExecutor()
        for factory in factories:
            try:
                nodes.append(factory())
            except (ConfigError, KeyboardInterrupt):
                raise
            except Exception as exc:  # noqa: BLE001 - e.g. a remapping to an invalid name
                raise ConfigError(f'cannot start: {" ".join(str(exc).split())}') from None
            executor.add_node(nodes[-1])
        spinning.set()
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except ConfigError as exc:
        print(f'{name}: {exc}', file=sys.stderr, flush=True)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        _shutdown(executor, nodes, status)
        for s, handler in old.items():
            signal.signal(s, handler)
    if status:
        sys.exit(status)


def _shutdown(executor, nodes, status: int) -> None:
    """Destroy the nodes and shut rclpy down; if that hangs, leave after STOP_TIMEOUT."""
    watchdog = threading.Timer(STOP_TIMEOUT, _leave, (status,))
    watchdog.daemon = True
    watchdog.start()
    try:
        for node in nodes:
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - shutting down regardless
                pass
        if executor is not None:
            executor.shutdown(timeout_sec=0.5)
        rclpy.try_shutdown()
    except Exception:  # noqa: BLE001
        pass
    finally:
        watchdog.cancel()


def _leave(status: int) -> None:
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
