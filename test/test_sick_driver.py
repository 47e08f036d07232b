"""The SICK driver against the device simulator over a real pseudo-terminal."""
import errno
import math
import os
import threading
import time

import numpy as np
import pytest
import serial

from laser_tracker.config import ConfigError
from laser_tracker.sick import protocol as P
from laser_tracker.sick.driver import (BaudDetectionError, CommandRejectedError, PortBusyError,
                                       PortNotFoundError, PortPermissionError, SickLmsConfig,
                                       SickLmsDriver, SickScan)
from laser_tracker.tools.sick_device import Corruption, Lms2xxSimulator

FAST = dict(reply_timeout=0.2, silence_timeout=0.3, reconnect_period=0.1)


class Collector:
    def __init__(self):
        self.scans: list[SickScan] = []
        self.events: list[tuple[str, str]] = []
        self.cond = threading.Condition()

    def on_scan(self, scan):
        with self.cond:
            self.scans.append(scan)
            self.cond.notify_all()

    def on_event(self, state, message):
        self.events.append((state, message))

    def wait(self, count, timeout=10.0) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: len(self.scans) >= count, timeout)

    def wait_more(self, count, timeout=10.0) -> bool:
        with self.cond:
            target = len(self.scans) + count
        return self.wait(target, timeout)


@pytest.fixture
def link(tmp_path):
    return tmp_path / 'ttyLMS'


@pytest.fixture
def rig(link):
    """make(sim kwargs, config kwargs) -> (sim, driver, collector); all stopped afterwards."""
    made = []

    def make(sim_kw=None, cfg_kw=None, start_driver=True):
        sim = Lms2xxSimulator(link, **(sim_kw or {}))
        sim.start()
        collector = Collector()
        cfg = SickLmsConfig(port=str(link), **{**FAST, **(cfg_kw or {})})
        driver = SickLmsDriver(cfg, collector.on_scan, on_event=collector.on_event,
                               clock=time.monotonic)
        made.append((sim, driver))
        if start_driver:
            driver.start()
        return sim, driver, collector

    yield make
    for sim, driver in made:
        driver.stop()
        sim.stop()


def expected_ranges(sent):
    return P.ranges_in_metres(sent.values, P.measuring_mode(sent.measuring_mode), sent.units)


def check_exact(sim, scans):
    """Every delivered scan is one the simulator sent intact, value for value."""
    assert sim.errors == []
    sent = list(sim.sent)
    clean = {s.values.tobytes(): s for s in sent if s.corruption is None}
    damaged = {s.values.tobytes() for s in sent if s.corruption is not None}
    assert len(clean) == sum(s.corruption is None for s in sent), 'scans must be unique'
    for scan in scans:
        key = scan.values.tobytes()
        assert key not in damaged, 'a corrupted telegram was delivered'
        assert key in clean, 'a scan the simulator never sent was delivered'
        np.testing.assert_array_equal(scan.ranges, expected_ranges(clean[key]))
        assert not np.isnan(scan.ranges).any()
    return clean


def sent_index(sim, scan):
    return next(s.index for s in list(sim.sent) if s.values.tobytes() == scan.values.tobytes())


# ------------------------------------------------------------------------- happy path


def test_from_power_on_rate_to_500k_with_exact_scans_and_stamps(rig):
    sim, driver, col = rig({'baud': 9600, 'units': 'cm', 'resolution_cdeg': 100},
                           {'baud': 500000, 'resolution': 0.5, 'units': 'mm'})
    assert col.wait(15), col.events
    assert sim.baud == 500000 and sim.device.units == P.RangeUnit.MM
    assert (sim.device.scan_angle, sim.device.resolution_cdeg) == (180, 50)
    scans = list(col.scans)
    clean = check_exact(sim, scans)
    for scan in scans:
        assert scan.geometry.count == 361 and scan.geometry.revolutions == 2
        assert scan.units == P.RangeUnit.MM and scan.range_max == pytest.approx(8.183)
        assert scan.status.raw == 0x10
    stamps = np.array([s.stamp for s in scans])
    assert np.all(np.diff(stamps) > 0)
    # the stamp estimates when the sweep started (the simulator knows the truth)
    errors = np.array([s.stamp - clean[s.values.tobytes()].acquired for s in scans])
    assert errors.min() > -0.5e-3 and np.median(errors) < 10e-3, errors
    stats = driver.stats()
    assert stats.state == 'streaming' and stats.baud == 500000
    assert stats.device_type == 'LMS200;30106' and stats.crc_errors == 0
    driver.stop()
    assert not sim.device.streaming, 'the driver stops continuous output on shutdown'
    assert col.events[-1][0] == 'stopped'


