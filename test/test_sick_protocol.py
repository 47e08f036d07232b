"""SICK LMS2xx telegrams: every worked telegram of the fact sheet, decoders, stream parser."""
import math

import numpy as np
import pytest

from laser_tracker.sick import protocol as P
from laser_tracker.tools.sick_device import Lms2xxDevice, corrupt, Corruption


def h(text: str) -> bytes:
    return bytes.fromhex(text)


def reply(payload_hex: str) -> bytes:
    return P.frame(h(payload_hex), P.REPLY_ADDRESS)


# ------------------------------------------------------ fact sheet section 1 vectors

HOST_VECTORS = [
    ('status request', P.request_status(), '02 00 01 00 31 15 12'),
    ('installation mode SICK_LMS', P.installation_mode('SICK_LMS'),
     '02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 BE C5'),
    ('start continuous', P.start_continuous(), '02 00 02 00 20 24 34 08'),
    ('stop continuous', P.stop_continuous(), '02 00 02 00 20 25 35 08'),
    ('baud 38400', P.set_baud_rate(38400), '02 00 02 00 20 40 50 08'),
    ('baud 9600', P.set_baud_rate(9600), '02 00 02 00 20 42 52 08'),
    ('baud 500000', P.set_baud_rate(500000), '02 00 02 00 20 48 58 08'),
    ('baud 19200', P.set_baud_rate(19200), '02 00 02 00 20 41 51 08'),
    ('request one scan', P.request_scan(), '02 00 02 00 30 01 31 18'),
    ('request config', P.request_config(), '02 00 01 00 74 50 12'),
    ('variant 180/0.5', P.set_variant(180, 50), '02 00 05 00 3B B4 00 32 00 3B 1F'),
    ('variant 100/1', P.set_variant(100, 100), '02 00 05 00 3B 64 00 64 00 1D 0F'),
]


@pytest.mark.parametrize('name,encoded,expected', HOST_VECTORS, ids=[v[0] for v in HOST_VECTORS])
def test_host_telegrams_match_the_fact_sheet(name, encoded, expected):
    assert encoded == h(expected)
    telegram = P.decode_frame(encoded, P.DEVICE_ADDRESS)  # and they decode back
    assert telegram.payload == h(expected)[4:-2]


def test_crc_of_the_worked_examples():
    for _, _, expected in HOST_VECTORS:
        raw = h(expected)
        assert P.crc16(raw[:-2]) == raw[-2] | raw[-1] << 8


def test_the_wrong_published_installation_crc_is_rejected():
    """One project hard-codes ...5F B2; the algorithm says BE C5."""
    bad = h('02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 5F B2')
    with pytest.raises(P.ChecksumError):
        P.decode_frame(bad, P.DEVICE_ADDRESS)


def test_mode_change_ok_reply_vector():
    raw = h('02 80 03 00 A0 00 10 16 0A')
    assert reply('A0 00 10') == raw
    decoded = P.decode_reply(P.decode_frame(raw))
    assert isinstance(decoded, P.ModeReply) and decoded.ok
    assert decoded.status.raw == 0x10 and decoded.status.severity == P.Severity.OK


def test_variant_reply_vector():
    raw = h('02 80 07 00 BB 01 B4 00 32 00 10 03 9D')
    assert reply('BB 01 B4 00 32 00 10') == raw
    decoded = P.decode_reply(P.decode_frame(raw))
    assert decoded == P.VariantReply(True, 180, 50, P.StatusByte(0x10))


def test_ack_then_reply_as_the_qt_driver_expects_it():
    parser = P.TelegramStreamParser()
    items = parser.feed(b'\x06' + h('02 80 03 00 A0 00 10 16 0A'), 1.0)
    assert isinstance(items[0], P.Handshake) and items[0].ack
    assert isinstance(items[1], P.ReceivedTelegram) and items[1].telegram.command == 0xA0


