"""``sick_lms_driver``: a SICK LMS2xx on a serial port -> ``scan`` and ``/diagnostics``.

A lifecycle (managed) node around :class:`laser_tracker.sick.driver.SickLmsDriver`, as ROS 2
laser drivers are:

* ``configure`` opens the port and sets the device up (finds its rate, switches it to
  ``baud``, sets the variant and the units); a failure answers FAILURE with one log line
  naming the port, and the node stays unconfigured, ready for another configure;
* ``activate`` starts the device's continuous output and publishing; a device lost while
  active is re-opened and set up again in the background (``/diagnostics`` says so);
* ``deactivate`` stops the device's output (the port stays open); ``cleanup`` closes the
  port; ``shutdown`` (from any state, and on Ctrl-C) stops the output and closes the port.

With ``autostart`` (default) the node configures and activates itself at start-up, so
``ros2 run laser_tracker sick_lms_driver --ros-args -p port:=/dev/ttyUSB0`` streams at once:
it waits for the device on a background thread (retrying every ``reconnect_period``), then
makes the two transitions. With ``autostart:=false`` it waits for a lifecycle manager
(``ros2 lifecycle set /sick_lms_driver configure``, then ``activate``).

Parameters are the fields of :class:`~laser_tracker.sick.config.SickLmsConfig`. The
connection ones (``CONFIGURE_FIELDS``: port, baud, scan_angle, resolution, units, password)
are read at configure: a change while configured is accepted, logged, listed in
``/diagnostics`` as pending, and applied at the next configure. The others (frame_id,
inverted, time_offset, the timeouts, diagnostics_period) apply at once.

``scan`` (sensor_msgs/LaserScan, reliable, published only while active): header stamp =
estimated acquisition time of the first beam (see the driver's stamp model), ranges without
NaN: +inf for "nothing within range" (REP 117), 0.0 (below ``range_min``) for the device's
other no-measurement codes. ``/diagnostics``: one DiagnosticStatus named
``sick_lms_driver: LMS2xx`` every ``diagnostics_period`` seconds of wall time (also with
``use_sim_time`` and no ``/clock``), with the lifecycle state.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from collections import deque

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from sensor_msgs.msg import LaserScan

from laser_tracker.conversions import ros_factory, scan_to_msg
from laser_tracker.core.scan import ScanError
from laser_tracker.nodes import common
from laser_tracker.nodes.params import LiveParameters
from laser_tracker.sick.config import CONFIGURE_FIELDS
from laser_tracker.sick.driver import SickError, SickLmsConfig, SickLmsDriver, SickScan
from laser_tracker.sick.protocol import StatusByte

NODE_NAME = 'sick_lms_driver'
QUEUE_LENGTH = 8  # scans waiting for the executor; older ones are dropped (and counted)
DIAGNOSTIC_NAME = 'sick_lms_driver: LMS2xx'
REPEAT_LOG_PERIOD = 30.0  # s: an unchanged error is logged again after this long
#: Fields the running driver takes at once (the rest are read at configure or start-up).
LIVE_FIELDS = tuple(f.name for f in dataclasses.fields(SickLmsConfig)
                    if f.name not in CONFIGURE_FIELDS and f.name != 'autostart')

SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE
ERROR = TransitionCallbackReturn.ERROR


class SickLmsDriverNode(LifecycleNode):
    """Publishes the scans of one LMS2xx; never calls ``rclpy.init`` (composable)."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        try:
            self.params = LiveParameters(self, NODE_NAME, self._apply_parameters)
        except BaseException:  # a bad parameter: leave no half-built node in the graph
            super().destroy_node()
            raise
        self.config: SickLmsConfig = self.params.sections['']
        self.driver: SickLmsDriver | None = None  # set while configured
        self._factory = ros_factory()
        self._scan_pub = self.create_lifecycle_publisher(LaserScan, 'scan', common.RELIABLE_OUT)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._queue: deque[SickScan] = deque()
        self._queue_lock = threading.Lock()
        self._published = 0
        self._dropped = 0
        self._unpublishable = 0
        self._last_log: tuple[str, float] = ('', 0.0)
        self._configure_error = ''
        self._stopping = False
        self._guard = self.create_guard_condition(self._publish_pending)
        # Diagnostics on the steady clock: they flow with use_sim_time and no /clock.
        self._wall_clock = Clock(clock_type=ClockType.STEADY_TIME)
        self._diag_timer = self.create_timer(self.config.diagnostics_period,
                                             self.publish_diagnostics, clock=self._wall_clock)
        # autostart: a thread waits for the device, then the executor makes the transitions
        self._waiter: threading.Thread | None = None
        self._waiter_stop = threading.Event()
        self._waiting_driver: SickLmsDriver | None = None
        self._ready_driver: SickLmsDriver | None = None
        self._autostart_guard = self.create_guard_condition(self._autostart_transitions)
        self._destroyed = False
        name = self.get_fully_qualified_name()
        output = (f'scans on {self._scan_pub.topic_name} in frame '
                  f'{self.config.frame_id!r} once active')
        if self.config.autostart:
            self.get_logger().info(f'autostart: waiting for the LMS2xx on {self.config.port}, '
                                   f'then configuring and activating; {output}')
            self._start_waiter()
        else:
            self.get_logger().info(f'unconfigured; waiting for a lifecycle manager '
                                   f'(ros2 lifecycle set {name} configure); {output}')

    # ------------------------------------------------------------------ lifecycle
    @property
    def lifecycle_state(self) -> str:
        """The current lifecycle state's label (``unconfigured``, ``inactive``, ...)."""
        return self._state_machine.current_state[1]

    def _new_driver(self) -> SickLmsDriver:
        return SickLmsDriver(self.config, self._on_scan, on_event=self._on_event,
                             clock=self._now)

    def on_configure(self, state) -> TransitionCallbackReturn:
        driver = self._take_ready_driver()
        if driver is None:
            if self._stopping:
                return FAILURE
            cfg = self.config
            self.get_logger().info(
                f'configuring: opening {cfg.port} ({cfg.scan_angle} deg / {cfg.resolution:g} '
                f'deg, {cfg.units}, {cfg.baud} baud)')
            driver = self._new_driver()
            self.driver = driver
            if self._stopping:  # Ctrl-C between the check and the assignment
                driver.interrupt()
            try:
                driver.connect(start_output=False)
            except Exception as exc:  # noqa: BLE001 - SickError, or a bug (rclpy hides it)
                self.driver = None
                driver.close()
                self._configure_failed(exc, retrying=False)
                return FAILURE if isinstance(exc, SickError) else ERROR
        self.driver = driver
        self._configure_error = ''
        self._last_log = ('', 0.0)
        s, cfg = driver.stats(), driver.config
        self.get_logger().info(
            f'configured: {cfg.port} at {s.baud} baud, {cfg.scan_angle} deg / '
            f'{cfg.resolution:g} deg, {cfg.units} ({s.device_type or "unknown type"}); '
            f'frame {self.config.frame_id}{", inverted" if self.config.inverted else ""}')
        return super().on_configure(state)

    def on_activate(self, state) -> TransitionCallbackReturn:
        if self.driver is None:
            return FAILURE
        self._clear_queue()
        try:
            self.driver.start()  # the reader starts the output, streams and recovers
        except RuntimeError as exc:  # the previous reader has not finished stopping
            self.get_logger().error(f'activate failed: {exc}')
            return FAILURE
        return super().on_activate(state)  # enables the scan publisher

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        result = super().on_deactivate(state)  # no scan is published from here on
        driver = self.driver
        if driver is not None:
            driver.stop(close_port=False)  # stops the device's output, port stays open
            s = driver.stats()
            self.get_logger().info(f'deactivated: {driver.config.port} output stopped'
                                   if s.state == 'idle' else
                                   f'deactivated: {driver.config.port} {s.state}')
        self._clear_queue()
        return result

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._release()
        return super().on_cleanup(state)

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self._stopping = True
        self._stop_waiter()
        self._scan_pub.on_deactivate(state)
        self._release()
        return super().on_shutdown(state)

    def on_error(self, state) -> TransitionCallbackReturn:
        self._scan_pub.on_deactivate(state)
        self._release()  # back to unconfigured with the port closed
        return super().on_error(state)

    def _release(self) -> None:
        """Stop the reader and the device's output, close the port."""
        driver, self.driver = self.driver, None
        if driver is not None:
            driver.stop()
            self.get_logger().info(f'{driver.config.port} closed')
        self._clear_queue()

    def _configure_failed(self, exc: Exception, retrying: bool) -> None:
        message = str(exc) if isinstance(exc, SickError) else f'{type(exc).__name__}: {exc}'
        self._configure_error = message
        if self._stopping:
            self.get_logger().info(f'configure interrupted: {message}')
            return
        if retrying:
            last, when = self._last_log
            now = time.monotonic()
            if message != last or now - when > REPEAT_LOG_PERIOD:
                self.get_logger().error(f'cannot configure: {message}; retrying every '
                                        f'{self.config.reconnect_period:g} s')
                self._last_log = (message, now)
        else:
            self.get_logger().error(f'configure failed: {message}')

    # ------------------------------------------------------------------ autostart
    def _wait_for_device(self) -> None:
        """autostart thread: open and set up the device (as configure does) until it
        answers, then let the executor configure (adopting it) and activate."""
        while not self._waiter_stop.is_set():
            driver = self._new_driver()
            self._waiting_driver = driver
            if self._waiter_stop.is_set():
                driver.interrupt()
            try:
                driver.connect(start_output=False)
            except Exception as exc:  # noqa: BLE001 - SickError, or a bug: both reported
                driver.close()
                if self._waiter_stop.is_set():
                    return
                self._configure_failed(exc, retrying=isinstance(exc, SickError))
                if not isinstance(exc, SickError):
                    return
                self._waiter_stop.wait(self.config.reconnect_period)
                continue
            finally:
                self._waiting_driver = None
            if self._waiter_stop.is_set():
                driver.close()
                return
            self._ready_driver = driver
            self._autostart_guard.trigger()
            return

    def _start_waiter(self) -> None:
        self._waiter_stop.clear()
        if self._stopping:
            return
        self._waiter = threading.Thread(target=self._wait_for_device,
                                        name='sick-lms-autostart', daemon=True)
        self._waiter.start()

    def _autostart_transitions(self) -> None:
        if self._stopping or self._ready_driver is None:
            return
        if self.lifecycle_state == 'unconfigured' and self.trigger_configure() != SUCCESS:
            self._start_waiter()  # e.g. the port changed meanwhile and is not there
            return
        if self.lifecycle_state == 'inactive':
            self.trigger_activate()

    def _stop_waiter(self, timeout: float = 1.0) -> None:
        self._waiter_stop.set()
        waiting = self._waiting_driver
        if waiting is not None:
            waiting.interrupt()
        if self._waiter is not None:
            self._waiter.join(timeout)
            self._waiter = None

    def _take_ready_driver(self) -> SickLmsDriver | None:
        """The device the autostart thread set up, if its settings are still current."""
        self._stop_waiter()
        driver, self._ready_driver = self._ready_driver, None
        if driver is None:
            return None
        if any(getattr(driver.config, f) != getattr(self.config, f) for f in CONFIGURE_FIELDS):
            driver.close()  # parameters changed meanwhile: set it up again with them
            return None
        driver.config = self._live_config(driver.config)
        return driver

    def request_stop(self) -> None:
        """Called from the signal handler (``common.run``): a configure or an autostart wait
        in progress gives up at once; nothing is retried."""
        self._stopping = True
        self._waiter_stop.set()
        for driver in (self.driver, self._waiting_driver):
            if driver is not None:
                driver.interrupt()

    # ----------------------------------------------------------------- parameters
    def _live_config(self, running: SickLmsConfig) -> SickLmsConfig:
        return dataclasses.replace(running, **{f: getattr(self.config, f) for f in LIVE_FIELDS})

    def _apply_parameters(self, sections: dict) -> None:
        """Live fields apply at once; connection fields at the next configure."""
        old, self.config = self.config, sections['']
        if self.config.diagnostics_period != old.diagnostics_period:
            self._diag_timer.timer_period_ns = int(self.config.diagnostics_period * 1e9)
            self._diag_timer.reset()
        driver = self.driver
        if driver is None:
            return
        driver.config = self._live_config(driver.config)
        changed = [f for f in CONFIGURE_FIELDS if getattr(self.config, f) != getattr(old, f)]
        if changed:
            what = ', '.join(f if f == 'password' else f'{f}={getattr(self.config, f)}'
                             for f in changed)
            self.get_logger().info(
                f'{what}: applied at the next configure (the device keeps its current '
                f'settings until then): ros2 lifecycle set {self.get_fully_qualified_name()} '
                f'deactivate / cleanup / configure / activate')

    def pending_changes(self) -> list[str]:
        """Connection parameters set since the running configuration was made."""
        driver = self.driver
        if driver is None:
            return []
        return [f for f in CONFIGURE_FIELDS
                if getattr(driver.config, f) != getattr(self.config, f)]

    # ------------------------------------------------------------- driver thread side
    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_scan(self, scan: SickScan) -> None:
        with self._queue_lock:
            if len(self._queue) >= QUEUE_LENGTH:
                self._queue.popleft()
                self._dropped += 1
            self._queue.append(scan)
        self._guard.trigger()

    def _clear_queue(self) -> None:
        with self._queue_lock:
            self._queue.clear()

    def _on_event(self, state: str, message: str) -> None:
        log = self.get_logger()
        if state == 'streaming':
            log.info(message)
            self._last_log = ('', 0.0)
        elif state == 'disconnected':
            last, when = self._last_log
            now = time.monotonic()
            if message != last or now - when > REPEAT_LOG_PERIOD:
                log.error(f'{message}; retrying every {self.config.reconnect_period:g} s')
                self._last_log = (message, now)
        else:
            log.debug(message)

    # ---------------------------------------------------------------- executor side
    def _publish_pending(self) -> None:
        with self._queue_lock:
            scans = list(self._queue)
            self._queue.clear()
        if not self._scan_pub.is_activated:
            return
        for sick_scan in scans:
            try:
                scan = sick_scan.to_scan(self.config.frame_id, self.config.inverted)
                msg = scan_to_msg(self._factory, scan)
            except (ScanError, ValueError) as exc:  # e.g. a negative stamp from a sim clock
                self._unpublishable += 1
                self.get_logger().warning(f'scan not published: {exc}',
                                          throttle_duration_sec=5.0)
                continue
            self._scan_pub.publish(msg)
            self._published += 1

    def diagnostics(self) -> DiagnosticStatus:
        lifecycle = self.lifecycle_state
        driver = self.driver
        cfg = driver.config if driver is not None else self.config
        s = driver.stats() if driver is not None else None
        status = StatusByte(s.status_byte) if s and s.status_byte is not None else None
        if lifecycle == 'active' and s is not None:
            level, message = DiagnosticStatus.OK, f'streaming at {s.scan_rate:.1f} Hz'
            if s.state != 'streaming':
                level = DiagnosticStatus.ERROR
                message = f'{s.state}: {s.last_error}' if s.last_error else s.state
            elif status is not None and status.is_error:
                level, message = DiagnosticStatus.ERROR, f'device reports {status.describe()}'
            elif status is not None and (status.severity == 2 or status.pollution
                                         or status.implausible):
                level, message = DiagnosticStatus.WARN, f'device reports {status.describe()}'
            elif s.scan_rate == 0.0:
                level, message = DiagnosticStatus.WARN, 'streaming, but no scan for 2 s'
        elif lifecycle == 'inactive':
            level = DiagnosticStatus.WARN
            message = f'inactive: {cfg.port} open, output stopped (activate to stream)'
            if s is not None and s.state != 'idle':  # lost while active, then deactivated
                message = f'inactive: {s.state}' + (f': {s.last_error}' if s.last_error else '')
        elif lifecycle == 'unconfigured' and self._configure_error:
            level = DiagnosticStatus.ERROR
            retry = (f'; retrying every {self.config.reconnect_period:g} s'
                     if self._waiter is not None and self._waiter.is_alive() else '')
            message = f'unconfigured: {self._configure_error}{retry}'
        else:
            level, message = DiagnosticStatus.WARN, f'{lifecycle}: port closed'
        values = {
            'lifecycle_state': lifecycle,
            'connection': s.state if s is not None else 'closed',
            'port': cfg.port,
            'baud': str(s.baud or '') if s is not None else '',
            'device_type': s.device_type if s is not None else '',
            'variant': f'{cfg.scan_angle} deg / {cfg.resolution:g} deg',
            'units': cfg.units,
            'pending_changes': ', '.join(self.pending_changes()),
            'scans_published': str(self._published),
            'scans_dropped': str(self._dropped + self._unpublishable),
        }
        if s is not None:  # the counters of the current configuration
            values.update({
                'scan_rate_hz': f'{s.scan_rate:.2f}',
                'scans_received': str(s.scans),
                'telegrams': str(s.telegrams),
                'crc_errors': str(s.crc_errors),
                'length_errors': str(s.length_errors),
                'bytes_discarded': str(s.bytes_discarded),
                'naks': str(s.naks),
                'unexpected_replies': str(s.unexpected_replies),
                'reconnects': str(s.reconnects),
                'device_status_byte': (f'0x{s.status_byte:02X}' if s.status_byte is not None
                                       else ''),
                'device_status': status.describe() if status is not None else '',
                'last_error': s.last_error,
            })
        else:
            values['last_error'] = self._configure_error
        device = s.device_type if s is not None and s.device_type else 'LMS2xx'
        return DiagnosticStatus(level=level, name=DIAGNOSTIC_NAME, message=message,
                                hardware_id=f'{device} on {cfg.port}',
                                values=[KeyValue(key=k, value=v) for k, v in values.items()])

    def publish_diagnostics(self) -> None:
        msg = DiagnosticArray(status=[self.diagnostics()])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(msg)

    def destroy_node(self):
        """Shut down from any state: stops the device's output and closes the port."""
        if not getattr(self, '_destroyed', True):
            self._destroyed = True
            self._stopping = True
            self._stop_waiter()
            try:
                if self.lifecycle_state in ('unconfigured', 'inactive', 'active'):
                    self.trigger_shutdown()
            except Exception:  # noqa: BLE001 - release the device regardless
                pass
            self._release()
            ready, self._ready_driver = self._ready_driver, None
            if ready is not None:
                ready.close()
        return super().destroy_node()


def main(args=None) -> None:
    common.run(SickLmsDriverNode, args)


if __name__ == '__main__':
    main()
