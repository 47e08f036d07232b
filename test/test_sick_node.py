"""The sick_lms_driver node end to end: simulator -> pty -> driver -> node -> subscriber,
and its lifecycle: configure / activate / deactivate / cleanup / shutdown, autostart."""
import math
import os
import threading
import time

import numpy as np
import pytest
import serial

from ros_env import isolate_ros_env

isolate_ros_env()  # before rclpy is imported anywhere in this process

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import LaserScan  # noqa: E402

from laser_tracker.nodes.sick_lms_driver import DIAGNOSTIC_NAME, SickLmsDriverNode  # noqa: E402
from laser_tracker.sick import protocol as P  # noqa: E402
from laser_tracker.tools.sick_device import Corruption, Lms2xxSimulator  # noqa: E402

FAST = {'reply_timeout': 0.2, 'silence_timeout': 0.3, 'reconnect_period': 0.1,
        'diagnostics_period': 0.2}


class Harness:
    """The driver node and a subscriber node in one SingleThreadedExecutor; the subscriber
    node also calls the lifecycle services (as ``ros2 lifecycle set/get`` does)."""

    def __init__(self, context, link, **params):
        values = {'port': str(link), **FAST, **params}
        overrides = [Parameter(k, value=v) for k, v in values.items()]
        self.node = SickLmsDriverNode(context=context, parameter_overrides=overrides)
        self.listener = Node('scan_listener', context=context)
        self.scans: list[LaserScan] = []  # best-effort (sensor data) subscriber
        self.default_qos_scans: list[LaserScan] = []  # default QoS (reliable), as RViz
        self.diagnostics: list[DiagnosticStatus] = []
        self.listener.create_subscription(LaserScan, 'scan', self.scans.append,
                                          qos_profile_sensor_data)
        self.listener.create_subscription(LaserScan, 'scan', self.default_qos_scans.append,
                                          QoSProfile(depth=10))
        self._change = self.listener.create_client(ChangeState, '/sick_lms_driver/change_state')
        self._get = self.listener.create_client(GetState, '/sick_lms_driver/get_state')
        self.listener.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda msg: self.diagnostics.extend(s for s in msg.status
                                                if s.name == DIAGNOSTIC_NAME), 10)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.listener)

    def spin_until(self, predicate, timeout=10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not predicate():
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def call(self, client, request):
        """Call a service of the driver node; the request is sent again if no answer came
        within 5 s (a request sent before the client and the service are matched is lost;
        ``service_is_ready`` can stay false while a destroyed node's endpoints linger)."""
        futures = []
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            futures.append(client.call_async(request))
            if self.spin_until(lambda: any(f.done() for f in futures), timeout=5.0):
                return next(f for f in futures if f.done()).result()
        raise AssertionError(f'no answer from {client.srv_name}')

    def transition(self, label: str) -> bool:
        """``ros2 lifecycle set /sick_lms_driver <label>``: True if it succeeded."""
        request = ChangeState.Request()
        request.transition.label = label
        return self.call(self._change, request).success

    def state(self) -> str:
        """``ros2 lifecycle get /sick_lms_driver``."""
        return self.call(self._get, GetState.Request()).current_state.label

    def wait(self, seconds: float) -> None:
        self.spin_until(lambda: False, timeout=seconds)

    def latest_diagnostics(self, timeout=5.0) -> tuple[DiagnosticStatus, dict]:
        """The next /diagnostics status after now, with its values as a dict."""
        count = len(self.diagnostics)
        assert self.spin_until(lambda: len(self.diagnostics) > count, timeout)
        status = self.diagnostics[-1]
        return status, {kv.key: kv.value for kv in status.values}

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.listener.destroy_node()


@pytest.fixture
def link(tmp_path):
    return tmp_path / 'ttyLMS'


@pytest.fixture
def harness(ros_context, link):
    made = []

    def make(**params):
        h = Harness(ros_context, link, **params)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


@pytest.fixture
def sim(link):
    made = []

    def make(**kw):
        s = Lms2xxSimulator(link, **kw)
        s.start()
        made.append(s)
        return s

    yield make
    for s in made:
        s.stop()


def sent_by_ranges(sim):
    """Published float32 ranges -> the simulator's record of that scan (intact ones only)."""
    out = {}
    for s in list(sim.sent):
        if s.corruption is None:
            ranges = P.ranges_in_metres(s.values, P.measuring_mode(s.measuring_mode), s.units)
            out[np.asarray(ranges, np.float32).tobytes()] = s
    return out


def assert_all_published_exact(sim, msgs, reverse=False):
    sent = sent_by_ranges(sim)
    assert sim.errors == []
    for msg in msgs:
        ranges = np.asarray(msg.ranges, np.float32)
        assert not np.isnan(ranges).any()
        key = (ranges[::-1] if reverse else ranges).tobytes()
        assert key in sent, 'published a scan the simulator never sent intact'
    return sent


def stamp(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def port_is_free(link) -> bool:
    """The driver opens the port exclusively: can another program open it now?"""
    try:
        serial.Serial(str(link), exclusive=True).close()
    except serial.SerialException:
        return False
    return True


def test_scans_and_diagnostics_end_to_end(harness, sim):
    device = sim(baud=9600, units='cm', resolution_cdeg=50)
    h = harness(baud=500000, resolution=1.0, units='mm', frame_id='base_laser')
    assert h.spin_until(lambda: len(h.scans) >= 20 and len(h.diagnostics) >= 2), \
        (len(h.scans), h.node.driver.stats())
    sent = assert_all_published_exact(device, h.scans)
    for msg in h.scans:
        assert msg.header.frame_id == 'base_laser' and len(msg.ranges) == 181
        assert msg.angle_min == pytest.approx(-math.pi / 2)
        assert msg.angle_max == pytest.approx(math.pi / 2)
        assert msg.angle_increment == pytest.approx(math.radians(1.0))
        assert msg.time_increment == pytest.approx(1 / 75 / 360)
        assert msg.scan_time == pytest.approx(1 / 75)
        assert msg.range_min == pytest.approx(0.01) and msg.range_max == pytest.approx(8.183)
    stamps = np.array([stamp(m) for m in h.scans])
    assert np.all(np.diff(stamps) > 0)
    # stamps follow the acquisition times (a constant offset between the two clocks)
    acquired = np.array([sent[np.asarray(m.ranges, np.float32).tobytes()].acquired
                         for m in h.scans])
    offset = stamps - acquired
    assert offset.max() - offset.min() < 0.02
    status = h.diagnostics[-1]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.OK, (status.message, values)
    assert values['connection'] == 'streaming' and values['baud'] == '500000'
    assert values['device_status_byte'] == '0x10' and values['crc_errors'] == '0'
    assert float(values['scan_rate_hz']) > 30.0
    assert 'LMS200' in status.hardware_id
    # autostart configured and activated the node; a default-QoS subscriber receives too
    assert h.node.lifecycle_state == 'active' and values['lifecycle_state'] == 'active'
    assert h.state() == 'active'
    assert len(h.default_qos_scans) >= 10
    assert_all_published_exact(device, h.default_qos_scans)


def test_faults_never_publish_a_corrupted_scan_and_scans_flow_again(harness, sim):
    device = sim(baud=500000, resolution_cdeg=100)
    h = harness(baud=500000, resolution=1.0, units='cm')
    assert h.spin_until(lambda: len(h.scans) >= 5)
    for kind in Corruption:
        device.corrupt_next(kind, 2)
    device.inject_bytes(bytes.fromhex('02 80 FF 7F') + bytes(range(256)))
    assert h.spin_until(lambda: device.counters.scans_corrupted == 6 and len(h.scans) >= 30)
    device.unplug()
    h.spin_until(lambda: False, timeout=0.3)
    before = len(h.scans)
    device.replug(power_cycle=True)  # back at 9600, idle: the driver must set it up again
    assert h.spin_until(lambda: len(h.scans) >= before + 10), h.node.driver.stats()
    assert h.spin_until(lambda: h.diagnostics and h.diagnostics[-1].level
                        == DiagnosticStatus.OK)
    assert_all_published_exact(device, h.scans)
    values = {kv.key: kv.value for kv in h.diagnostics[-1].values}
    assert int(values['reconnects']) >= 1
    assert int(values['crc_errors']) + int(values['length_errors']) >= 6


def test_inverted_mounting_and_the_100_degree_variant(harness, sim):
    device = sim(baud=500000)
    h = harness(baud=500000, scan_angle=100, resolution=0.5, inverted=True)
    assert h.spin_until(lambda: len(h.scans) >= 5)
    assert_all_published_exact(device, h.scans, reverse=True)
    msg = h.scans[-1]
    assert len(msg.ranges) == 201
    assert msg.angle_min == pytest.approx(math.radians(-50))
    assert msg.angle_max == pytest.approx(math.radians(50))
    assert msg.scan_time == pytest.approx(2 / 75)


def test_autostart_waits_for_a_missing_device_and_reports_it(harness, sim):
    h = harness(baud=500000)
    assert h.spin_until(lambda: len(h.diagnostics) >= 2)
    status = h.diagnostics[-1]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.ERROR
    assert 'no such serial port' in status.message and 'ttyLMS' in status.message
    assert 'retrying' in status.message and values['lifecycle_state'] == 'unconfigured'
    assert h.state() == 'unconfigured' and not h.scans
    device = sim(baud=9600)  # plugged in later: autostart configures and activates then
    assert h.spin_until(lambda: len(h.scans) >= 5), h.diagnostics[-1].message
    assert h.state() == 'active'
    assert_all_published_exact(device, h.scans)


def test_impossible_variant_parameters_are_refused(ros_context, link):
    from laser_tracker.config import ConfigError
    with pytest.raises(ConfigError, match='0.25 degree resolution needs the 100 degree'):
        SickLmsDriverNode(context=ros_context, parameter_overrides=[
            Parameter('port', value=str(link)), Parameter('scan_angle', value=180),
            Parameter('resolution', value=0.25)])


def test_lifecycle_transitions_drive_the_device(harness, sim, link):
    device = sim(baud=9600, resolution_cdeg=100)
    h = harness(autostart=False, baud=500000, resolution=0.5, units='mm')
    h.wait(0.5)
    assert h.state() == 'unconfigured' and h.node.driver is None
    assert device.baud == 9600 and device.counters.requests == 0 and port_is_free(link)
    status, values = h.latest_diagnostics()
    assert values['lifecycle_state'] == 'unconfigured' and values['connection'] == 'closed'

    # configure: port opened, device found at 9600, switched to 500000, variant and units set
    assert h.transition('configure')
    assert h.state() == 'inactive'
    assert device.baud == 500000 and device.device.resolution_cdeg == 50
    assert device.device.units == P.RangeUnit.MM
    assert not device.device.streaming and not port_is_free(link)
    status, values = h.latest_diagnostics()
    assert status.level == DiagnosticStatus.WARN and values['lifecycle_state'] == 'inactive'
    assert values['connection'] == 'idle' and values['baud'] == '500000'
    h.wait(0.3)
    assert device.counters.scans_sent == 0 and not h.scans

    # activate: continuous output, scans published
    assert h.transition('activate')
    assert h.spin_until(lambda: len(h.scans) >= 5)
    assert device.device.streaming
    assert_all_published_exact(device, h.scans)
    assert all(len(m.ranges) == 361 for m in h.scans)

    # a connection parameter set while active: accepted, pending until the next configure
    result = h.node.set_parameters([Parameter('resolution', value=1.0)])[0]
    assert result.successful, result.reason
    count = len(h.scans)
    assert h.spin_until(lambda: len(h.scans) >= count + 5)
    assert all(len(m.ranges) == 361 for m in h.scans)
    status, values = h.latest_diagnostics()
    assert values['pending_changes'] == 'resolution' and values['variant'] == '180 deg / 0.5 deg'

    # deactivate: the device is told to stop its output; the port stays open
    assert h.transition('deactivate')
    assert h.state() == 'inactive'
    assert not device.device.streaming  # the simulator received "stop continuous output"
    assert h.node.driver.stats().state == 'idle' and not port_is_free(link)
    h.wait(0.2)
    sent, received = device.counters.scans_sent, len(h.scans)
    h.wait(0.3)
    assert device.counters.scans_sent == sent and len(h.scans) == received

    # cleanup: the port is closed
    assert h.transition('cleanup')
    assert h.state() == 'unconfigured' and h.node.driver is None and port_is_free(link)

    # configure again: the new resolution reaches the device; activate streams it
    assert h.transition('configure') and device.device.resolution_cdeg == 100
    assert h.transition('activate')
    count = len(h.scans)
    assert h.spin_until(lambda: len(h.scans) >= count + 5)
    assert all(len(m.ranges) == 181 for m in h.scans[count:])
    assert_all_published_exact(device, h.scans)
    status, values = h.latest_diagnostics()
    assert values['pending_changes'] == '' and values['variant'] == '180 deg / 1 deg'

    # shutdown from active: output stopped, port closed
    assert h.transition('shutdown')
    assert h.state() == 'finalized'
    assert not device.device.streaming and port_is_free(link)
    assert device.errors == []


def test_configure_fails_on_a_missing_port_and_the_node_survives(harness, sim):
    h = harness(autostart=False, baud=500000)
    assert not h.transition('configure')
    assert h.state() == 'unconfigured' and h.node.driver is None
    status, values = h.latest_diagnostics()
    assert status.level == DiagnosticStatus.ERROR
    assert 'ttyLMS' in status.message and 'no such serial port' in status.message
    assert 'retrying' not in status.message  # without autostart nothing is retried
    device = sim(baud=9600)
    assert h.transition('configure') and h.transition('activate')
    assert h.spin_until(lambda: len(h.scans) >= 5)
    assert_all_published_exact(device, h.scans)
    status, _ = h.latest_diagnostics()
    assert status.level == DiagnosticStatus.OK, status.message


def test_destroying_an_active_node_stops_the_output(harness, sim, link):
    device = sim(baud=500000)
    h = harness(baud=500000)
    assert h.spin_until(lambda: len(h.scans) >= 3)
    assert device.device.streaming
    h.node.destroy_node()  # what Ctrl-C does (common.run)
    assert not device.device.streaming and port_is_free(link)


def test_a_stop_request_interrupts_a_configure_waiting_for_a_silent_device(harness, link):
    master, slave = os.openpty()  # a serial port on which nothing ever answers
    try:
        os.symlink(os.ttyname(slave), link)
        h = harness(autostart=False, reply_timeout=0.5)
        stopper = threading.Timer(0.3, h.node.request_stop)  # the Ctrl-C handler calls this
        stopper.start()
        started = time.monotonic()
        result = h.node.trigger_configure()  # the rate search alone would take seconds
        elapsed = time.monotonic() - started
        stopper.join()
        assert result == TransitionCallbackReturn.FAILURE
        assert 0.25 < elapsed < 1.0, elapsed
        assert h.node.lifecycle_state == 'unconfigured' and port_is_free(link)
    finally:
        os.close(master)
        os.close(slave)


def test_diagnostics_run_on_wall_time_with_sim_time_and_no_clock(harness):
    h = harness(autostart=False, use_sim_time=True, diagnostics_period=0.2)
    assert h.node.get_clock().now().nanoseconds == 0  # no /clock: ROS time stands still
    started = time.monotonic()
    assert h.spin_until(lambda: len(h.diagnostics) >= 5, timeout=5.0)
    assert time.monotonic() - started < 3.0
    values = {kv.key: kv.value for kv in h.diagnostics[-1].values}
    assert values['lifecycle_state'] == 'unconfigured'
    # the period is live
    assert h.node.set_parameters([Parameter('diagnostics_period', value=1.0)])[0].successful
    h.wait(0.3)
    count = len(h.diagnostics)
    h.wait(1.5)
    assert 1 <= len(h.diagnostics) - count <= 2


def test_live_parameters_change_the_published_scans_at_once(harness, sim):
    device = sim(baud=500000)
    h = harness(baud=500000, resolution=1.0, frame_id='laser')
    assert h.spin_until(lambda: len(h.scans) >= 5)
    assert h.scans[-1].header.frame_id == 'laser'
    sent = sent_by_ranges(device)

    def clock_offsets(msgs, reverse=False):
        """Published stamp minus the simulator's acquisition time, per scan."""
        return np.array([stamp(m) - sent[np.asarray(m.ranges[::-1] if reverse else m.ranges,
                                                     np.float32).tobytes()].acquired
                         for m in msgs])

    before = clock_offsets(h.scans)
    result = h.node.set_parameters([Parameter('frame_id', value='laser_front'),
                                    Parameter('inverted', value=True),
                                    Parameter('time_offset', value=0.5)])
    assert all(r.successful for r in result)
    count = len(h.scans)
    assert h.spin_until(lambda: len(h.scans) >= count + 6)
    changed = [m for m in h.scans[count:] if m.header.frame_id == 'laser_front']
    assert len(changed) >= 5  # at most the scans already queued keep the old frame
    assert_all_published_exact(device, changed, reverse=True)
    sent = sent_by_ranges(device)
    after = clock_offsets(changed[2:], reverse=True)
    assert np.median(after) - np.median(before) == pytest.approx(0.5, abs=0.01)
    assert h.node.driver.stats().reconnects == 0  # no re-initialisation for live parameters


def test_autostart_is_read_only_while_running(harness):
    h = harness(autostart=False)
    result = h.node.set_parameters([Parameter('autostart', value=True)])[0]
    assert not result.successful
