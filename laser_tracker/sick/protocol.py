"""SICK LMS2xx serial telegrams: framing, checksum, host commands, device replies (no I/O).

A telegram is ``STX(0x02) | ADDR | LEN (u16 LE) | CMD | DATA... | [STATUS] | CRC (u16 LE)``.
``ADDR`` is 0x00 from the host, 0x80 from the device; ``LEN`` counts CMD through STATUS
(device replies end in a status byte, host telegrams have none). Before any reply the device
sends one unframed byte, ACK 0x06 or NAK 0x15. The facts and the test vectors come from SICK's
LMS2xx telegram listing as implemented by the open drivers (sicktoolbox, Player, RL, MRPT).

Everything here is pure: encoders return bytes, decoders take bytes and return frozen
dataclasses or raise a :class:`ProtocolError` subclass, and :class:`TelegramStreamParser`
turns a byte stream (with the times its chunks were read) into telegrams.
"""
from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from laser_tracker.errors import LaserTrackerError

STX = 0x02
ACK = 0x06
NAK = 0x15
DEVICE_ADDRESS = 0x00  # host -> device telegrams carry the device's address
REPLY_ADDRESS = 0x80  # device -> host: "address offset for answers"
MAX_LENGTH = 812  # largest LEN any LMS2xx telegram uses (sicktoolbox's cap)
FRAME_OVERHEAD = 6  # STX, ADDR, LEN (2), CRC (2)
BITS_PER_BYTE = 10  # 8N1: start + 8 data + stop
MIRROR_PERIOD = 1.0 / 75.0  # s, one mirror revolution
DEFAULT_PASSWORD = 'SICK_LMS'

# Request codes; the reply code is the request code + 0x80.
CMD_RESET = 0x10
CMD_OPERATING_MODE = 0x20
CMD_REQUEST_VALUES = 0x30
CMD_REQUEST_STATUS = 0x31
CMD_REQUEST_ERRORS = 0x32
CMD_REQUEST_TYPE = 0x3A
CMD_SET_VARIANT = 0x3B
CMD_REQUEST_CONFIG = 0x74
CMD_SET_CONFIG = 0x77

REPLY_POWER_ON = 0x90
REPLY_RESET = 0x91
REPLY_INCORRECT_COMMAND = 0x92
REPLY_MODE = 0xA0
REPLY_VALUES = 0xB0
REPLY_STATUS = 0xB1
REPLY_ERRORS = 0xB2
REPLY_TYPE = 0xBA
REPLY_VARIANT = 0xBB
REPLY_CONFIG = 0xF4
REPLY_SET_CONFIG = 0xF7

# Operating modes (data byte of 0x20).
MODE_INSTALLATION = 0x00
MODE_CONTINUOUS = 0x24  # continuous output of all values
MODE_ON_REQUEST = 0x25  # values on request only: stops streaming

BAUD_MODES = {38400: 0x40, 19200: 0x41, 9600: 0x42, 500000: 0x48}
BAUD_RATES = tuple(sorted(BAUD_MODES))  # (9600, 19200, 38400, 500000)
DEFAULT_BAUD = 9600  # the rate after power-on

SCAN_ANGLES = (100, 180)  # degrees
RESOLUTIONS_CDEG = (100, 50, 25)  # 1/100 degree
CONFIG_UNITS_BYTE = 6  # index of the units byte in the configuration block
CONFIG_MODE_BYTE = 5  # index of the measuring mode byte


# ------------------------------------------------------------------------------ errors


class ProtocolError(LaserTrackerError, ValueError):
    """Bytes that are not a valid LMS2xx telegram or reply; the message says why."""


class FramingError(ProtocolError):
    """Wrong STX, address, or a frame shorter/longer than its length field says."""


class LengthError(FramingError):
    """A length field outside the sizes an LMS2xx uses (below the minimum or past 812)."""


class ChecksumError(ProtocolError):
    """The CRC does not match the telegram's bytes."""


class DecodeError(ProtocolError):
    """A telegram with a valid frame whose payload does not fit its reply code."""


class UnexpectedReplyError(ProtocolError):
    """A reply code this module has no decoder for, or not the one a request expects."""

    def __init__(self, code: int, expected: int | None = None):
        self.code, self.expected = code, expected
        want = f', expected 0x{expected:02X}' if expected is not None else ''
        super().__init__(f'unexpected reply code 0x{code:02X}{want}')


# -------------------------------------------------------------------------------- CRC


