"""A SICK LMS2xx on a pseudo-terminal: the binary protocol, the line rate, and faults on demand.

Two layers:

* :class:`Lms2xxDevice` is the device's protocol state machine, pure: a host telegram in,
  the reply telegram (and a pending baud-rate change) out.
* :class:`Lms2xxSimulator` puts it on a pty (``os.openpty``) behind a symlink it can re-point
  (unplug / replug), paces every byte at the device's rate, streams 0xB0 telegrams at the
  rate the mirror and the line allow, and injects faults.

How "the device is at baud X" is modelled: Linux ptys do not enforce baud rates, but the
termios of the slave (where pyserial sets the host's rate) is readable from the master side
with ``tcgetattr``. Before handling host bytes and before writing device bytes the simulator
compares the host's rate with the rate it believes the device is at. If they differ, host
bytes are dropped unread (the device sees framing errors and stays silent) and device bytes
are replaced by random bytes (as many, or fewer if the host is slower), which is what a UART
at the wrong rate delivers: noise that never passes the CRC.

Timing: a byte takes ``10 / baud`` s (8N1); the mirror turns at 75 Hz; an interlaced scan
(0.5 or 0.25 degrees) completes every 2 or 4 turns. When the line is free the device sends
the newest completed scan it has not sent yet, so at 9600/19200/38400 baud it skips scans
(which the real device does or buffers is UNCONFIRMED; skipping keeps the data fresh). All
device times are divided by ``speedup`` (for fast tests); bytes are written as their
transmission completes, so the host sees them arrive at the line rate.
"""
from __future__ import annotations

import enum
import errno
import math
import os
import select
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from laser_tracker.errors import InputFileError
from laser_tracker.sick import protocol as P

# (scan index, device time in s, beam angles in rad) -> ranges in metres; inf = no return,
# NaN = "not valid". Angles follow REP 103 in the laser frame (0 ahead, +90 deg left).
RangeSource = Callable[[int, float, np.ndarray], np.ndarray]

DEFAULT_TYPE = 'LMS200;30106'
DEFAULT_LINK = '/tmp/sick-lms2xx'


# ------------------------------------------------------------------------ range sources


class SyntheticRoom:
    """A rectangular room with a pillar and a person walking to and fro; 1 cm of noise.

    The noise is seeded by the scan index, so every scan differs and any scan can be
    recomputed exactly.
    """

    def __init__(self, x_min=-2.0, x_max=6.0, y_min=-3.0, y_max=3.0, noise=0.01, seed=0):
        self.box = (x_min, x_max, y_min, y_max)
        self.noise, self.seed = noise, seed
        self.pillar = (3.5, 1.5, 0.3)
        self.walker_radius = 0.25

    def walker(self, t: float) -> tuple[float, float]:
        """Walks between y = -2 and y = +2 at x = 2.5, 1 m/s."""
        phase = (t % 8.0) / 4.0
        y = -2.0 + 4.0 * (phase if phase <= 1.0 else 2.0 - phase)
        return 2.5, y

    def __call__(self, index: int, t: float, angles: np.ndarray) -> np.ndarray:
        c, s = np.cos(angles), np.sin(angles)
        x_min, x_max, y_min, y_max = self.box
        with np.errstate(divide='ignore', invalid='ignore'):
            tx = np.where(c > 0, x_max / c, np.where(c < 0, x_min / c, np.inf))
            ty = np.where(s > 0, y_max / s, np.where(s < 0, y_min / s, np.inf))
        r = np.minimum(tx, ty)
        wx, wy = self.walker(t)
        for cx, cy, radius in (self.pillar, (wx, wy, self.walker_radius)):
            b = c * cx + s * cy
            disc = b * b - (cx * cx + cy * cy - radius * radius)
            hit = (disc >= 0) & (b > 0)
            d = b - np.sqrt(np.where(hit, disc, 0.0))
            r = np.where(hit & (d > 0) & (d < r), d, r)
        rng = np.random.default_rng((self.seed, index))
        return r + rng.normal(0.0, self.noise, r.shape)


