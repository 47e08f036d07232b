"""The sick_lms_driver node end to end: simulator -> pty -> driver -> node -> subscriber."""
import math
import time

import numpy as np
import pytest

from ros_env import isolate_ros_env

isolate_ros_env()  # before rclpy is imported anywhere in this process

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import LaserScan  # noqa: E402

from laser_tracker.nodes.sick_lms_driver import DIAGNOSTIC_NAME, SickLmsDriverNode  # noqa: E402
from laser_tracker.sick import protocol as P  # noqa: E402
from laser_tracker.tools.sick_device import Corruption, Lms2xxSimulator  # noqa: E402

FAST = {'reply_timeout': 0.2, 'silence_timeout': 0.3, 'reconnect_period': 0.1,
        'diagnostics_period': 0.2}


class Harness:
    """The driver node and a subscriber node in one SingleThreadedExecutor."""

    def __init__(self, context, link, **params):
        values = {'port': str(link), **FAST, **params}
        overrides = [Parameter(k, value=v) for k, v in values.items()]
        self.node = SickLmsDriverNode(context=context, parameter_overrides=overrides)
        self.listener = Node('scan_listener', context=context)
        self.scans: list[LaserScan] = []
        self.diagnostics: list[DiagnosticStatus] = []
        self.listener.create_subscription(LaserScan, 'scan', self.scans.append,
                                          qos_profile_sensor_data)
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


def test_missing_device_is_reported_in_diagnostics(harness):
    h = harness(baud=500000)
    assert h.spin_until(lambda: len(h.diagnostics) >= 2)
    status = h.diagnostics[-1]
    assert status.level == DiagnosticStatus.ERROR
    assert 'no such serial port' in status.message and 'ttyLMS' in status.message
    assert h.node.driver.running and not h.scans


def test_impossible_variant_parameters_are_refused(ros_context, link):
    from laser_tracker.config import ConfigError
    with pytest.raises(ConfigError, match='0.25 degree resolution needs the 100 degree'):
        SickLmsDriverNode(context=ros_context, parameter_overrides=[
            Parameter('port', value=str(link)), Parameter('scan_angle', value=180),
            Parameter('resolution', value=0.25)])