def test_handshake_byte():
    assert P.decode_handshake(0x06) is True
    assert P.decode_handshake(0x15) is False
    with pytest.raises(P.ProtocolError):
        P.decode_handshake(0x02)


# ------------------------------------------------------------------- encoders, limits


def test_encoders_refuse_what_the_device_cannot_do():
    with pytest.raises(ValueError):
        P.set_baud_rate(115200)
    with pytest.raises(ValueError, match='100 degree'):
        P.set_variant(180, 25)
    with pytest.raises(ValueError):
        P.set_variant(90, 100)
    with pytest.raises(ValueError):
        P.installation_mode('short')
    with pytest.raises(P.LengthError):
        P.frame(bytes(813))


def test_set_config_wraps_the_block():
    block = bytes(range(34))
    raw = P.set_config(block)
    assert raw[:5] == h('02 00 23 00 77') and P.decode_frame(raw, None).data == block


# ---------------------------------------------------------------------- 0xB0 values


def test_measured_values_header_for_361_values_mm_and_cm():
    values = np.arange(361, dtype=np.uint16)
    mm = reply(P.encode_measured_values(values, P.RangeUnit.MM, 0x10).hex())
    cm = reply(P.encode_measured_values(values, P.RangeUnit.CM, 0x10).hex())
    assert mm[:7] == h('02 80 D6 02 B0 69 41')  # LEN 726, count 361, mm
    assert cm[:7] == h('02 80 D6 02 B0 69 01')
    decoded = P.decode_reply(P.decode_frame(mm))
    assert decoded.count == 361 and decoded.units == P.RangeUnit.MM
    assert not decoded.partial and decoded.realtime_index is None
    np.testing.assert_array_equal(decoded.values, values)


def test_181_values_give_len_366():
    raw = reply(P.encode_measured_values(np.zeros(181), P.RangeUnit.CM).hex())
    assert raw[2] | raw[3] << 8 == 366


def test_count_word_partial_scan_bits_and_realtime_index():
    payload = P.encode_measured_values(np.ones(181), P.RangeUnit.MM, 0x10, partial=True,
                                       partial_index=2, realtime_index=7)
    word = payload[1] | payload[2] << 8
    assert word == 181 | 2 << 11 | 0x2000 | 0x4000
    decoded = P.decode_measured_values(P.decode_frame(reply(payload.hex())))
    assert decoded.partial and decoded.partial_index == 2 and decoded.realtime_index == 7
    geometry = P.scan_geometry(decoded)  # one turn at 1 degree, shifted by 0.5 degree
    assert geometry.angle_min == pytest.approx(math.radians(-90 + 0.5))
    assert geometry.angle_increment == pytest.approx(math.radians(1.0))


def test_count_word_reads_ten_bits_not_nine():
    """MRPT's 0x1FF mask misreads counts above 511; PL's 0x3FFF mixes in the flag bits."""
    payload = P.encode_measured_values(np.zeros(401), P.RangeUnit.MM, partial_index=3)
    assert P.decode_measured_values(P.decode_frame(reply(payload.hex()))).count == 401


def test_ten_centimetre_units_code():
    payload = bytearray(P.encode_measured_values([100], P.RangeUnit.CM))
    payload[2] |= 0x80  # units bits 10
    assert P.decode_measured_values(P.Telegram(0x80, bytes(payload))).units == P.RangeUnit.DM


def test_value_count_mismatch_is_a_decode_error():
    payload = P.encode_measured_values(np.zeros(181), P.RangeUnit.CM)
    short = P.Telegram(0x80, payload[:-3] + payload[-1:])
    with pytest.raises(P.DecodeError, match='181 values'):
        P.decode_measured_values(short)