def test_probes_the_rates_and_sets_the_100_degree_quarter_degree_variant(rig):
    sim, driver, col = rig({'baud': 38400, 'units': 'mm', 'speedup': 8.0},
                           {'baud': 19200, 'scan_angle': 100, 'resolution': 0.25, 'units': 'cm'})
    assert col.wait(4, timeout=15), col.events
    assert sim.baud == 19200 and sim.device.units == P.RangeUnit.CM
    scan = col.scans[-1]
    assert scan.geometry.count == 401 and scan.geometry.revolutions == 4
    assert scan.geometry.angle_min == pytest.approx(math.radians(-50))
    assert scan.units == P.RangeUnit.CM and scan.range_max == pytest.approx(81.83)
    check_exact(sim, col.scans)


def test_line_rate_pacing_at_38400(rig):
    """181 values take 367 bytes = 95.6 ms at 38400: about 10.5 scans/s, never faster."""
    sim, driver, col = rig({'baud': 38400, 'resolution_cdeg': 100},
                           {'baud': 38400, 'resolution': 1.0, 'units': 'cm'})
    assert col.wait(2, timeout=10), col.events
    start = len(col.scans)
    time.sleep(1.2)
    scans = col.scans[start:]
    first_bytes = np.array([s.first_byte_time for s in scans])
    rate = (len(scans) - 1) / (first_bytes[-1] - first_bytes[0])
    assert 9.0 < rate < 11.5, rate
    assert np.diff(first_bytes).min() > 0.8 * P.frame_time(367, 38400)
    clean = check_exact(sim, scans)
    # at this rate the device waits for the line, so a scan may be up to one turn older
    errors = np.array([s.stamp - clean[s.values.tobytes()].acquired for s in scans])
    assert errors.min() > -0.5e-3 and errors.max() < P.MIRROR_PERIOD + 20e-3, errors


def test_set_up_without_output_then_start_and_stop_the_output_keeping_the_port(rig):
    """The lifecycle node's steps: configure = connect(start_output=False), activate = start,
    deactivate = stop(close_port=False), activate again = start (no new set-up)."""
    sim, driver, col = rig({'baud': 9600}, {'baud': 500000}, start_driver=False)
    driver.connect(start_output=False)
    assert driver.stats().state == 'idle' and driver.stats().baud == 500000
    assert sim.baud == 500000 and not sim.device.streaming
    time.sleep(0.2)
    assert sim.counters.scans_sent == 0 and not col.scans
    driver.start()
    assert col.wait(5), col.events
    assert sim.device.streaming
    driver.stop(close_port=False)
    assert not sim.device.streaming and driver.stats().state == 'idle'
    assert col.events[-1][0] == 'idle'
    requests = sim.counters.requests
    driver.start()  # the device is still set up: only "start continuous output" is sent
    assert col.wait_more(5), col.events
    assert sim.counters.requests == requests + 1 and driver.stats().reconnects == 0
    check_exact(sim, col.scans)
    driver.stop()
    assert not sim.device.streaming and col.events[-1][0] == 'stopped'


# ----------------------------------------------------------------------------- faults


def test_corruption_and_garbage_lose_only_the_damaged_telegrams(rig):
    sim, driver, col = rig({'baud': 500000, 'resolution_cdeg': 100},
                           {'baud': 500000, 'resolution': 1.0})
    assert col.wait(5), col.events
    first = sent_index(sim, col.scans[0])
    rng = np.random.default_rng(3)
    real = sim.device.scan_reply(np.arange(181, dtype=np.uint16))
    for kind in Corruption:
        sim.corrupt_next(kind, 3)
        time.sleep(0.05)
    sim.inject_bytes(rng.integers(0, 256, 300, dtype=np.uint8).tobytes())  # garbage
    sim.inject_bytes(bytes.fromhex('02 80 FF 7F') + bytes(20))  # length past 812
    sim.inject_bytes(bytes.fromhex('02 80 40 01') + bytes(10))  # plausible length, bad CRC
    sim.inject_bytes(real[:200])  # a truncated telegram
    sim.inject_bytes(real[:-2] + b'\x00\x00')  # a wrong CRC
    time.sleep(0.3)
    assert col.wait_more(10)
    sent = [s for s in list(sim.sent) if s.index >= first]
    damaged = [s for s in sent if s.corruption]
    assert len(damaged) == 9
    clean = check_exact(sim, col.scans)
    delivered = {s.values.tobytes() for s in col.scans}
    last = sent[-1].index
    missing = [s.index for s in sent if s.corruption is None and s.index < last - 2
               and s.values.tobytes() not in delivered]
    assert missing == [], 'an intact telegram was lost'
    stats = driver.stats()
    assert stats.crc_errors + stats.length_errors >= 9 and stats.reconnects == 0
    assert len(clean) > 0