def crc16(data: bytes) -> int:
    """The SICK CRC-16 (generator 0x8005, init 0, each step xors the byte pair (prev, byte)).

    Not a standard table CRC; see the fact sheet section 1.
    """
    crc = 0
    prev = 0
    for b in data:
        if crc & 0x8000:
            crc = ((crc & 0x7FFF) << 1) ^ 0x8005
        else:
            crc = (crc << 1) & 0xFFFF
        crc ^= b | (prev << 8)
        prev = b
    return crc


# --------------------------------------------------------------------------- framing


@dataclass(frozen=True)
class Telegram:
    """One frame: ``payload`` is CMD through the last data byte (and STATUS in replies)."""

    address: int
    payload: bytes

    @property
    def command(self) -> int:
        return self.payload[0]

    @property
    def is_reply(self) -> bool:
        return bool(self.address & REPLY_ADDRESS)

    @property
    def status(self) -> int:
        """The trailing status byte of a device reply."""
        if not self.is_reply:
            raise DecodeError('host telegrams have no status byte')
        return self.payload[-1]

    @property
    def data(self) -> bytes:
        """Bytes between the command and the status byte (or the end, for host telegrams)."""
        return self.payload[1:-1] if self.is_reply else self.payload[1:]

    def encode(self) -> bytes:
        return frame(self.payload, self.address)


def frame(payload: bytes, address: int = DEVICE_ADDRESS) -> bytes:
    """``payload`` (CMD..[STATUS]) wrapped in STX, address, length and CRC."""
    payload = bytes(payload)
    if not 1 <= len(payload) <= MAX_LENGTH:
        raise LengthError(f'payload of {len(payload)} bytes; must be 1..{MAX_LENGTH}')
    head = bytes((STX, address & 0xFF, len(payload) & 0xFF, len(payload) >> 8)) + payload
    crc = crc16(head)
    return head + bytes((crc & 0xFF, crc >> 8))


def decode_frame(raw: bytes, address: int | None = REPLY_ADDRESS) -> Telegram:
    """Strictly decode one complete frame; ``address=None`` accepts any address."""
    raw = bytes(raw)
    if len(raw) < FRAME_OVERHEAD + 1:
        raise FramingError(f'frame of {len(raw)} bytes is too short')
    if raw[0] != STX:
        raise FramingError(f'frame starts with 0x{raw[0]:02X}, not STX 0x02')
    if address is not None and raw[1] != address:
        raise FramingError(f'address 0x{raw[1]:02X}, expected 0x{address:02X}')
    length = raw[2] | (raw[3] << 8)
    if not 1 <= length <= MAX_LENGTH:
        raise LengthError(f'length field {length} outside 1..{MAX_LENGTH}')
    if len(raw) != length + FRAME_OVERHEAD:
        raise FramingError(f'length field says {length + FRAME_OVERHEAD} bytes, '
                           f'frame has {len(raw)}')
    got = raw[-2] | (raw[-1] << 8)
    want = crc16(raw[:-2])
    if got != want:
        raise ChecksumError(f'CRC 0x{got:04X}, computed 0x{want:04X}')
    return Telegram(raw[1], raw[4:-2])


def frame_time(n_bytes: int, baud: int) -> float:
    """Seconds ``n_bytes`` take on an 8N1 line at ``baud``."""
    return n_bytes * BITS_PER_BYTE / float(baud)


# -------------------------------------------------------------------------- encoders


def request_status() -> bytes:
    return frame(bytes((CMD_REQUEST_STATUS,)))


def request_errors() -> bytes:
    return frame(bytes((CMD_REQUEST_ERRORS,)))


def request_type() -> bytes:
    return frame(bytes((CMD_REQUEST_TYPE,)))


def request_config() -> bytes:
    return frame(bytes((CMD_REQUEST_CONFIG,)))


def request_scan() -> bytes:
    """Request one scan of all values (reply 0xB0)."""
    return frame(bytes((CMD_REQUEST_VALUES, 0x01)))


def reset() -> bytes:
    return frame(bytes((CMD_RESET,)))


def set_operating_mode(mode: int, extra: bytes = b'') -> bytes:
    if not 0 <= mode <= 0xFF:
        raise ValueError(f'operating mode must be a byte, got {mode!r}')
    return frame(bytes((CMD_OPERATING_MODE, mode)) + bytes(extra))