def test_geometry_for_every_variant():
    for n, (angle, res, revs) in {181: (180, 1.0, 1), 361: (180, 0.5, 2), 101: (100, 1.0, 1),
                                  201: (100, 0.5, 2), 401: (100, 0.25, 4)}.items():
        values = P.MeasuredValues(np.zeros(n, np.uint16), P.RangeUnit.MM, False, 0,
                                  P.StatusByte(0x10))
        g = P.scan_geometry(values)
        assert (g.scan_angle, g.resolution, g.revolutions) == (angle, res, revs)
        assert g.angle_min == pytest.approx(-math.radians(angle / 2))
        assert g.angle_min + (n - 1) * g.angle_increment == pytest.approx(math.radians(angle / 2))
        assert g.scan_time == pytest.approx(revs / 75.0)
    with pytest.raises(P.DecodeError, match='subrange'):
        P.scan_geometry(P.MeasuredValues(np.zeros(50, np.uint16), P.RangeUnit.MM, False, 0,
                                         P.StatusByte(0)))


def test_one_degree_time_increment_is_the_mirror_rate():
    values = P.MeasuredValues(np.zeros(181, np.uint16), P.RangeUnit.MM, False, 0,
                              P.StatusByte(0))
    assert P.scan_geometry(values).time_increment == pytest.approx(1 / 75 / 360)


# ---------------------------------------------------------- value flags, special codes


def test_value_flag_bits_per_measuring_mode():
    word = np.array([0xE000 | 1234], dtype=np.uint16)
    distances, flags = P.split_values(word, P.measuring_mode(0x00))
    assert distances[0] == 1234 and flags == {'field_a': [1], 'field_b': [1], 'field_c': [1]}
    distances, flags = P.split_values(np.array([0xA000 | 99]), P.measuring_mode(0x01))
    assert distances[0] == 99 and flags['reflector'][0] == 0b101
    distances, flags = P.split_values(np.array([0x8000 | 0x3000]), P.measuring_mode(0x03))
    assert distances[0] == 0x3000 and flags['reflector'][0] == 0b10
    distances, flags = P.split_values(np.array([0x4000 | 5]), P.measuring_mode(0x04))
    assert distances[0] == 5 and flags['field_a'][0] == 1 and flags['field_b'][0] == 0
    distances, flags = P.split_values(np.array([0x8000 | 0x7000]), P.measuring_mode(0x05))
    assert distances[0] == 0x7000 and flags['reflector'][0] == 1
    distances, flags = P.split_values(np.array([0x8000 | 7]), P.measuring_mode(0x06))
    assert distances[0] == 7 and flags['field_a'][0] == 1
    distances, flags = P.split_values(np.array([0xFF00]), P.measuring_mode(0x0F))
    assert distances[0] == 0xFF00 and flags == {}
    with pytest.raises(P.DecodeError, match='reflectivity'):
        P.measuring_mode(0x3F)


def test_special_codes_in_13_bit_mode():
    mode = P.measuring_mode(0x00)
    raw = np.array([0x1FFF, 0x1FFE, 0x1FFD, 0x1FFB, 0x1FFA, 0x1FF7, 0x1FF6, 8182 | 0x2000])
    distances, _ = P.split_values(raw, mode)
    codes = P.no_measurement_codes(distances, mode)
    assert list(codes) == [P.NoMeasurement.NOT_VALID, P.NoMeasurement.DAZZLING,
                           P.NoMeasurement.OPERATION_OVERFLOW, P.NoMeasurement.SNR_TOO_SMALL,
                           P.NoMeasurement.CHANNEL1_READ_ERROR,
                           P.NoMeasurement.VALUE_ABOVE_MAXIMUM, -1, -1]
    metres = P.ranges_in_metres(raw, mode, P.RangeUnit.MM)
    assert list(metres[:5]) == [0.0] * 5  # no reading: below range_min, never NaN
    assert metres[5] == math.inf  # nothing within range: REP 117 +inf
    assert metres[6] == pytest.approx(8.182) and metres[7] == pytest.approx(8.182)
    assert not np.isnan(metres).any()


