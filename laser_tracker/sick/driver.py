"""SICK LMS2xx serial driver: pyserial, a background reader, recovery; no ROS.

:class:`SickLmsDriver` opens the port, finds the rate the device is at, switches it to the
configured rate, sets the variant and the units, starts continuous output and hands every
complete scan (:class:`SickScan`) to a callback, from its own thread. It survives garbage,
CRC errors, NAKs, silence and the device disappearing: it closes the port, reopens the same
path and initialises the device again.

Interlaced scans: in continuous mode (0x24) the LMS assembles the 2 (0.5 degree) or 4
(0.25 degree) interlaced mirror turns itself and sends one 361/201/401-value telegram, which
is published as delivered, one scan per telegram. Partial-scan telegrams (count word bit 13,
only sent in mode 0x2A, which this driver never selects) would be published as delivered too,
with their 0.25 degree offset in ``angle_min``; the driver does not merge them.

Stamp model (``SickScan.stamp`` is the acquisition time of the first beam):

* the parser estimates when the telegram's first byte (STX) arrived, from the times chunks
  were read and the line's byte time ``10 / baud`` (see ``TelegramStreamParser``);
* the device starts sending when the mirror turn that completes the scan ends, so the first
  beam was measured one scan period (``revolutions / 75`` s) before the STX went on the line:
  ``stamp = t_first_byte - 10 / baud - revolutions / 75 + time_offset``;
* stamps are kept strictly increasing (at least 1 us apart).

The device's processing latency is not documented (UNCONFIRMED); ``time_offset`` calibrates
it. At 9600-38400 baud the line is slower than the mirror and the device sends its newest
scan when the line frees, which the model still describes (the STX time is measured).

The clock for stamps is a parameter (``clock``, default ``time.time``; the node passes the
ROS clock); timeouts and pacing use ``time.monotonic``.
"""
from __future__ import annotations

import errno
import math
import termios
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import serial

from laser_tracker.core.scan import Scan
from laser_tracker.errors import LaserTrackerError
from laser_tracker.sick import protocol as P
from laser_tracker.sick.config import SickLmsConfig  # noqa: F401  (re-exported)

RANGE_MIN = 0.01  # m; "no reading" is published as 0.0, below this (REP 117 style)
PROBE_ORDER = (9600, 38400, 19200, 500000)  # after the configured rate
MIN_STAMP_STEP = 1e-6
MAX_NAK_RESENDS = 3  # resends after NAKs, on top of the timeout retries


# ------------------------------------------------------------------------------ errors


class SickError(LaserTrackerError):
    """A driver failure; the message names the port."""


class PortError(SickError):
    def __init__(self, port: str, reason: str):
        self.port = port
        super().__init__(f'{port}: {reason}')


class PortNotFoundError(PortError):
    """The port does not exist (unplugged adapter, wrong name)."""


class PortBusyError(PortError):
    """Another program holds the port."""


class PortPermissionError(PortError):
    """No permission to open the port."""


class DeviceLostError(SickError):
    """The port failed or the device stopped sending; the driver reopens and re-initialises."""


class BaudDetectionError(SickError):
    """No LMS2xx answered at any of the rates probed."""


class DeviceTimeoutError(SickError):
    """No (good) reply to a command after the retries."""


class CommandRejectedError(SickError):
    """The device refused a command (0x92, wrong password, variant or configuration refused)."""


# ------------------------------------------------------------------------------- scans