class RecordingSource:
    """Ranges replayed from a recording, cycled: a rosbag2 folder (its ``/scan`` topic), a
    ``.npy`` array (scans x beams, metres, spanning -90..+90 degrees evenly) or a ``.csv`` of
    the same. Each device beam takes the recorded beam nearest in angle; beams outside the
    recorded span read as no return."""

    def __init__(self, path: str | Path, topic: str = '/scan'):
        path = Path(path)
        self.path = path
        self.scans: list[tuple[float, float, np.ndarray]] = []  # angle_min, increment, ranges
        if path.suffix in ('.npy', '.csv'):
            try:
                rows = np.load(path) if path.suffix == '.npy' else np.loadtxt(path, delimiter=',',
                                                                              ndmin=2)
            except (OSError, ValueError) as exc:
                raise InputFileError(path, f'cannot read ranges: {exc}') from None
            rows = np.atleast_2d(np.asarray(rows, dtype=float))
            if rows.shape[1] < 2:
                raise InputFileError(path, 'need at least 2 beams per row')
            inc = math.pi / (rows.shape[1] - 1)
            self.scans = [(-math.pi / 2, inc, row) for row in rows]
        else:
            # rosbags only when a bag is replayed
            from laser_tracker.tools.bag import read_scans, scan_topic_of

            for scan in read_scans(path, scan_topic_of(path, topic, '--topic')):
                if isinstance(scan, Exception):
                    continue
                self.scans.append((scan.angle_min, scan.angle_increment, scan.ranges))
        if not self.scans:
            raise InputFileError(path, f'no usable scans (topic {topic})')

    def __call__(self, index: int, t: float, angles: np.ndarray) -> np.ndarray:
        angle_min, inc, ranges = self.scans[index % len(self.scans)]
        k = np.rint((angles - angle_min) / inc).astype(np.int64)
        inside = (k >= 0) & (k < ranges.size)
        out = np.full(angles.shape, np.inf)
        out[inside] = ranges[k[inside]]
        return out


class ScenarioSource:
    """Ranges from the scenario simulator (``laser_tracker.tools.sim``): the scene of scenario
    ``name`` cast from the platform's pose at the scan time (looped over the scenario's
    duration), through its sensor model (noise, dropouts, spurious returns). Its no-return
    reading (``range_max``) becomes the device's "value above maximum"."""

    def __init__(self, name: str, seed: int | None = None):
        from laser_tracker.tools.sim import scenarios
        from laser_tracker.tools.sim.lidar import Lidar

        if name not in scenarios.SCENARIOS:
            raise ValueError(f'unknown scenario {name!r}; known: {", ".join(scenarios.SCENARIOS)}')
        self.scenario = scenarios.build(name, seed)
        self.lidar = Lidar(self.scenario.lidar)
        self._seed = self.scenario.seed

    def __call__(self, index: int, t: float, angles: np.ndarray) -> np.ndarray:
        from laser_tracker.tools.sim.world import cast

        sc = self.scenario
        span = max(sc.duration - sc.scan_start, 1e-3)
        t = sc.scan_start + (t % span)
        n = angles.size
        times = np.full(n, t)
        pose = sc.platform.pose(times)
        lc = sc.lidar
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        origins = np.column_stack([pose[:, 0] + c * lc.mount_x - s * lc.mount_y,
                                   pose[:, 1] + s * lc.mount_x + c * lc.mount_y])
        heading = pose[:, 2] + lc.mount_yaw + angles
        directions = np.column_stack([np.cos(heading), np.sin(heading)])
        seg = sc.world.segments
        circ = sc.world.circles
        seg_sets = [(seg, np.zeros(len(seg), dtype=np.int64))]
        circ_sets = [(circ, np.zeros(len(circ), dtype=np.int64))]
        for a in sc.agents:
            if not a.trajectory.exists(t):
                continue
            ac, asg = a.circles(times), a.segments(times)
            if ac.shape[1]:
                circ_sets.append((ac, np.full(ac.shape[1], a.id, dtype=np.int64)))
            if asg.shape[1]:
                seg_sets.append((asg, np.full(asg.shape[1], a.id, dtype=np.int64)))
        true_ranges, _ = cast(origins, directions, seg_sets, circ_sets)
        readings, _ = self.lidar.measure(true_ranges, np.random.default_rng((self._seed, index)))
        return np.where(readings >= lc.range_max, np.inf, readings)