def test_nak_and_wrong_reply_codes_during_initialisation(rig):
    sim, driver, col = rig({'baud': 500000}, {'baud': 500000}, start_driver=False)
    sim.nak_next(3)
    sim.wrong_reply_next(2)
    driver.connect()
    stats = driver.stats()
    assert stats.state == 'streaming' and stats.naks == 3 and stats.unexpected_replies >= 2
    assert sim.counters.naks_sent == 3
    for _ in range(200):
        driver.read_once()
        if col.scans:
            break
    assert col.scans
    driver.close(stop_output=True)
    assert not sim.device.streaming


def test_silence_short_is_ridden_out_long_reinitialises(rig):
    sim, driver, col = rig({'baud': 500000, 'resolution_cdeg': 100},
                           {'baud': 500000, 'resolution': 1.0})
    assert col.wait(5), col.events
    sim.silence(0.1)
    time.sleep(0.2)
    assert col.wait_more(5)
    assert driver.stats().reconnects == 0
    sim.silence(0.8)
    time.sleep(0.8)
    assert col.wait_more(10, timeout=10), col.events
    assert driver.stats().reconnects >= 1
    assert any(state == 'disconnected' and 'no good scan' in msg for state, msg in col.events)
    check_exact(sim, col.scans)


def test_slow_device_still_initialises(rig):
    sim, driver, col = rig({'baud': 500000}, {'baud': 500000}, start_driver=False)
    sim.set_slow(0.12)  # every answer 120 ms late (the reply timeout is 200 ms here)
    driver.start()
    assert col.wait(5), col.events
    assert driver.stats().reconnects == 0
    check_exact(sim, col.scans)


@pytest.mark.parametrize('power_cycle', [True, False], ids=['power-cycle', 'adapter-replug'])
def test_unplug_and_replug_at_the_same_path(rig, power_cycle):
    sim, driver, col = rig({'baud': 9600, 'resolution_cdeg': 100},
                           {'baud': 500000, 'resolution': 1.0})
    assert col.wait(5), col.events
    sim.unplug()
    time.sleep(0.3)
    before = len(col.scans)
    sim.replug(power_cycle=power_cycle)
    replugged = time.monotonic()
    assert col.wait(before + 5, timeout=10), col.events
    recovery = col.scans[before].first_byte_time - replugged
    assert recovery < 3.0
    assert driver.stats().reconnects >= 1 and sim.baud == 500000
    assert any(state == 'disconnected' for state, _ in col.events)
    check_exact(sim, col.scans)


# -------------------------------------------------------------------------- bad input


def test_nonexistent_port(tmp_path):
    port = str(tmp_path / 'no-such-tty')
    driver = SickLmsDriver(SickLmsConfig(port=port, **FAST), lambda s: None)
    with pytest.raises(PortNotFoundError, match='no-such-tty'):
        driver.connect()


def test_busy_port(rig, link):
    sim, driver, col = rig({'baud': 500000}, {'baud': 500000}, start_driver=False)
    holder = serial.Serial(str(link), 500000, exclusive=True)
    try:
        with pytest.raises(PortBusyError, match=str(link)):
            driver.connect()
    finally:
        holder.close()


def test_permission_error_names_the_port(tmp_path):
    class Denied:
        def __init__(self, port, **kw):
            raise serial.SerialException(errno.EACCES, f'could not open port {port}: '
                                         f'[Errno 13] Permission denied: {port!r}')

    driver = SickLmsDriver(SickLmsConfig(port='/dev/ttyS7', **FAST), lambda s: None,
                           serial_class=Denied)
    with pytest.raises(PortPermissionError, match='/dev/ttyS7.*dialout'):
        driver.connect()


@pytest.mark.skipif(os.geteuid() == 0, reason='root opens any file')
def test_permission_error_on_a_real_file(tmp_path):
    path = tmp_path / 'tty-locked'
    path.write_bytes(b'')
    path.chmod(0)
    driver = SickLmsDriver(SickLmsConfig(port=str(path), **FAST), lambda s: None)
    with pytest.raises(PortPermissionError, match='tty-locked'):
        driver.connect()


def test_device_at_an_unknown_rate(rig, link):
    sim, driver, col = rig({'baud': 115200}, {'baud': 500000}, start_driver=False)
    with pytest.raises(BaudDetectionError, match=r'ttyLMS.*500000, 9600, 38400, 19200'):
        driver.connect()
    assert sim.counters.garbled_in > 0 and sim.counters.requests == 0
    driver.close()


