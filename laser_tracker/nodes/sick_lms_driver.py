"""``sick_lms_driver``: a SICK LMS2xx on a serial port -> ``scan`` and ``/diagnostics``.

A thin shell around :class:`laser_tracker.sick.driver.SickLmsDriver`: the driver reads the
port on its own thread and hands scans over through a bounded queue and a guard condition,
so messages are built and published from the executor. Parameters are the fields of
:class:`~laser_tracker.sick.driver.SickLmsConfig` (plain names: ``port``, ``baud``,
``scan_angle``, ``resolution``, ``units``, ``frame_id``, ``inverted``, ``time_offset``, ...).

``scan`` (sensor_msgs/LaserScan, sensor-data QoS): header stamp = estimated acquisition time
of the first beam (see the driver's stamp model), ranges without NaN: +inf for "nothing
within range" (REP 117), 0.0 (below ``range_min``) for the device's other no-measurement
codes. ``/diagnostics``: one DiagnosticStatus named ``sick_lms_driver: LMS2xx`` every
``diagnostics_period`` seconds.
"""
from __future__ import annotations

import threading
import time
from collections import deque

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan

from laser_tracker.conversions import scan_to_msg, ros_factory
from laser_tracker.core.scan import ScanError
from laser_tracker.nodes import common
from laser_tracker.nodes.params import LiveParameters
from laser_tracker.sick.driver import SickLmsConfig, SickLmsDriver, SickScan
from laser_tracker.sick.protocol import StatusByte

QUEUE_LENGTH = 8  # scans waiting for the executor; older ones are dropped (and counted)
DIAGNOSTIC_NAME = 'sick_lms_driver: LMS2xx'
REPEAT_LOG_PERIOD = 30.0  # s: an unchanged error is logged again after this long


class SickLmsDriverNode(Node):
    """Publishes the scans of one LMS2xx; never calls ``rclpy.init`` (composable)."""

    def __init__(self, **kwargs):
        super().__init__('sick_lms_driver', **kwargs)
        self.params = LiveParameters(self, 'sick_lms_driver', self._apply_parameters)
        self.config: SickLmsConfig = self.params.sections['']
        self._factory = ros_factory()
        self._scan_pub = self.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._queue: deque[SickScan] = deque()
        self._queue_lock = threading.Lock()
        self._published = 0
        self._dropped = 0
        self._unpublishable = 0
        self._last_log: tuple[str, float] = ('', 0.0)
        self._guard = self.create_guard_condition(self._publish_pending)
        self._diag_timer = self.create_timer(self.config.diagnostics_period,
                                             self.publish_diagnostics)
        self.driver = SickLmsDriver(self.config, self._on_scan, on_event=self._on_event,
                                    clock=self._now)
        self._destroyed = False
        self.driver.start()
        self.get_logger().info(
            f'opening {self.config.port}: {self.config.scan_angle} deg / '
            f'{self.config.resolution:g} deg, {self.config.units}, {self.config.baud} baud, '
            f'frame {self.config.frame_id}{", inverted" if self.config.inverted else ""}')

    def _apply_parameters(self, sections: dict) -> None:
        """Only ``diagnostics_period`` can change while running (the rest is read-only)."""
        self.config = sections['']
        self._diag_timer.cancel()
        self.destroy_timer(self._diag_timer)
        self._diag_timer = self.create_timer(self.config.diagnostics_period,
                                             self.publish_diagnostics)

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
        s = self.driver.stats()
        status = StatusByte(s.status_byte) if s.status_byte is not None else None
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
        cfg = self.config
        values = {
            'connection': s.state,
            'port': cfg.port,
            'baud': str(s.baud or ''),
            'device_type': s.device_type,
            'variant': f'{cfg.scan_angle} deg / {cfg.resolution:g} deg',
            'units': cfg.units,
            'scan_rate_hz': f'{s.scan_rate:.2f}',
            'scans_received': str(s.scans),
            'scans_published': str(self._published),
            'scans_dropped': str(self._dropped + self._unpublishable),
            'telegrams': str(s.telegrams),
            'crc_errors': str(s.crc_errors),
            'length_errors': str(s.length_errors),
            'bytes_discarded': str(s.bytes_discarded),
            'naks': str(s.naks),
            'unexpected_replies': str(s.unexpected_replies),
            'reconnects': str(s.reconnects),
            'device_status_byte': f'0x{s.status_byte:02X}' if s.status_byte is not None else '',
            'device_status': status.describe() if status is not None else '',
            'last_error': s.last_error,
        }
        return DiagnosticStatus(level=level, name=DIAGNOSTIC_NAME, message=message,
                                hardware_id=f'{s.device_type or "LMS2xx"} on {cfg.port}',
                                values=[KeyValue(key=k, value=v) for k, v in values.items()])

    def publish_diagnostics(self) -> None:
        msg = DiagnosticArray(status=[self.diagnostics()])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(msg)

    def destroy_node(self):
        if not getattr(self, '_destroyed', True):
            self._destroyed = True
            self.driver.stop()  # stops the device's output and closes the port
        return super().destroy_node()


def main(args=None) -> None:
    common.run(SickLmsDriverNode, args)


if __name__ == '__main__':
    main()