# --------------------------------------------------------------------- device model


def default_config_block(units: P.RangeUnit = P.RangeUnit.CM, measuring_mode: int = 0) -> bytearray:
    """A 34-byte configuration block (the sicktoolbox/MRPT size) with LMS200-like values."""
    block = bytearray(34)
    block[2] = 0x46  # stop threshold
    block[3] = 0x00  # peak threshold
    block[P.CONFIG_MODE_BYTE] = measuring_mode
    block[P.CONFIG_UNITS_BYTE] = int(units)
    return block


@dataclass
class DeviceAnswer:
    """What the device sends for one host telegram: handshake byte, then maybe a reply."""

    handshake: int = P.ACK
    reply: bytes | None = None  # a framed telegram
    new_baud: int | None = None  # switch after the reply is on the line
    stream: bool | None = None  # start (True) / stop (False) continuous output
    scan_request: bool = False  # 0x30 0x01: reply with the newest scan (built by the I/O layer)


class Lms2xxDevice:
    """The protocol state of an LMS2xx (pure; no time, no I/O).

    Power-on state: 9600 baud, values on request (not streaming). Variant and configuration
    survive a power cycle (the real device keeps them in EEPROM; UNCONFIRMED for 0x3B).
    Commands it does not simulate (other operating modes, 0x3C, 0x3D, ...) get 0x92.
    """

    def __init__(self, scan_angle: int = 180, resolution_cdeg: int = 100,
                 units: P.RangeUnit = P.RangeUnit.CM, measuring_mode: int = 0,
                 device_type: str = DEFAULT_TYPE, status_byte: int = 0x10,
                 password: str = P.DEFAULT_PASSWORD):
        P.check_variant(scan_angle, resolution_cdeg)
        P.measuring_mode(measuring_mode)
        self.scan_angle, self.resolution_cdeg = scan_angle, resolution_cdeg
        self.config = default_config_block(units, measuring_mode)
        self.device_type = device_type
        self.status_byte = status_byte
        self.password = password
        self.baud = P.DEFAULT_BAUD
        self.streaming = False
        self.installation = False

    # -- state
    @property
    def units(self) -> P.RangeUnit:
        return P.RangeUnit(self.config[P.CONFIG_UNITS_BYTE])

    @property
    def mode(self) -> P.MeasuringMode:
        return P.measuring_mode(self.config[P.CONFIG_MODE_BYTE])

    @property
    def count(self) -> int:
        return P.value_count(self.scan_angle, self.resolution_cdeg)

    @property
    def revolutions(self) -> int:
        return 100 // self.resolution_cdeg

    def angles(self) -> np.ndarray:
        """Beam angles (rad, REP 103) of the current variant."""
        half = self.scan_angle / 2.0
        return np.radians(np.linspace(-half, half, self.count))

    def power_on(self) -> None:
        self.baud = P.DEFAULT_BAUD
        self.streaming = False
        self.installation = False

    def reply(self, payload: bytes) -> bytes:
        """Frame a reply payload (without status) and append the status byte."""
        return P.frame(bytes(payload) + bytes((self.status_byte,)), P.REPLY_ADDRESS)

    def scan_reply(self, values: np.ndarray) -> bytes:
        return P.frame(P.encode_measured_values(values, self.units, self.status_byte),
                       P.REPLY_ADDRESS)

    def values_from_ranges(self, ranges: np.ndarray) -> np.ndarray:
        return P.metres_to_values(ranges, self.mode, self.units)

    def status_block(self) -> bytes:
        """The 152 data bytes of the 0xB1 reply, filled at the offsets the drivers read."""
        p = bytearray(153)  # index 0 = command byte, as in the fact sheet's offsets
        p[0] = P.REPLY_STATUS
        p[1:8] = b'V02.10 '
        p[8] = 0x24 if self.streaming else 0x25
        p[9] = 0x00
        p[18] = 0x01
        p[102] = self.config[P.CONFIG_MODE_BYTE]
        p[107:109] = self.scan_angle.to_bytes(2, 'little')
        p[109:111] = self.resolution_cdeg.to_bytes(2, 'little')
        p[116:118] = P.baud_divisor(self.baud).to_bytes(2, 'little')
        p[119] = 0
        p[120] = 0
        p[122] = self.config[P.CONFIG_UNITS_BYTE]
        return bytes(p[1:])

    # -- commands
    def handle(self, telegram: P.Telegram) -> DeviceAnswer:
        cmd, data = telegram.command, telegram.data
        if cmd == P.CMD_OPERATING_MODE and data:
            return self._operating_mode(data[0], data[1:])
        if cmd == P.CMD_REQUEST_VALUES and data == b'\x01':
            return DeviceAnswer(scan_request=True)
        if cmd == P.CMD_REQUEST_STATUS and not data:
            return DeviceAnswer(reply=self.reply(bytes((P.REPLY_STATUS,)) + self.status_block()))
        if cmd == P.CMD_REQUEST_TYPE and not data:
            text = self.device_type.encode('ascii')[:20].ljust(20, b' ')
            return DeviceAnswer(reply=self.reply(bytes((P.REPLY_TYPE,)) + text + b'\x00'))
        if cmd == P.CMD_SET_VARIANT and len(data) == 4:
            angle, res = int.from_bytes(data[:2], 'little'), int.from_bytes(data[2:], 'little')
            try:
                P.check_variant(angle, res)
                self.scan_angle, self.resolution_cdeg, ok = angle, res, 1
            except ValueError:
                ok = 0
            body = bytes((P.REPLY_VARIANT, ok)) + self.scan_angle.to_bytes(2, 'little') \
                + self.resolution_cdeg.to_bytes(2, 'little')
            # a variant change stops continuous output (sicktoolbox)
            return DeviceAnswer(reply=self.reply(body), stream=False if self.streaming else None)
        if cmd == P.CMD_REQUEST_CONFIG and not data:
            return DeviceAnswer(reply=self.reply(bytes((P.REPLY_CONFIG,)) + bytes(self.config)))
        if cmd == P.CMD_SET_CONFIG:
            return self._set_config(data)
        if cmd == P.CMD_RESET and not data:
            self.power_on()
            return DeviceAnswer(reply=self.reply(bytes((P.REPLY_RESET,))), new_baud=P.DEFAULT_BAUD,
                                stream=False)
        return DeviceAnswer(reply=self.reply(bytes((P.REPLY_INCORRECT_COMMAND, 0x00))))

    def _operating_mode(self, mode: int, extra: bytes) -> DeviceAnswer:
        if mode == P.MODE_INSTALLATION:
            if len(extra) != 8:
                return DeviceAnswer(reply=self.reply(bytes((P.REPLY_INCORRECT_COMMAND, 0x00))))
            ok = extra == self.password.encode('ascii')
            self.installation = self.installation or ok
            return DeviceAnswer(reply=self.reply(bytes((P.REPLY_MODE, 0x00 if ok else 0x01))))
        ok_reply = self.reply(bytes((P.REPLY_MODE, 0x00)))
        if mode == P.MODE_CONTINUOUS:
            self.streaming, self.installation = True, False
            return DeviceAnswer(reply=ok_reply, stream=True)
        if mode == P.MODE_ON_REQUEST:
            self.streaming, self.installation = False, False
            return DeviceAnswer(reply=ok_reply, stream=False)
        for baud, code in P.BAUD_MODES.items():
            if mode == code:
                return DeviceAnswer(reply=ok_reply, new_baud=baud)
        return DeviceAnswer(reply=self.reply(bytes((P.REPLY_INCORRECT_COMMAND, 0x00))))

    def _set_config(self, data: bytes) -> DeviceAnswer:
        ok = (self.installation and len(data) == len(self.config)
              and data[P.CONFIG_MODE_BYTE] in P.MEASURING_MODES
              and data[P.CONFIG_UNITS_BYTE] in (0, 1))
        if ok:
            self.config = bytearray(data)
        body = bytes((P.REPLY_SET_CONFIG, 0x01 if ok else 0x00)) + bytes(self.config)
        return DeviceAnswer(reply=self.reply(body))