def test_special_codes_in_16_and_32_metre_modes_and_limits():
    m16, m32 = P.measuring_mode(0x03), P.measuring_mode(0x05)
    assert P.ranges_in_metres(np.array([0x3FF7]), m16, P.RangeUnit.MM)[0] == math.inf
    assert P.ranges_in_metres(np.array([0x7FFE]), m32, P.RangeUnit.MM)[0] == 0.0
    assert P.range_limits(P.measuring_mode(0), P.RangeUnit.MM)[0] == pytest.approx(8.182)
    assert P.range_limits(m16, P.RangeUnit.MM)[0] == pytest.approx(16.374)
    assert P.range_limits(m32, P.RangeUnit.MM)[0] == pytest.approx(32.758)
    assert P.range_limits(P.measuring_mode(0), P.RangeUnit.CM)[0] == pytest.approx(81.82)
    assert P.range_limits(m16, P.RangeUnit.CM)[0] == pytest.approx(163.74)
    assert P.range_limits(m32, P.RangeUnit.CM)[0] == pytest.approx(327.58)


def test_metres_to_values_round_trip():
    mode = P.measuring_mode(0)
    ranges = np.array([0.5, 8.182, 8.2, np.inf, np.nan])
    raw = P.metres_to_values(ranges, mode, P.RangeUnit.MM)
    assert list(raw) == [500, 8182, 0x1FF7, 0x1FF7, 0x1FFF]
    back = P.ranges_in_metres(raw, mode, P.RangeUnit.MM)
    assert list(back) == [0.5, 8.182, math.inf, math.inf, 0.0]


# ------------------------------------------------------------------------ status byte


def test_status_byte_fields():
    usual = P.StatusByte(0x10)
    assert usual.severity == 0 and usual.device_class == 'LMS-xx6' and not usual.is_error
    s14 = P.StatusByte(0x18)
    assert s14.device_class == 'reserved'
    bad = P.StatusByte(0x80 | 0x40 | 0x20 | 0x03)
    assert bad.is_error and bad.pollution and bad.implausible and bad.restart
    assert 'pollution' in bad.describe()


# -------------------------------------------------------------------- other replies


def test_status_reply_0xb1():
    device = Lms2xxDevice(scan_angle=100, resolution_cdeg=25, units=P.RangeUnit.MM)
    device.baud = 38400
    raw = device.reply(bytes((P.REPLY_STATUS,)) + device.status_block())
    assert raw[2] | raw[3] << 8 == 154
    status = P.decode_reply(P.decode_frame(raw))
    assert isinstance(status, P.DeviceStatusReport)
    assert (status.scan_angle, status.resolution_cdeg, status.units) == (100, 25, 1)
    assert status.baud == 38400
    assert status.device_error == 0 and status.status.raw == 0x10


def test_baud_divisor_word():
    assert [P.baud_divisor(b) for b in (9600, 19200, 38400, 500000)] == [0x67, 0x33, 0x19, 0x01]


def test_type_reply_0xba():
    text = b'LMS291;S05'.ljust(20, b' ') + b'\x00'
    decoded = P.decode_reply(P.decode_frame(reply((b'\xBA' + text + b'\x10').hex())))
    assert decoded == P.DeviceType('LMS291;S05', P.StatusByte(0x10))


def test_refused_variant_reply():
    decoded = P.decode_reply(P.decode_frame(reply('BB 00 64 00 64 00 10')))
    assert not decoded.accepted and decoded.angle_deg == 100


def test_incorrect_command_reply_0x92_with_len_2_and_3():
    assert isinstance(P.decode_reply(P.decode_frame(reply('92 10'))), P.IncorrectCommand)
    assert isinstance(P.decode_reply(P.decode_frame(reply('92 00 10'))), P.IncorrectCommand)
    with pytest.raises(P.DecodeError):
        P.decode_reply(P.decode_frame(reply('92 00 00 10')))