@dataclass(frozen=True)
class SickScan:
    """One scan as delivered, ranges in metres.

    ``ranges`` follows REP 117 without NaN: +inf where the device reported "value above
    maximum" (nothing within range), 0.0 (below ``range_min``) for every other no-measurement
    code (not valid, dazzling, overflow, weak signal, read error).
    """

    stamp: float  # acquisition of the first beam (driver clock, seconds)
    first_byte_time: float  # estimated arrival of the telegram's STX (driver clock)
    ranges: np.ndarray
    values: np.ndarray  # the raw value words
    geometry: P.ScanGeometry
    range_min: float
    range_max: float
    units: P.RangeUnit
    measuring_mode: int
    status: P.StatusByte
    sequence: int

    def to_scan(self, frame_id: str = 'laser', inverted: bool = False) -> Scan:
        """The scan; ``inverted``: of the scanner mounted upside down, as the same scanner
        right side up would see it (``Scan.mirrored``)."""
        g = self.geometry
        scan = Scan(stamp=self.stamp, ranges=self.ranges, angle_min=g.angle_min,
                    angle_increment=g.angle_increment, range_min=self.range_min,
                    range_max=self.range_max, time_increment=g.time_increment,
                    scan_time=g.scan_time, frame_id=frame_id)
        return scan.mirrored() if inverted else scan


@dataclass(frozen=True)
class DriverStats:
    """A snapshot of the driver's state and counters (for diagnostics and tests)."""

    state: str  # disconnected / initialising / idle / streaming / stopped
    port: str
    baud: int | None
    device_type: str
    scans: int
    telegrams: int
    crc_errors: int
    length_errors: int
    bytes_discarded: int
    naks: int
    unexpected_replies: int
    bad_scans: int
    reconnects: int
    callback_errors: int
    status_byte: int | None
    scan_rate: float
    last_error: str


#: ``idle``: the port is open and the device set up, its continuous output stopped.
STATES = ('disconnected', 'initialising', 'idle', 'streaming', 'stopped')


# ------------------------------------------------------------------------------ driver