def installation_mode(password: str = DEFAULT_PASSWORD) -> bytes:
    """Enter installation mode (needed before 0x77); the password is 8 ASCII characters."""
    pw = password.encode('ascii')
    if len(pw) != 8:
        raise ValueError(f'the installation password has 8 characters, got {password!r}')
    return set_operating_mode(MODE_INSTALLATION, pw)


def start_continuous() -> bytes:
    return set_operating_mode(MODE_CONTINUOUS)


def stop_continuous() -> bytes:
    return set_operating_mode(MODE_ON_REQUEST)


def set_baud_rate(baud: int) -> bytes:
    """Switch the device's rate; it acknowledges at the old rate, then changes."""
    try:
        return set_operating_mode(BAUD_MODES[baud])
    except KeyError:
        raise ValueError(f'LMS2xx baud rates are {BAUD_RATES}, got {baud!r}') from None


def check_variant(angle_deg: int, resolution_cdeg: int) -> None:
    """Raise ValueError unless (angle, resolution) is a variant the LMS2xx offers."""
    if angle_deg not in SCAN_ANGLES:
        raise ValueError(f'scan angle must be one of {SCAN_ANGLES} degrees, got {angle_deg!r}')
    if resolution_cdeg not in RESOLUTIONS_CDEG:
        raise ValueError(f'resolution must be one of 1, 0.5, 0.25 degrees, '
                         f'got {resolution_cdeg / 100.0!r}')
    if angle_deg == 180 and resolution_cdeg == 25:
        raise ValueError('0.25 degree resolution needs the 100 degree scan angle')


def set_variant(angle_deg: int, resolution_cdeg: int) -> bytes:
    """Scan angle (100/180 degrees) and resolution (100/50/25 in 1/100 degree)."""
    check_variant(angle_deg, resolution_cdeg)
    return frame(bytes((CMD_SET_VARIANT,)) + angle_deg.to_bytes(2, 'little')
                 + resolution_cdeg.to_bytes(2, 'little'))


def set_config(block: bytes) -> bytes:
    """Write a configuration block (installation mode required); reply 0xF7."""
    return frame(bytes((CMD_SET_CONFIG,)) + bytes(block))


# ------------------------------------------------------------------ units and modes


class RangeUnit(enum.IntEnum):
    """Range units: the count word's bits 14-15 and configuration byte 6 use these codes."""

    CM = 0
    MM = 1
    DM = 2  # 10 cm (Player/RACK; UNCONFIRMED on real devices)

    @property
    def metres(self) -> float:
        return {RangeUnit.CM: 0.01, RangeUnit.MM: 0.001, RangeUnit.DM: 0.1}[self]

    @classmethod
    def parse(cls, name: str) -> RangeUnit:
        try:
            return {'cm': cls.CM, 'mm': cls.MM, 'dm': cls.DM}[name]
        except KeyError:
            raise ValueError(f'units must be mm or cm, got {name!r}') from None


@dataclass(frozen=True)
class MeasuringMode:
    """How a value word splits into range bits and flag bits (fact sheet section 2)."""

    code: int
    range_bits: int
    flags: tuple[tuple[str, int, int], ...] = ()  # (name, shift, width) of each flag field

    @property
    def range_mask(self) -> int:
        return (1 << self.range_bits) - 1

    @property
    def first_special(self) -> int:
        """Raw values at or above this are "no measurement" codes (0x..F7)."""
        return self.range_mask - 8

    @property
    def max_valid(self) -> int:
        return self.first_special - 1


MEASURING_MODES: dict[int, MeasuringMode] = {
    0x00: MeasuringMode(0x00, 13, (('field_a', 13, 1), ('field_b', 14, 1), ('field_c', 15, 1))),
    0x01: MeasuringMode(0x01, 13, (('reflector', 13, 3),)),
    0x02: MeasuringMode(0x02, 13, (('field_a', 13, 1), ('field_b', 14, 1), ('field_c', 15, 1))),
    0x03: MeasuringMode(0x03, 14, (('reflector', 14, 2),)),
    0x04: MeasuringMode(0x04, 14, (('field_a', 14, 1), ('field_b', 15, 1))),
    0x05: MeasuringMode(0x05, 15, (('reflector', 15, 1),)),
    0x06: MeasuringMode(0x06, 15, (('field_a', 15, 1),)),
    0x0F: MeasuringMode(0x0F, 16),
}
REFLECTIVITY_MODE = 0x3F  # values are reflectivities, not ranges