def test_config_replies():
    block = bytes(5) + b'\x00\x01' + bytes(27)
    got = P.decode_reply(P.decode_frame(reply((b'\xF4' + block + b'\x10').hex())))
    assert got.block == block and got.units == 1 and got.measuring_mode == 0 and got.ok is None
    done = P.decode_reply(P.decode_frame(reply((b'\xF7\x01' + block + b'\x10').hex())))
    assert done.ok and done.block == block


def test_unexpected_reply_code():
    with pytest.raises(P.UnexpectedReplyError, match='0xB5'):
        P.decode_reply(P.decode_frame(reply('B5 00 10')))
    with pytest.raises(P.UnexpectedReplyError, match='expected 0xB0'):
        P.decode_measured_values(P.decode_frame(reply('A0 00 10')))


def test_decode_frame_errors():
    good = h('02 80 03 00 A0 00 10 16 0A')
    with pytest.raises(P.FramingError):
        P.decode_frame(b'\x03' + good[1:])
    with pytest.raises(P.FramingError, match='address'):
        P.decode_frame(good, P.DEVICE_ADDRESS)
    with pytest.raises(P.FramingError):
        P.decode_frame(good[:-1])  # truncated
    with pytest.raises(P.ChecksumError):
        P.decode_frame(good[:-1] + b'\x0B')
    with pytest.raises(P.LengthError, match='812'):
        P.decode_frame(h('02 80 2D 03') + bytes(819))  # LEN 813


# ---------------------------------------------------------------------- stream parser


def scan_telegram(seed: int, n: int = 181) -> bytes:
    values = np.random.default_rng(seed).integers(0, 8000, n).astype(np.uint16)
    return reply(P.encode_measured_values(values, P.RangeUnit.MM, 0x10).hex())


def telegrams(items):
    return [i.telegram for i in items if isinstance(i, P.ReceivedTelegram)]


def test_parser_resynchronises_after_garbage_and_bad_frames():
    a, b, c = scan_telegram(1), scan_telegram(2), scan_telegram(3)
    broken = bytearray(b)
    broken[100] ^= 0x10  # wrong CRC
    stream = (b'\x55\xAA\x02\x02\x80' + a + bytes(broken) + b'\x02\x80\xFF\x7F' + b'\x00' * 5
              + c[:50])
    parser = P.TelegramStreamParser()
    got = telegrams(parser.feed(stream, 1.0))
    got += telegrams(parser.feed(c[50:], 2.0))  # the truncated telegram completes later
    assert [g.encode() for g in got] == [a, c]
    assert parser.counters.crc_errors >= 1 and parser.counters.length_errors >= 1
    assert parser.buffered == 0


def test_parser_finds_a_telegram_hidden_behind_a_false_header():
    """A fake ``02 80`` with a plausible length swallows the real telegram's start: only
    the STX is discarded on the CRC failure, so the real telegram is found afterwards."""
    real = scan_telegram(4)
    fake = h('02 80 64 00')  # LEN 100: the parser waits for 106 bytes, CRC fails
    parser = P.TelegramStreamParser()
    got = telegrams(parser.feed(fake + real, 0.0))
    assert [g.encode() for g in got] == [real]
    assert parser.counters.crc_errors == 1


def test_parser_rejects_lengths_past_812_and_below_2():
    real = scan_telegram(5)
    parser = P.TelegramStreamParser()
    items = parser.feed(h('02 80 2D 03') + h('02 80 01 00') + real)  # LEN 813, LEN 1
    assert [i.reason for i in items if isinstance(i, P.RejectedFrame)] == ['length', 'length']
    assert [t.encode() for t in telegrams(items)] == [real]