# ---------------------------------------------------------------------------- faults


class Corruption(str, enum.Enum):
    FLIP = 'flip'  # one bit flipped
    DROP = 'drop'  # 1-3 bytes removed
    INSERT = 'insert'  # 1-3 random bytes inserted


def corrupt(data: bytes, kind: Corruption, rng: np.random.Generator) -> bytes:
    """A damaged copy of a telegram (never identical to it)."""
    buf = bytearray(data)
    if kind == Corruption.FLIP:
        i = int(rng.integers(len(buf)))
        buf[i] ^= 1 << int(rng.integers(8))
    elif kind == Corruption.DROP:
        n = int(rng.integers(1, 4))
        i = int(rng.integers(0, len(buf) - n + 1))
        del buf[i:i + n]
    else:
        n = int(rng.integers(1, 4))
        i = int(rng.integers(0, len(buf) + 1))
        buf[i:i] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
    return bytes(buf)


@dataclass
class SentScan:
    """One 0xB0 telegram the simulator put on the line (for tests and the benchmark)."""

    index: int  # mirror scan index
    values: np.ndarray  # uint16 value words
    units: P.RangeUnit
    measuring_mode: int
    acquired: float  # time.monotonic() when the scan's first revolution started
    tx_start: float  # time.monotonic() when its STX started on the line
    baud: int
    corruption: str | None = None