def test_wrong_installation_password(rig):
    sim, driver, col = rig({'baud': 500000, 'units': 'cm'}, {'baud': 500000, 'units': 'mm'},
                           start_driver=False)
    sim.device.password = 'XXXXXXXX'
    with pytest.raises(CommandRejectedError, match='password'):
        driver.connect()
    driver.close()


def test_reader_waits_for_a_device_that_appears_later(link):
    col = Collector()
    driver = SickLmsDriver(SickLmsConfig(port=str(link), baud=500000, resolution=1.0, **FAST),
                           col.on_scan, on_event=col.on_event, clock=time.monotonic)
    driver.start()
    sim = None
    try:
        time.sleep(0.3)
        assert driver.running and col.events[-1][0] == 'disconnected'
        assert str(link) in col.events[-1][1] and 'no such serial port' in col.events[-1][1]
        sim = Lms2xxSimulator(link, baud=500000)
        sim.start()
        assert col.wait(3), col.events
    finally:
        driver.stop()
        if sim is not None:
            sim.stop()


def test_config_refuses_impossible_variants():
    with pytest.raises(ConfigError, match='100 degree'):
        SickLmsConfig(scan_angle=180, resolution=0.25)
    with pytest.raises(ConfigError, match='password'):
        SickLmsConfig(password='short')


# ----------------------------------------------------------------------- the simulator


def test_simulator_answers_a_single_scan_request(rig, link):
    sim, _, _ = rig({'baud': 500000, 'resolution_cdeg': 50}, start_driver=False)
    with serial.Serial(str(link), 500000, timeout=0.5) as port:
        port.write(P.request_scan())
        parser = P.TelegramStreamParser()
        items = []
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and not any(
                isinstance(i, P.ReceivedTelegram) for i in items):
            items += parser.feed(port.read(max(1, port.in_waiting)))
    assert isinstance(items[0], P.Handshake) and items[0].ack
    values = P.decode_reply(items[1].telegram)
    assert isinstance(values, P.MeasuredValues) and values.count == 361


def test_simulator_garbles_replies_at_the_wrong_host_rate(rig, link):
    sim, _, _ = rig({'baud': 9600}, start_driver=False)
    with serial.Serial(str(link), 38400, timeout=0.3) as port:
        port.write(P.request_status())
        time.sleep(0.3)
        assert port.read(100) == b''  # the device did not understand the request
    assert sim.counters.garbled_in > 0
    with serial.Serial(str(link), 9600, timeout=0.5) as port:
        port.write(P.request_status())
        parser = P.TelegramStreamParser()
        got = []
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and not got:
            got = [i for i in parser.feed(port.read(max(1, port.in_waiting)))
                   if isinstance(i, P.ReceivedTelegram)]
        assert P.decode_reply(got[0].telegram).baud == 9600


def test_inverted_mounting_reverses_the_beams():
    values = P.MeasuredValues(np.arange(101, dtype=np.uint16), P.RangeUnit.MM, True, 1,
                              P.StatusByte(0x10))
    geometry = P.scan_geometry(values)  # partial scan: -49.75 .. +50.25 degrees
    ranges = np.arange(101) * 0.01
    scan = SickScan(stamp=1.0, first_byte_time=1.02, ranges=ranges, values=values.values,
                    geometry=geometry, range_min=0.01, range_max=8.183, units=P.RangeUnit.MM,
                    measuring_mode=0, status=values.status, sequence=1)
    upright, inverted = scan.to_scan('laser'), scan.to_scan('laser', inverted=True)
    assert upright.angle_min == pytest.approx(math.radians(-50 + 0.25))
    assert inverted.angle_min == pytest.approx(math.radians(-50.25))
    # the beam that looked at +a now looks at -a
    for i in (0, 40, 100):
        a_up = upright.angles[i]
        j = int(np.argmin(np.abs(inverted.angles + a_up)))
        assert inverted.angles[j] == pytest.approx(-a_up)
        assert inverted.ranges[j] == upright.ranges[i]


def test_stop_does_not_wait_for_a_slow_initialisation(rig):
    sim, driver, col = rig({'baud': 115200}, {'baud': 500000, 'reply_timeout': 2.0})
    time.sleep(0.2)  # probing, each probe would wait 2 s
    t0 = time.monotonic()
    driver.stop()
    assert time.monotonic() - t0 < 0.5 and not driver.running
    assert col.events[-1][0] == 'stopped'
