"""What the node shells share: running nodes, guarded callbacks, QoS profiles.

* :func:`run` starts one or more nodes in one executor and stops them within a second or two
  of Ctrl-C or SIGTERM, every time: rclpy's own signal handling is replaced by a flag that
  the spin loop checks (and a node's ``request_stop()``, if it has one, is called so that a
  long callback such as a lifecycle configure gives up), cleanup runs under a watchdog, and
  a start-up configuration error is one line on stderr with exit status 2 (no traceback).
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
from collections import Counter
from collections.abc import Callable, Iterable

import rclpy
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


def parameter_files(args: Iterable[str] | None) -> list[str]:
    """The ``--params-file`` paths among ROS command-line arguments."""
    args = list(sys.argv if args is None else args)
    files, in_ros = [], False
    for i, arg in enumerate(args):
        if arg == '--ros-args':
            in_ros = True
        elif arg == '--':
            in_ros = False
        elif in_ros and arg == '--params-file' and i + 1 < len(args):
            files.append(args[i + 1])
    return files


def run(factories: Callable | Iterable[Callable], args=None, name: str | None = None) -> None:
    """Run the nodes made by ``factories`` in one executor until Ctrl-C, SIGTERM or an
    external shutdown; exit status 0, or 2 after a configuration error (one line)."""
    factories = [factories] if callable(factories) else list(factories)
    name = name or os.path.basename(sys.argv[0] or 'laser_tracker')
    params.PARAMETER_FILES[:] = parameter_files(args)
    stop = threading.Event()
    nodes = []

    def on_signal(signum, frame):
        if stop.is_set():            # a second Ctrl-C: leave at once
            os._exit(130)
        stop.set()
        for node in nodes:           # a callback in progress (e.g. a configure) gives up
            try:
                getattr(node, 'request_stop', lambda: None)()
            except Exception:  # noqa: BLE001 - stopping regardless
                pass

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    status = 0
    from rclpy.signals import SignalHandlerOptions
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    executor = SingleThreadedExecutor()
    try:
        for factory in factories:
            nodes.append(factory())
            executor.add_node(nodes[-1])
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