@dataclass
class SimCounters:
    requests: int = 0
    naks_sent: int = 0
    scans_sent: int = 0
    scans_corrupted: int = 0
    bytes_written: int = 0
    bytes_dropped: int = 0  # device output nobody could take (host away or buffer full)
    garbled_in: int = 0  # host bytes sent at a rate the device is not at
    garbled_out: int = 0
    unplugs: int = 0


@dataclass
class _Segment:
    data: bytes
    start: float  # real time the first byte starts on the line
    byte_time: float
    baud: int
    written: int = 0
    on_done: Callable[[], None] | None = None

    @property
    def end(self) -> float:
        return self.start + len(self.data) * self.byte_time


_SPEEDS = {getattr(termios, f'B{b}'): b for b in (50, 75, 110, 134, 150, 200, 300, 600, 1200,
           1800, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000,
           921600, 1000000) if hasattr(termios, f'B{b}')}


class Lms2xxSimulator:
    """An LMS2xx on a pty behind ``link`` (a symlink the simulator re-points on replug).

    ``start()`` returns the link path; open it with pyserial as if it were /dev/ttyUSB0.
    Thread-safe fault controls: :meth:`corrupt_next`, :meth:`inject_bytes`, :meth:`nak_next`,
    :meth:`wrong_reply_next`, :meth:`silence`, :meth:`set_slow`, :meth:`unplug`,
    :meth:`replug`, ``fault_rate`` (random corruption of streamed telegrams). ``sent``
    records every streamed telegram (values, acquisition time, corruption) for checking.
    """

    def __init__(self, link: str | Path = DEFAULT_LINK, ranges: RangeSource | None = None, *,
                 baud: int = P.DEFAULT_BAUD, speedup: float = 1.0, scan_angle: int = 180,
                 resolution_cdeg: int = 100, units: str = 'cm', measuring_mode: int = 0,
                 device_type: str = DEFAULT_TYPE, seed: int = 0, boot_time: float = 0.0,
                 ack_delay: float = 0.002, reply_delay: float = 0.005, fault_rate: float = 0.0,
                 fault_kinds: Sequence[Corruption | str] = tuple(Corruption),
                 record: bool = True):
        if speedup <= 0:
            raise ValueError(f'speedup must be positive, got {speedup!r}')
        self.link = Path(link)
        self.ranges = ranges or SyntheticRoom(seed=seed)
        self.device = Lms2xxDevice(scan_angle, resolution_cdeg, P.RangeUnit.parse(units),
                                   measuring_mode, device_type)
        self.device.baud = int(baud)
        self.speedup = float(speedup)
        self.boot_time, self.ack_delay, self.reply_delay = boot_time, ack_delay, reply_delay
        self.fault_rate = fault_rate
        self.fault_kinds = tuple(Corruption(k) for k in fault_kinds)
        self.record = record
        self.sent: list[SentScan] = []
        self.errors: list[str] = []  # exceptions inside the simulator loop (should stay empty)
        self.counters = SimCounters()
        self.slave_name: str | None = None
        self._rng = np.random.default_rng(seed)
        self._lock = threading.RLock()
        self._master: int | None = None
        self._slave: int | None = None
        self._segments: deque[_Segment] = deque()
        self._parser = P.TelegramStreamParser(P.DEVICE_ADDRESS, min_length=1)
        self._corrupt_queue: deque[Corruption] = deque()
        self._naks = 0
        self._wrong_replies = 0
        self._silent_until = 0.0
        self._booting_until = 0.0
        self._slow = 0.0
        self._mirror_t0 = time.monotonic()
        self._last_scan = -1
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Path:
        with self._lock:
            self._open_pty()
        self._thread = threading.Thread(target=self._run, name='lms2xx-sim', daemon=True)
        self._thread.start()
        return self.link

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        with self._lock:
            self._close_pty(remove_link=True)

    def __enter__(self) -> Lms2xxSimulator:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing, before anyone writes
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.slave_name = os.ttyname(slave)
        tmp = self.link.with_name(self.link.name + f'.{os.getpid()}.tmp')
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(self.slave_name)
        os.replace(tmp, self.link)  # atomic re-point: readers never see a missing link
        self._parser.reset()
        self._segments.clear()

    def _close_pty(self, remove_link: bool) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None
        self._segments.clear()
        if remove_link and self.link.is_symlink():
            try:
                self.link.unlink()
            except FileNotFoundError:
                pass

    # --------------------------------------------------------------- fault controls
    @property
    def plugged(self) -> bool:
        return self._master is not None

    @property
    def baud(self) -> int:
        return self.device.baud

    def corrupt_next(self, kind: Corruption | str, count: int = 1) -> None:
        """Damage the next ``count`` streamed telegrams."""
        with self._lock:
            self._corrupt_queue.extend([Corruption(kind)] * count)

    def nak_next(self, count: int = 1) -> None:
        """Answer the next ``count`` host telegrams with NAK and no reply."""
        with self._lock:
            self._naks += count

    def wrong_reply_next(self, count: int = 1) -> None:
        """Answer the next ``count`` host telegrams with a well-framed reply of a wrong code."""
        with self._lock:
            self._wrong_replies += count

    def inject_bytes(self, data: bytes) -> None:
        """Put raw bytes on the line (after what is queued): garbage, fake headers, ..."""
        with self._lock:
            if self.plugged:
                self._enqueue(bytes(data), time.monotonic())

    def silence(self, seconds: float) -> None:
        """The device hangs: no output, input ignored, for ``seconds`` (real time)."""
        with self._lock:
            self._silent_until = time.monotonic() + seconds
            self._segments.clear()

    def set_slow(self, latency: float) -> None:
        """A slow device: every answer and every streamed telegram ``latency`` s later."""
        with self._lock:
            self._slow = max(0.0, latency)

    def set_status_byte(self, value: int) -> None:
        with self._lock:
            self.device.status_byte = value & 0xFF

    def unplug(self) -> None:
        """The device disappears: the pty master closes, the link is removed."""
        with self._lock:
            if self.plugged:
                self.counters.unplugs += 1
                self._close_pty(remove_link=True)

    def replug(self, power_cycle: bool = True) -> None:
        """A new pty at the same link. ``power_cycle``: the device restarts at 9600, idle,
        and sends its 0x90 power-on telegram after ``boot_time``; otherwise (a USB adapter
        replugged, laser still powered) it keeps its rate and keeps streaming."""
        with self._lock:
            if self.plugged:
                self._close_pty(remove_link=False)
            self._open_pty()
            if power_cycle:
                self.device.power_on()
                now = time.monotonic()
                self._booting_until = now + self.boot_time / self.speedup
                power_on = self.device.reply(bytes((P.REPLY_POWER_ON,))
                                             + self.device.device_type.encode('ascii')[:21]
                                             .ljust(21, b'\x00'))
                self._enqueue(power_on, self._booting_until)

    # ---------------------------------------------------------------------- timing
    def byte_time(self) -> float:
        return P.BITS_PER_BYTE / self.device.baud / self.speedup

    def scan_period(self) -> float:
        return self.device.revolutions * P.MIRROR_PERIOD / self.speedup

    def host_baud(self) -> int | None:
        """The rate the host set on its end of the pty (None if unknown or unplugged)."""
        if self._master is None:
            return None
        try:
            return _SPEEDS.get(termios.tcgetattr(self._master)[5])
        except termios.error:
            return None

    # --------------------------------------------------------------------- the loop
    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                master = self._master
            if master is None:
                time.sleep(0.005)
                continue
            timeout = self._step_timeout()
            try:
                readable, _, _ = select.select([master], [], [], timeout)
            except (OSError, ValueError):  # closed by unplug() meanwhile
                continue
            with self._lock:
                if self._master != master:
                    continue
                now = time.monotonic()
                try:
                    if readable:
                        self._read_host(now)
                    self._stream(now)
                    self._write_due(now)
                except Exception as exc:  # noqa: BLE001 - keep the device alive, record the bug
                    self.errors.append(f'{type(exc).__name__}: {exc}')
                    self._segments.clear()

    def _step_timeout(self) -> float:
        with self._lock:
            now = time.monotonic()
            wake = now + 0.005
            if self._segments:
                head = self._segments[0]
                wake = min(wake, head.start + (head.written + 1) * head.byte_time)
            if self.device.streaming:
                period = self.scan_period()
                nxt = self._mirror_t0 + (math.floor((now - self._mirror_t0) / period) + 1) * period
                wake = min(wake, nxt)
            return min(max(wake - now, 0.0005), 0.005)

    def _read_host(self, now: float) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:  # EIO: nobody has the slave open (cannot happen while we hold it)
            if exc.errno != errno.EIO:
                raise
            return
        if not data or now < self._silent_until or now < self._booting_until:
            return
        if self.host_baud() != self.device.baud:
            self.counters.garbled_in += len(data)
            return
        for item in self._parser.feed(data, now):
            if isinstance(item, P.RejectedFrame) and item.reason == 'crc':
                self._send_handshake(P.NAK, now)  # NAK for a bad CRC: UNCONFIRMED, documented
            elif isinstance(item, P.ReceivedTelegram):
                self._answer(item.telegram, now)

    def _send_handshake(self, byte: int, now: float) -> None:
        if byte == P.NAK:
            self.counters.naks_sent += 1
        self._enqueue(bytes((byte,)), now + (self.ack_delay + self._slow) / self.speedup)

    def _answer(self, telegram: P.Telegram, now: float) -> None:
        self.counters.requests += 1
        if self._naks > 0:
            self._naks -= 1
            self._send_handshake(P.NAK, now)
            return
        was_streaming = self.device.streaming
        answer = self.device.handle(telegram)
        self._send_handshake(answer.handshake, now)
        reply = answer.reply
        if reply is not None and self._wrong_replies > 0:
            self._wrong_replies -= 1
            reply = P.frame(bytes((0xB5,)) + reply[5:-2], P.REPLY_ADDRESS)
            answer.new_baud = None
        if reply is not None:
            on_done = None
            if answer.new_baud is not None:
                new = answer.new_baud

                def on_done(new=new):
                    self.device.baud = new
            self._enqueue(reply, now + (self.reply_delay + self._slow) / self.speedup, on_done)
        if answer.scan_request:  # the newest completed scan (the first one, if none yet)
            period = self.scan_period()
            newest = max(math.floor((now - self._mirror_t0) / period) - 1, 0)
            ready = self._mirror_t0 + (newest + 1) * period
            self._enqueue_scan(newest, max(ready, now + (self.reply_delay + self._slow)
                                           / self.speedup), corruptible=False)
        if (answer.stream and not was_streaming) or telegram.command == P.CMD_SET_VARIANT:
            period = self.scan_period()
            self._last_scan = math.floor((now - self._mirror_t0) / period)

    def _enqueue(self, data: bytes, not_before: float,
                 on_done: Callable[[], None] | None = None) -> _Segment:
        line_free = self._segments[-1].end if self._segments else 0.0
        seg = _Segment(data, max(not_before, line_free), self.byte_time(), self.device.baud,
                       on_done=on_done)
        self._segments.append(seg)
        return seg

    def _stream(self, now: float) -> None:
        dev = self.device
        if not dev.streaming or self._segments or now < self._silent_until:
            return
        period = self.scan_period()
        newest = math.floor((now - self._mirror_t0) / period) - 1  # last completed scan
        if newest <= self._last_scan:
            return
        self._last_scan = newest
        completed = self._mirror_t0 + (newest + 1) * self.scan_period()
        self._enqueue_scan(newest, max(completed, now - 0.002) + self._slow / self.speedup)

    def _enqueue_scan(self, index: int, not_before: float, corruptible: bool = True) -> None:
        dev = self.device
        period = self.scan_period()
        acquired = self._mirror_t0 + index * period
        device_time = (acquired - self._mirror_t0) * self.speedup
        values = dev.values_from_ranges(self.ranges(index, device_time, dev.angles()))
        data = dev.scan_reply(values)
        kind = None
        if corruptible and self._corrupt_queue:
            kind = self._corrupt_queue.popleft()
        elif corruptible and self.fault_rate > 0 and self._rng.random() < self.fault_rate:
            kind = self.fault_kinds[int(self._rng.integers(len(self.fault_kinds)))]
        if kind is not None:
            data = corrupt(data, kind, self._rng)
            self.counters.scans_corrupted += 1
        seg = self._enqueue(data, not_before)
        self.counters.scans_sent += 1
        if self.record:
            self.sent.append(SentScan(index, values, dev.units, dev.mode.code, acquired,
                                      seg.start, dev.baud, kind.value if kind else None))

    def _write_due(self, now: float) -> None:
        while self._segments:
            seg = self._segments[0]
            due = min(len(seg.data), int((now - seg.start) / seg.byte_time) if now >= seg.start
                      else 0)
            if due > seg.written:
                self._write(seg.data[seg.written:due], seg.baud)
                seg.written = due
            if seg.written < len(seg.data):
                return
            self._segments.popleft()
            if seg.on_done is not None:
                seg.on_done()

    def _write(self, data: bytes, baud: int) -> None:
        host = self.host_baud()
        if host != baud:
            slower = host is not None and host < baud
            n = max(1, round(len(data) * host / baud)) if slower else len(data)
            data = self._rng.integers(0, 256, n, dtype=np.uint8).tobytes()
            self.counters.garbled_out += len(data)
        try:
            written = os.write(self._master, data)
        except OSError:  # buffer full (nobody reading) or the pty went away
            written = 0
        self.counters.bytes_written += written
        self.counters.bytes_dropped += len(data) - written