class SickLmsDriver:
    """The LMS2xx over pyserial. Use :meth:`start`/:meth:`stop` for the background reader,
    or :meth:`connect`, :meth:`read_once` and :meth:`close` step by step (tests, tools).

    A managed (lifecycle) node splits the set-up: ``connect(start_output=False)`` opens the
    port and initialises the device without starting its output (state ``idle``);
    :meth:`start` then starts the output and reads; ``stop(close_port=False)`` stops the
    reader and the device's output and keeps the port open; :meth:`close` releases the port.

    ``on_scan(scan)`` and ``on_event(state, message)`` are called from the reader thread;
    they must be quick and must not call back into the driver.
    """

    def __init__(self, config: SickLmsConfig, on_scan: Callable[[SickScan], None], *,
                 on_event: Callable[[str, str], None] | None = None,
                 clock: Callable[[], float] = time.time,
                 serial_class: type = serial.Serial):
        self.config = config
        self.on_scan = on_scan
        self.on_event = on_event or (lambda state, message: None)
        self.clock = clock
        self.serial_class = serial_class
        self._port: serial.Serial | None = None
        self._baud: int | None = None
        self._parser = P.TelegramStreamParser()
        self._lock = threading.Lock()
        self._state = 'disconnected'
        self._streaming = False
        self._ready = False  # the port is open and the device set up (output on or off)
        self._close_on_stop = True
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._measuring_mode = P.MEASURING_MODES[0]
        self._device_type = ''
        self._status_byte: int | None = None
        self._last_error = ''
        self._last_stamp = -math.inf
        self._last_scan_mono = 0.0
        self._arrivals: deque[float] = deque(maxlen=30)
        self._sequence = 0
        self._naks = self._unexpected = self._bad_scans = 0
        self._reconnects = self._callback_errors = 0

    # --------------------------------------------------------------- background use
    def start(self) -> None:
        """Start the reader thread: it connects (retrying every ``reconnect_period``) or,
        after ``connect(start_output=False)``, starts the output of the set-up device,
        streams, and recovers; errors are reported through ``on_event``."""
        if self._thread is not None:
            raise RuntimeError('driver already started')
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name='sick-lms-reader', daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 3.0, close_port: bool = True) -> None:
        """Stop the reader; it stops the device's output and closes the port (with
        ``close_port=False`` the port stays open and the device set up, state ``idle``)."""
        self._close_on_stop = close_port
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if not self._thread.is_alive():
                self._thread = None
        elif close_port:
            self.close()
        else:
            self.stop_output()

    def interrupt(self) -> None:
        """Make a :meth:`connect` in progress (in any thread) give up at its next read;
        safe from a signal handler. Until :meth:`start`, later commands give up too."""
        self._stop.set()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # noqa: BLE001 - a bug: report it instead of dying silently
            self._fail(exc)
            self.close()
            self._set_state('stopped', f'driver failed: {type(exc).__name__}: {exc}')

    def _loop(self) -> None:
        while not self._stop.is_set():
            if not self._streaming:
                try:
                    if self._ready:
                        self.start_output()
                    else:
                        self.connect()
                except SickError as exc:
                    self.close()
                    if self._stop.is_set():
                        break
                    self._fail(exc)
                    self._stop.wait(self.config.reconnect_period)
                    continue
            try:
                self.read_once()
            except DeviceLostError as exc:
                self.close()
                if self._stop.is_set():
                    break
                with self._lock:
                    self._reconnects += 1
                self._fail(exc)
        if self._close_on_stop or self._port is None:
            self.close(stop_output=True)
            self._set_state('stopped', 'driver stopped')
        else:
            self.stop_output()

    def _fail(self, exc: Exception) -> None:
        with self._lock:
            self._last_error = str(exc)
        self._set_state('disconnected', str(exc))

    def _set_state(self, state: str, message: str) -> None:
        with self._lock:
            self._state = state
        try:
            self.on_event(state, message)
        except Exception:  # noqa: BLE001 - a faulty listener must not kill the reader
            pass

    # ------------------------------------------------------------------ connection
    def connect(self, start_output: bool = True) -> None:
        """Open the port and initialise the device until it streams (or, without
        ``start_output``, until it is set up: state ``idle``); raises SickError."""
        self._set_state('initialising', f'opening {self.config.port}')
        if self._port is None:
            self._open()
        try:
            self._initialise()
        except (serial.SerialException, OSError, termios.error) as exc:
            raise DeviceLostError(f'{self.config.port}: {exc}') from None
        except P.ProtocolError as exc:  # e.g. a measuring mode without ranges (0x3F)
            raise SickError(f'{self.config.port}: unusable device reply: {exc}') from None
        self._ready = True
        if start_output:
            self.start_output()
        else:
            self._set_state('idle', f'{self.config.port}: ready at {self._baud} baud, '
                            f'{self._describe_setup()}')

    def _describe_setup(self) -> str:
        return (f'{self.config.scan_angle} deg / {self.config.resolution:g} deg, '
                f'{self.config.units} ({self._device_type or "unknown type"})')

    def start_output(self) -> None:
        """Start the continuous output of the set-up device; raises SickError."""
        cfg = self.config
        try:
            started = self._transact(P.start_continuous(), P.REPLY_MODE)
        except (serial.SerialException, OSError, termios.error) as exc:
            raise DeviceLostError(f'{cfg.port}: {exc}') from None
        if not started.ok:
            raise CommandRejectedError(f'{cfg.port}: continuous output refused '
                                       f'({started.describe()})')
        self._streaming = True
        self._last_scan_mono = time.monotonic()
        self._set_state('streaming', f'{cfg.port}: streaming at {self._baud} baud, '
                        f'{self._describe_setup()}')

    def stop_output(self) -> None:
        """Ask the device to stop its continuous output; the port stays open (``idle``).
        Without an answer the device counts as lost: the next start sets it up again."""
        if self._port is None or not self._streaming:
            return
        try:
            self._transact(P.stop_continuous(), P.REPLY_MODE, tries=2, abortable=False)
        except (SickError, serial.SerialException, OSError, termios.error):
            self._ready = False
        self._streaming = False
        self._set_state('idle', f'{self.config.port}: output stopped')

    def _open(self) -> None:
        port = self.config.port
        try:
            self._port = self.serial_class(port=port, baudrate=self.config.baud, timeout=0.05,
                                           write_timeout=1.0, exclusive=True)
        except serial.SerialException as exc:
            raise _port_error(port, exc) from None
        except OSError as exc:
            raise _port_error(port, exc) from None
        except ValueError as exc:
            raise PortError(port, f'cannot configure the port: {exc}') from None
        self._baud = self.config.baud
        self._parser.reset()

    def close(self, stop_output: bool = False) -> None:
        """Close the port; with ``stop_output`` first ask the device to stop streaming."""
        self._ready = False
        port = self._port
        if port is None:
            self._streaming = False
            return
        if stop_output and self._streaming:
            try:
                self._transact(P.stop_continuous(), P.REPLY_MODE, tries=2, abortable=False)
            except (SickError, serial.SerialException, OSError, termios.error):
                pass
        try:
            port.close()
        except (serial.SerialException, OSError, termios.error):
            pass
        self._port = None
        self._streaming = False

    def _set_rate(self, baud: int) -> None:
        self._port.baudrate = baud
        self._baud = baud
        self._parser.byte_time = P.frame_time(1, baud)
        self._port.reset_input_buffer()
        self._parser.reset()

    def _initialise(self) -> None:
        cfg = self.config
        current = self.detect_baud()
        if current != cfg.baud:
            reply = self._transact(P.set_baud_rate(cfg.baud), P.REPLY_MODE)
            if not reply.ok:
                raise CommandRejectedError(f'{cfg.port}: switching to {cfg.baud} baud refused '
                                           f'({reply.describe()})')
            self._set_rate(cfg.baud)
            time.sleep(0.05)  # sicktoolbox waits 250 ms, RACK 30 ms
            self._transact(P.stop_continuous(), P.REPLY_MODE)  # answers at the new rate?
        try:
            self._device_type = self._transact(P.request_type(), P.REPLY_TYPE).text
        except (CommandRejectedError, DeviceTimeoutError):
            self._device_type = 'unknown'
        variant = self._transact(P.set_variant(cfg.scan_angle, cfg.resolution_cdeg),
                                 P.REPLY_VARIANT)
        if not variant.accepted:
            raise CommandRejectedError(
                f'{cfg.port}: the device refused the variant {cfg.scan_angle} deg / '
                f'{cfg.resolution:g} deg (it keeps {variant.angle_deg} deg / '
                f'{variant.resolution_cdeg / 100:g} deg; LMS-S14 units have a fixed variant)')
        config = self._transact(P.request_config(), P.REPLY_CONFIG)
        block = bytearray(config.block)
        if block[P.CONFIG_UNITS_BYTE] != int(cfg.range_unit):
            mode = self._transact(P.installation_mode(cfg.password), P.REPLY_MODE)
            if not mode.ok:
                raise CommandRejectedError(f'{cfg.port}: installation mode refused '
                                           f'({mode.describe()}); check the password')
            block[P.CONFIG_UNITS_BYTE] = int(cfg.range_unit)
            written = self._transact(P.set_config(bytes(block)), P.REPLY_SET_CONFIG,
                                     timeout=15.0, tries=1)  # slow: sicktoolbox allows 15 s
            if not written.ok:
                raise CommandRejectedError(f'{cfg.port}: the device refused the configuration '
                                           f'(units {cfg.units})')
            block = bytearray(written.block)
        self._measuring_mode = P.measuring_mode(block[P.CONFIG_MODE_BYTE])
        status = self._transact(P.request_status(), P.REPLY_STATUS)
        self._status_byte = status.status.raw

    def detect_baud(self) -> int:
        """Find the device's rate: at each rate send "stop output" and wait for its reply
        (a good telegram of any code or a NAK at a rate earns a second round there)."""
        cfg = self.config
        rates = [cfg.baud] + [r for r in PROBE_ORDER if r != cfg.baud]
        for rate in rates:
            self._set_rate(rate)
            telegrams, naks = self._parser.counters.telegrams, self._naks
            for _ in range(2):
                try:
                    self._transact(P.stop_continuous(), P.REPLY_MODE, tries=2)
                    return rate
                except CommandRejectedError:
                    return rate  # it answered (0x92), so it is at this rate
                except DeviceTimeoutError:
                    # a good telegram or a NAK means the device is at this rate: insist once
                    if self._parser.counters.telegrams == telegrams and self._naks == naks:
                        break
        raise BaudDetectionError(
            f'{cfg.port}: no LMS2xx answered at {", ".join(map(str, rates))} baud (the '
            f'device is at another rate, off, or not connected); check power and cabling')

    # ------------------------------------------------------------------ commands
    def _write(self, data: bytes) -> None:
        try:
            self._port.write(data)
        except serial.SerialTimeoutException:
            raise DeviceLostError(f'{self.config.port}: write timed out') from None

    def _read(self) -> tuple[bytes, float]:
        port = self._port
        try:
            data = port.read(max(1, port.in_waiting))
        except (serial.SerialException, OSError) as exc:
            raise DeviceLostError(f'{self.config.port}: {exc}') from None
        return data, self.clock()

    def _transact(self, request: bytes, expected: int, timeout: float | None = None,
                  tries: int = 3, abortable: bool = True):
        """Send ``request`` and return the decoded reply with code ``expected``.

        Flushes the input first; resends after a timeout (``tries`` times in all) and after
        a NAK (up to ``MAX_NAK_RESENDS`` more); 0x92 raises CommandRejectedError; other
        well-framed replies are counted and skipped. ``abortable``: give up as soon as
        :meth:`stop` is called (so shutdown never waits for a slow initialisation).
        """
        timeout = self.config.reply_timeout if timeout is None else timeout
        line = P.frame_time(len(request) + 200, self._baud)
        streaming_allowance = P.frame_time(2 * P.max_frame_bytes(), self._baud)
        timeouts = naks = 0
        while timeouts < tries and naks <= MAX_NAK_RESENDS:
            self._port.reset_input_buffer()
            self._parser.reset()
            self._write(request)
            deadline = time.monotonic() + timeout + line
            extended = nak = False
            while not nak and time.monotonic() < deadline:
                if abortable and self._stop.is_set():
                    raise DeviceLostError(f'{self.config.port}: driver stopping')
                data, t = self._read()
                if data and not extended:  # bytes arriving: maybe a scan ahead of the reply
                    deadline += streaming_allowance
                    extended = True
                for item in self._parser.feed(data, t):
                    if isinstance(item, P.Handshake) and not item.ack:
                        nak = True
                        break
                    if not isinstance(item, P.ReceivedTelegram) or not item.telegram.is_reply:
                        continue
                    code = item.telegram.command
                    if code == expected:
                        try:
                            return P.decode_reply(item.telegram)
                        except P.ProtocolError:
                            with self._lock:
                                self._unexpected += 1
                            continue
                    if code == P.REPLY_INCORRECT_COMMAND:
                        raise CommandRejectedError(
                            f'{self.config.port}: the device rejected command '
                            f'0x{request[4]:02X} (reply 0x92, incorrect command)')
                    with self._lock:
                        self._unexpected += 1
            if nak:
                naks += 1
                with self._lock:
                    self._naks += 1
                time.sleep(0.01)
            else:
                timeouts += 1
        what = f'{naks} NAKs' if naks > MAX_NAK_RESENDS else f'{tries} tries'
        raise DeviceTimeoutError(f'{self.config.port}: no reply 0x{expected:02X} to command '
                                 f'0x{request[4]:02X} at {self._baud} baud after {what}')

    # ------------------------------------------------------------------- streaming
    def silence_limit(self) -> float:
        """Seconds without a good scan before the device counts as lost."""
        frame = P.frame_time(self.config.variant.frame_bytes, self._baud or self.config.baud)
        return self.config.silence_timeout + 3.0 * frame

    def read_once(self) -> int:
        """Read what has arrived (waits up to 50 ms), deliver complete scans; returns how many.

        Raises DeviceLostError if the port fails or no good scan came for too long.
        """
        data, t = self._read()
        delivered = 0
        for item in self._parser.feed(data, t):
            if not isinstance(item, P.ReceivedTelegram):
                continue
            if item.telegram.command == P.REPLY_VALUES:
                delivered += self._deliver(item)
            else:
                with self._lock:
                    self._unexpected += 1
        now = time.monotonic()
        if delivered:
            self._last_scan_mono = now
        elif now - self._last_scan_mono > self.silence_limit():
            raise DeviceLostError(f'{self.config.port}: no good scan for '
                                  f'{now - self._last_scan_mono:.1f} s')
        return delivered

    def _deliver(self, item: P.ReceivedTelegram) -> int:
        try:
            values = P.decode_measured_values(item.telegram)
            geometry = P.scan_geometry(values)
        except P.ProtocolError:
            with self._lock:
                self._bad_scans += 1
            return 0
        mode = self._measuring_mode
        ranges = P.ranges_in_metres(values.values, mode, values.units)
        _, range_max = P.range_limits(mode, values.units)
        first = item.first_byte_time if item.first_byte_time is not None else self.clock()
        stamp = (first - P.frame_time(1, self._baud) - geometry.scan_time
                 + self.config.time_offset)
        stamp = max(stamp, self._last_stamp + MIN_STAMP_STEP)
        self._last_stamp = stamp
        with self._lock:
            self._sequence += 1
            self._status_byte = values.status.raw
            self._arrivals.append(time.monotonic())
            sequence = self._sequence
        scan = SickScan(stamp=stamp, first_byte_time=first, ranges=ranges,
                        values=values.values, geometry=geometry, range_min=RANGE_MIN,
                        range_max=range_max, units=values.units,
                        measuring_mode=mode.code, status=values.status, sequence=sequence)
        try:
            self.on_scan(scan)
        except Exception:  # noqa: BLE001 - the reader outlives a faulty consumer
            with self._lock:
                self._callback_errors += 1
        return 1

    # ----------------------------------------------------------------------- stats
    def stats(self) -> DriverStats:
        with self._lock:
            c = self._parser.counters
            arrivals = list(self._arrivals)
            rate = 0.0
            if len(arrivals) >= 2 and time.monotonic() - arrivals[-1] < 2.0:
                rate = (len(arrivals) - 1) / max(arrivals[-1] - arrivals[0], 1e-9)
            return DriverStats(
                state=self._state, port=self.config.port,
                baud=self._baud if self._state in ('idle', 'streaming') else None,
                device_type=self._device_type, scans=self._sequence, telegrams=c.telegrams,
                crc_errors=c.crc_errors, length_errors=c.length_errors,
                bytes_discarded=c.bytes_discarded, naks=self._naks,
                unexpected_replies=self._unexpected, bad_scans=self._bad_scans,
                reconnects=self._reconnects, callback_errors=self._callback_errors,
                status_byte=self._status_byte, scan_rate=rate, last_error=self._last_error)


def _port_error(port: str, exc: Exception) -> PortError:
    """Map an open failure to an error that names the port and says what to do."""
    code = getattr(exc, 'errno', None)
    text = str(exc)
    if code in (errno.ENOENT, errno.ENODEV, errno.ENXIO) or 'No such file' in text:
        return PortNotFoundError(port, 'no such serial port (unplugged, or a wrong name?)')
    if code in (errno.EACCES, errno.EPERM) or 'Permission denied' in text:
        return PortPermissionError(port, 'permission denied; add the user to the group that '
                                   'owns the port (usually dialout) or fix its udev rule')
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK) or 'lock' in text.lower():
        return PortBusyError(port, 'busy: another program has the port open')
    return PortError(port, f'cannot open: {text}')


__all__ = ['SickLmsConfig', 'SickLmsDriver', 'SickScan', 'DriverStats', 'SickError',
           'PortError', 'PortNotFoundError', 'PortBusyError', 'PortPermissionError',
           'DeviceLostError', 'BaudDetectionError', 'DeviceTimeoutError',
           'CommandRejectedError', 'RANGE_MIN']