def measuring_mode(code: int) -> MeasuringMode:
    try:
        return MEASURING_MODES[code]
    except KeyError:
        what = 'reflectivity values, not ranges' if code == REFLECTIVITY_MODE else 'unknown'
        raise DecodeError(f'measuring mode 0x{code:02X}: {what}') from None


class NoMeasurement(enum.IntEnum):
    """The special values, as offsets below the mode's range mask (0x1FFF... in 13-bit modes)."""

    NOT_VALID = 0
    DAZZLING = 1
    OPERATION_OVERFLOW = 2
    SNR_TOO_SMALL = 4
    CHANNEL1_READ_ERROR = 5
    VALUE_ABOVE_MAXIMUM = 8


# ------------------------------------------------------------------------ status byte


class Severity(enum.IntEnum):
    OK = 0
    INFO = 1
    WARNING = 2
    ERROR = 3
    FATAL = 4


DEVICE_CLASSES = ('LMS-xx1..xx4', 'LMI', 'LMS-xx6', 'reserved')


@dataclass(frozen=True)
class StatusByte:
    """The trailing status byte of every reply (bits 0-2 severity, 3-4 class, 5-7 flags)."""

    raw: int

    @property
    def severity(self) -> int:
        """0 OK, 1 info, 2 warning, 3 error, 4 fatal (5-7 are undefined)."""
        return self.raw & 0x07

    @property
    def device_class(self) -> str:
        return DEVICE_CLASSES[(self.raw >> 3) & 0x03]

    @property
    def restart(self) -> bool:
        return bool(self.raw & 0x20)

    @property
    def implausible(self) -> bool:
        return bool(self.raw & 0x40)

    @property
    def pollution(self) -> bool:
        return bool(self.raw & 0x80)

    @property
    def is_error(self) -> bool:
        return self.severity >= Severity.ERROR

    def describe(self) -> str:
        names = {0: 'ok', 1: 'info', 2: 'warning', 3: 'error', 4: 'fatal'}
        parts = [names.get(self.severity, f'severity {self.severity}'), self.device_class]
        parts += [n for n, on in (('restart', self.restart), ('implausible values',
                  self.implausible), ('pollution', self.pollution)) if on]
        return f'0x{self.raw:02X} (' + ', '.join(parts) + ')'


# --------------------------------------------------------------------------- replies


@dataclass(frozen=True)
class ModeReply:
    """0xA0: result of an operating-mode change (0 OK, 1 wrong password, 2 LMS fault)."""

    result: int
    status: StatusByte

    @property
    def ok(self) -> bool:
        return self.result == 0

    def describe(self) -> str:
        return {0: 'ok', 1: 'wrong password', 2: 'LMS fault'}.get(self.result,
                                                                  f'result 0x{self.result:02X}')


@dataclass(frozen=True)
class MeasuredValues:
    """0xB0: raw value words and what the count word says about them."""

    values: np.ndarray  # uint16, as sent (range bits and flag bits)
    units: RangeUnit
    partial: bool  # bit 13: this telegram is one partial scan of an interlaced sweep
    partial_index: int  # bits 11-12: partial scan offset 0..3 = +0, 0.25, 0.5, 0.75 degrees
    status: StatusByte
    realtime_index: int | None = None  # present when availability bit 0x02 is set

    @property
    def count(self) -> int:
        return int(self.values.size)


@dataclass(frozen=True)
class DeviceStatusReport:
    """0xB1: the fields of the 152-byte status block the driver uses (offsets per RL/STB)."""

    software_version: str
    operating_mode: int
    device_error: int  # offset 9: non-zero means the device reports an error
    variant: int
    measuring_mode: int
    scan_angle: int  # degrees
    resolution_cdeg: int
    baud: int  # from the divisor word: 1e6 / (word + 1)
    permanent_baud: bool
    address: int
    units: int
    status: StatusByte


@dataclass(frozen=True)
class DeviceType:
    """0xBA: the type string, e.g. ``LMS200;30106``."""

    text: str
    status: StatusByte


@dataclass(frozen=True)
class VariantReply:
    """0xBB: variant accepted (else the previous variant is still active), and the echo."""

    accepted: bool
    angle_deg: int
    resolution_cdeg: int
    status: StatusByte


@dataclass(frozen=True)
class ConfigReply:
    """0xF4 (request) / 0xF7 (set): the configuration block; ``ok`` is None for 0xF4."""

    block: bytes
    ok: bool | None
    status: StatusByte

    @property
    def measuring_mode(self) -> int:
        return self.block[CONFIG_MODE_BYTE]

    @property
    def units(self) -> int:
        return self.block[CONFIG_UNITS_BYTE]