def test_parser_data_containing_02_80_and_byte_by_byte_feeding():
    values = np.full(181, 0x8002, dtype=np.uint16)  # every value word is 02 80 on the wire
    raw = reply(P.encode_measured_values(values, P.RangeUnit.MM).hex())
    parser = P.TelegramStreamParser()
    got = []
    for k, byte in enumerate(raw + raw):
        got += telegrams(parser.feed(bytes((byte,)), float(k)))
    assert [g.encode() for g in got] == [raw, raw]
    assert parser.counters.crc_errors == 0


@pytest.mark.parametrize('kind', list(Corruption))
def test_corrupted_telegrams_never_pass(kind):
    rng = np.random.default_rng(7)
    parser = P.TelegramStreamParser()
    good = 0
    for i in range(200):
        raw = scan_telegram(i)
        bad = corrupt(raw, kind, rng)
        assert bad != raw
        good += len(telegrams(parser.feed(bad + raw)))
    assert good == 200  # every intact telegram after a damaged one is still found
    assert parser.counters.telegrams == 200


def test_nak_byte_is_reported():
    parser = P.TelegramStreamParser()
    items = parser.feed(b'\x15')
    assert items == [P.Handshake(False, None)] and parser.counters.naks == 1


def test_first_byte_arrival_estimate():
    """Each read bounds the STX's arrival: read time minus the bytes after it at line rate."""
    raw = scan_telegram(6)  # 368 bytes
    byte_time = 1e-3
    parser = P.TelegramStreamParser(byte_time=byte_time)
    # the first 100 bytes were read late (at 10.0) but the rest promptly (last byte at 10.5)
    assert parser.feed(raw[:100], 10.0) == []
    item, = parser.feed(raw[100:], 10.5)
    expected = min(10.0 - 99 * byte_time, 10.5 - (len(raw) - 1) * byte_time)
    assert item.first_byte_time == pytest.approx(expected)
    assert item.size == len(raw)


def test_reset_discards_buffer_but_keeps_counters():
    parser = P.TelegramStreamParser()
    parser.feed(scan_telegram(8)[:30])
    parser.reset()
    assert parser.buffered == 0 and parser.counters.bytes_discarded == 30


# ----------------------------------------------------------- the simulated device model


def answer(device, raw):
    return device.handle(P.decode_frame(raw, P.DEVICE_ADDRESS))


def test_device_model_session():
    device = Lms2xxDevice()
    a = answer(device, P.set_baud_rate(500000))
    assert a.handshake == P.ACK and a.new_baud == 500000
    assert a.reply == h('02 80 03 00 A0 00 10 16 0A')  # the "mode change OK" vector
    a = answer(device, P.set_variant(180, 50))
    assert a.reply == h('02 80 07 00 BB 01 B4 00 32 00 10 03 9D')
    refused = answer(device, P.frame(h('3B B4 00 19 00')))  # 180 / 0.25: refused
    assert P.decode_reply(P.decode_frame(refused.reply)).accepted is False
    wrong_pw = answer(device, P.installation_mode('SICK_XXX'))
    assert P.decode_reply(P.decode_frame(wrong_pw.reply)).result == 1
    config = P.decode_reply(P.decode_frame(answer(device, P.request_config()).reply))
    block = bytearray(config.block)
    block[P.CONFIG_UNITS_BYTE] = 1
    refused = P.decode_reply(P.decode_frame(answer(device, P.set_config(block)).reply))
    assert refused.ok is False  # installation mode required
    answer(device, P.installation_mode())
    done = P.decode_reply(P.decode_frame(answer(device, P.set_config(block)).reply))
    assert done.ok and device.units == P.RangeUnit.MM
    assert answer(device, P.start_continuous()).stream is True and device.streaming
    assert answer(device, P.stop_continuous()).stream is False
    unknown = answer(device, P.frame(h('3C')))
    assert isinstance(P.decode_reply(P.decode_frame(unknown.reply)), P.IncorrectCommand)
    one = answer(device, P.request_scan())
    assert one.handshake == P.ACK and one.scan_request  # the pty layer sends the 0xB0