@dataclass(frozen=True)
class IncorrectCommand:
    """0x92: the device did not understand the command ("not acknowledge")."""

    status: StatusByte


@dataclass(frozen=True)
class OtherReply:
    """A known reply the driver does not interpret further (0x90 power-on, 0x91, 0xB2)."""

    code: int
    data: bytes
    status: StatusByte


Reply = (ModeReply | MeasuredValues | DeviceStatusReport | DeviceType | VariantReply
         | ConfigReply | IncorrectCommand | OtherReply)


def decode_handshake(byte: int) -> bool:
    """The byte before a reply: True for ACK, False for NAK; anything else is an error."""
    if byte == ACK:
        return True
    if byte == NAK:
        return False
    raise ProtocolError(f'expected ACK 0x06 or NAK 0x15, got 0x{byte:02X}')


def _need(telegram: Telegram, n_data: int, name: str, exact: bool = True) -> None:
    got = len(telegram.payload) - 2  # minus command and status
    if got < n_data or (exact and got != n_data):
        raise DecodeError(f'{name} reply 0x{telegram.command:02X} with {got} data bytes, '
                          f'expected {"" if exact else "at least "}{n_data}')


def decode_measured_values(telegram: Telegram) -> MeasuredValues:
    if telegram.command != REPLY_VALUES:
        raise UnexpectedReplyError(telegram.command, REPLY_VALUES)
    p = telegram.payload
    if len(p) < 4:
        raise DecodeError(f'measured-values reply of {len(p)} bytes has no count word')
    word = p[1] | (p[2] << 8)
    n = word & 0x3FF
    rest = len(p) - 3 - 2 * n  # status, and the real-time index when present
    if rest not in (1, 2):
        raise DecodeError(f'count word says {n} values, but the reply holds '
                          f'{(len(p) - 4) / 2:g} value words')
    units_code = (word >> 14) & 0x03
    if units_code == 3:
        raise DecodeError('count word has the reserved units code 11')
    values = np.frombuffer(p, dtype='<u2', count=n, offset=3).astype(np.uint16)
    return MeasuredValues(values=values, units=RangeUnit(units_code),
                          partial=bool(word & 0x2000), partial_index=(word >> 11) & 0x03,
                          status=StatusByte(p[-1]),
                          realtime_index=p[-2] if rest == 2 else None)


def encode_measured_values(values, units: RangeUnit, status: int = 0x10,
                           partial: bool = False, partial_index: int = 0,
                           realtime_index: int | None = None) -> bytes:
    """The 0xB0 reply payload (for the device simulator and tests)."""
    values = np.asarray(values, dtype='<u2')
    if values.size > 0x3FF:
        raise ValueError(f'{values.size} values do not fit the 10-bit count')
    word = values.size | (partial_index & 3) << 11 | (0x2000 if partial else 0) | int(units) << 14
    tail = bytes(() if realtime_index is None else (realtime_index,)) + bytes((status,))
    return bytes((REPLY_VALUES, word & 0xFF, word >> 8)) + values.tobytes() + tail


def _u16(p: bytes, i: int) -> int:
    return p[i] | (p[i + 1] << 8)


def decode_status(telegram: Telegram) -> DeviceStatusReport:
    _need(telegram, 152, 'status')
    p = telegram.payload
    word = _u16(p, 116)
    return DeviceStatusReport(
        software_version=p[1:8].decode('ascii', 'replace').strip('\x00 '),
        operating_mode=p[8], device_error=p[9], variant=p[18], measuring_mode=p[102],
        scan_angle=_u16(p, 107), resolution_cdeg=_u16(p, 109),
        baud=_nominal_baud(1e6 / ((word & 0xFF) + 1)), permanent_baud=bool(p[119]),
        address=p[120], units=p[122], status=StatusByte(p[-1]))


def _nominal_baud(rate: float) -> int:
    """The standard rate within 2 % of ``rate`` (38461.5 -> 38400), else ``rate`` rounded."""
    for baud in BAUD_RATES:
        if abs(rate - baud) <= 0.02 * baud:
            return baud
    return int(round(rate))


def baud_divisor(baud: int) -> int:
    """The status block's baud word (0x67 = 9600, 0x33 = 19200, 0x19 = 38400, 0x01 = 500k)."""
    return int(round(1e6 / baud)) - 1


def decode_reply(telegram: Telegram) -> Reply:
    """Decode any device reply by its code; unknown codes raise UnexpectedReplyError."""
    if not telegram.is_reply:
        raise FramingError(f'address 0x{telegram.address:02X} is not a device reply')
    code = telegram.command
    p = telegram.payload
    if len(p) < 2:
        raise DecodeError(f'reply 0x{code:02X} without a status byte')
    status = StatusByte(p[-1])
    if code == REPLY_MODE:
        _need(telegram, 1, 'mode change')
        return ModeReply(p[1], status)
    if code == REPLY_VALUES:
        return decode_measured_values(telegram)
    if code == REPLY_STATUS:
        return decode_status(telegram)
    if code == REPLY_TYPE:
        _need(telegram, 1, 'type', exact=False)
        return DeviceType(p[1:21].decode('ascii', 'replace').strip('\x00 '), status)
    if code == REPLY_VARIANT:
        _need(telegram, 5, 'variant')
        return VariantReply(p[1] == 0x01, _u16(p, 2), _u16(p, 4), status)
    if code == REPLY_CONFIG:
        _need(telegram, CONFIG_UNITS_BYTE + 1, 'configuration', exact=False)
        return ConfigReply(bytes(p[1:-1]), None, status)
    if code == REPLY_SET_CONFIG:
        _need(telegram, 1, 'set configuration', exact=False)
        return ConfigReply(bytes(p[2:-1]), p[1] == 0x01, status)
    if code == REPLY_INCORRECT_COMMAND:
        if len(p) not in (2, 3):  # RL sends LEN 2, old Player expects LEN 3
            raise DecodeError(f'0x92 reply with LEN {len(p)}, expected 2 or 3')
        return IncorrectCommand(status)
    if code in (REPLY_POWER_ON, REPLY_RESET, REPLY_ERRORS):
        return OtherReply(code, bytes(p[1:-1]), status)
    raise UnexpectedReplyError(code)


# ------------------------------------------------------------------- value conversion


def split_values(values: np.ndarray,
                 mode: MeasuringMode) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Value words -> (raw distances, {flag name: flag values}) for a measuring mode."""
    values = np.asarray(values, dtype=np.uint16).astype(np.int64)
    flags = {name: (values >> shift) & ((1 << width) - 1) for name, shift, width in mode.flags}
    return values & mode.range_mask, flags


def no_measurement_codes(distances: np.ndarray, mode: MeasuringMode) -> np.ndarray:
    """Per value: -1 for a measured range, else the :class:`NoMeasurement` offset (0..8)."""
    distances = np.asarray(distances, dtype=np.int64)
    return np.where(distances >= mode.first_special, mode.range_mask - distances, -1)


def range_limits(mode: MeasuringMode, units: RangeUnit) -> tuple[float, float]:
    """(largest valid range, first invalid range) in metres, e.g. (8.182, 8.183) in mm."""
    return mode.max_valid * units.metres, mode.first_special * units.metres


def ranges_in_metres(values: np.ndarray, mode: MeasuringMode, units: RangeUnit,
                     too_far: float = math.inf, invalid: float = 0.0) -> np.ndarray:
    """Value words -> metres (float64).

    ``too_far`` replaces "value above maximum" (nothing within range: REP 117's +inf) and
    ``invalid`` every other no-measurement code (dazzling, overflow, weak signal, read error,
    not valid), by default 0.0, a value below any ``range_min``: "no reading, no free space".
    """
    distances, _ = split_values(values, mode)
    codes = no_measurement_codes(distances, mode)
    out = distances.astype(np.float64) * units.metres
    out[codes >= 0] = invalid
    out[codes == NoMeasurement.VALUE_ABOVE_MAXIMUM] = too_far
    return out


def metres_to_values(ranges: np.ndarray, mode: MeasuringMode, units: RangeUnit) -> np.ndarray:
    """Metres -> raw distance words (simulator side): beyond range or inf -> 'above maximum',
    NaN -> 'not valid'. Flag bits are zero."""
    ranges = np.asarray(ranges, dtype=np.float64)
    with np.errstate(invalid='ignore'):
        scaled = np.round(ranges / units.metres)
        out = np.full(ranges.shape, mode.first_special, dtype=np.int64)
        ok = np.isfinite(scaled) & (scaled >= 0) & (scaled <= mode.max_valid)
    out[ok] = scaled[ok].astype(np.int64)
    out[np.isnan(ranges)] = mode.range_mask - NoMeasurement.NOT_VALID
    return out.astype(np.uint16)


# ---------------------------------------------------------------------- scan geometry


@dataclass(frozen=True)
class ScanGeometry:
    """Where the beams of a 0xB0 telegram point, and how long the sweep took.

    Angles follow REP 103 in the laser frame: 0 straight ahead, counter-clockwise positive.
    The device scans counter-clockwise from the right, so a 180 degree scan spans -90..+90
    degrees and a 100 degree scan -50..+50 degrees.
    """

    scan_angle: int  # degrees
    resolution: float  # degrees between consecutive values
    angle_min: float  # rad
    angle_increment: float  # rad
    revolutions: int  # mirror turns that contributed (interlaced scans take 2 or 4)
    count: int

    @property
    def scan_time(self) -> float:
        """Seconds from the first beam's revolution start to the last revolution's end."""
        return self.revolutions * MIRROR_PERIOD

    @property
    def time_increment(self) -> float:
        """Mean time between consecutive beams: the sweep from first to last beam spread
        evenly (exact for 1 degree scans, a linear approximation for interlaced ones)."""
        sweep = (self.revolutions - 1) * MIRROR_PERIOD + self.scan_angle / 360.0 * MIRROR_PERIOD
        return sweep / max(self.count - 1, 1)


FULL_SCAN_COUNTS = {181: (180, 1.0), 361: (180, 0.5), 101: (100, 1.0), 201: (100, 0.5),
                    401: (100, 0.25)}


def scan_geometry(values: MeasuredValues) -> ScanGeometry:
    """Geometry from the value count (it names the variant unambiguously).

    A partial-scan telegram (bit 13) holds one mirror turn at 1 degree, shifted by the partial
    index times 0.25 degrees; it is described as delivered, not merged.
    """
    n = values.count
    if n not in FULL_SCAN_COUNTS:
        raise DecodeError(f'{n} values is no LMS2xx variant (181/361 at 180 degrees, '
                          f'101/201/401 at 100 degrees); subrange modes are not supported')
    angle, resolution = FULL_SCAN_COUNTS[n]
    offset = 0.0
    revolutions = int(round(1.0 / resolution))
    if values.partial:
        if resolution != 1.0:
            raise DecodeError(f'partial scan with {n} values; partial scans hold 1 degree steps')
        offset = 0.25 * values.partial_index
        revolutions = 1
    return ScanGeometry(scan_angle=angle, resolution=resolution,
                        angle_min=math.radians(-angle / 2.0 + offset),
                        angle_increment=math.radians(resolution), revolutions=revolutions,
                        count=n)


def value_count(scan_angle: int, resolution_cdeg: int) -> int:
    return int(scan_angle * 100 // resolution_cdeg) + 1


# ----------------------------------------------------------------------- stream parser


@dataclass(frozen=True)
class Handshake:
    """An unframed ACK/NAK byte seen between telegrams; ``time`` estimates its arrival."""

    ack: bool
    time: float | None


@dataclass(frozen=True)
class ReceivedTelegram:
    """A telegram with a good CRC; ``first_byte_time`` estimates when its STX arrived."""

    telegram: Telegram
    first_byte_time: float | None
    size: int


@dataclass(frozen=True)
class RejectedFrame:
    """A candidate frame that failed (``reason`` is 'length' or 'crc')."""

    reason: str


@dataclass
class ParserCounters:
    bytes_received: int = 0
    bytes_discarded: int = 0  # not part of any good telegram and not an ACK/NAK
    telegrams: int = 0
    crc_errors: int = 0
    length_errors: int = 0
    acks: int = 0
    naks: int = 0


ParsedItem = Handshake | ReceivedTelegram | RejectedFrame


@dataclass
class _Chunk:
    start: int  # absolute stream index of the chunk's first byte
    end: int
    time: float


class TelegramStreamParser:
    """Finds telegrams in a byte stream: resynchronise on ``STX ADDR``, bound LEN, check CRC.

    On a bad length or CRC only the STX is discarded and the search resumes one byte later,
    so a good telegram hidden behind a false start (data may contain ``02 80``) is found.
    ACK/NAK bytes met while searching are reported as :class:`Handshake` items.

    Arrival times: :meth:`feed` takes the time a chunk was read. Every byte of a chunk had
    arrived by then, and the bytes of one telegram follow each other at the line rate
    (``byte_time`` seconds apart), so each chunk bounds the first byte's arrival from above
    by ``read time - (bytes after the first, up to the chunk's last) * byte_time``; the
    smallest bound over the chunks the telegram spans is the estimate.
    """

    def __init__(self, address: int = REPLY_ADDRESS, max_length: int = MAX_LENGTH,
                 min_length: int = 2, byte_time: float = 0.0):
        self.address, self.max_length, self.min_length = address, max_length, min_length
        self.byte_time = byte_time
        self.counters = ParserCounters()
        self._buf = bytearray()
        self._base = 0  # absolute stream index of _buf[0]
        self._chunks: deque[_Chunk] = deque()
        self._sync = bytes((STX, address))

    def reset(self) -> None:
        """Forget buffered bytes (after a port flush or a rate change); counters stay."""
        self.counters.bytes_discarded += len(self._buf)
        self._base += len(self._buf)
        self._buf.clear()
        self._chunks.clear()

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def _time_of(self, start: int, end: int) -> float | None:
        """Upper-bound estimate of the arrival of absolute byte ``start`` of span [start, end)."""
        best = None
        for c in self._chunks:
            if c.end <= start or c.start >= end or math.isnan(c.time):
                continue
            bound = c.time - (min(c.end, end) - 1 - start) * self.byte_time
            best = bound if best is None else min(best, bound)
        return best

    def _drop(self, n: int, discarded: bool = True) -> None:
        if discarded:
            self.counters.bytes_discarded += n
        del self._buf[:n]
        self._base += n
        while self._chunks and self._chunks[0].end <= self._base:
            self._chunks.popleft()

    def feed(self, data: bytes, read_time: float | None = None) -> list[ParsedItem]:
        if data:
            start = self._base + len(self._buf)
            self._buf += data
            self.counters.bytes_received += len(data)
            self._chunks.append(_Chunk(start, start + len(data),
                                       math.nan if read_time is None else read_time))
        out: list[ParsedItem] = []
        buf = self._buf
        while buf:
            i = buf.find(self._sync)
            if i < 0:
                # keep a trailing STX: it may begin a telegram whose address is still to come
                n = len(buf) - (1 if buf[-1] == STX else 0)
                if n:
                    self._scan_handshakes(n, out)
                break
            if i > 0:
                self._scan_handshakes(i, out)
                continue
            if len(buf) < 4:
                break
            length = buf[2] | (buf[3] << 8)
            if not self.min_length <= length <= self.max_length:
                self.counters.length_errors += 1
                out.append(RejectedFrame('length'))
                self._drop(1)
                continue
            size = length + FRAME_OVERHEAD
            if len(buf) < size:
                break
            got = buf[size - 2] | (buf[size - 1] << 8)
            if got != crc16(bytes(buf[:size - 2])):
                self.counters.crc_errors += 1
                out.append(RejectedFrame('crc'))
                self._drop(1)
                continue
            telegram = Telegram(buf[1], bytes(buf[4:size - 2]))
            when = self._time_of(self._base, self._base + size)
            self.counters.telegrams += 1
            out.append(ReceivedTelegram(telegram, when, size))
            self._drop(size, discarded=False)
        return out

    def _scan_handshakes(self, n: int, out: list[ParsedItem]) -> None:
        """Drop ``n`` leading bytes that are not a telegram, reporting ACK/NAK among them."""
        for k in range(n):
            b = self._buf[k]
            if b in (ACK, NAK):
                ack = b == ACK
                if ack:
                    self.counters.acks += 1
                else:
                    self.counters.naks += 1
                out.append(Handshake(ack, self._time_of(self._base + k, self._base + k + 1)))
            else:
                self.counters.bytes_discarded += 1
        self._drop(n, discarded=False)


def max_frame_bytes() -> int:
    return MAX_LENGTH + FRAME_OVERHEAD


@dataclass(frozen=True)
class VariantSpec:
    """A requested variant: scan angle in degrees and resolution in 1/100 degree."""

    scan_angle: int = 180
    resolution_cdeg: int = 50

    def __post_init__(self):
        check_variant(self.scan_angle, self.resolution_cdeg)

    @property
    def count(self) -> int:
        return value_count(self.scan_angle, self.resolution_cdeg)

    @property
    def frame_bytes(self) -> int:
        """Bytes of one 0xB0 telegram of this variant (without the real-time index)."""
        return 2 * self.count + 4 + FRAME_OVERHEAD

