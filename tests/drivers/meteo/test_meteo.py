"""Meteo sensor: line codec (golden lines, properties, fuzz); SerialMeteo against MockMeteo on a pty."""

from __future__ import annotations

import contextlib
import os
import re
import threading
import time
import tty

import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackcal.drivers.errors import ConnectionLost, DeviceTimeout, ProtocolError
from trackcal.drivers.interfaces import Environment, Meteo, RealClock
from trackcal.drivers.meteo.client import SerialMeteo
from trackcal.drivers.meteo.codec import (
    MAX_LINE_BYTES,
    MAX_SEQ,
    Reading,
    checksum,
    encode_reading,
    parse_line,
    parse_request,
    request,
)
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.meteo import MeteoFault, MockMeteo, reading_for

# ---------------------------------------------------------------- golden lines, checksums computed by hand
#
# GOLDEN_1 body "MET,T=20.31,P=1013.25,H=45.2" (ASCII hex: M 4D, E 45, T 54, ',' 2C, '=' 3D, '.' 2E,
# '0'..'5' 30..35, P 50, H 48). Equal characters cancel in pairs under XOR: T x2, '0' x2 (20, 1013),
# '3' x2 (.31, 1013), '5' x2 (.25, 45); ',' '=' '.' '2' '1' each occur 3 times and leave one.
# Left: 4D^45 = 08; ^2C = 24; ^3D = 19; ^2E = 37; ^32 = 05; ^31 = 34; ^50 = 64; ^48 = 2C; ^34 ('4') = 18.
GOLDEN_1 = b"$MET,T=20.31,P=1013.25,H=45.2*18\r\n"
#
# GOLDEN_2 body "MET,T=-5.00,P=950.00,H=0.0": T x2 and '5' x2 cancel, ',' '=' '.' x3 leave one each,
# '0' occurs 7 times (two in -5.00, three in 950.00, two in 0.0) and leaves one; '-' 2D and '9' 39 once.
# Left: 4D^45 = 08; ^2C = 24; ^3D = 19; ^2E = 37; ^2D = 1A; ^30 = 2A; ^50 = 7A; ^48 = 32; ^39 = 0B.
GOLDEN_2 = b"$MET,T=-5.00,P=950.00,H=0.0*0B\r\n"


def test_golden_lines_encode():
    assert encode_reading(Reading(20.31, 1013.25, 45.2)) == GOLDEN_1
    assert encode_reading(Reading(-5.0, 950.0, 0.0)) == GOLDEN_2


def test_golden_lines_parse():
    assert parse_line(GOLDEN_1) == Reading(20.31, 1013.25, 45.2)
    assert parse_line(GOLDEN_2) == Reading(-5.0, 950.0, 0.0)
    assert parse_line(GOLDEN_1.rstrip(b"\r\n")) == Reading(20.31, 1013.25, 45.2)  # terminator optional
    assert parse_line(GOLDEN_2.replace(b"*0B", b"*0b")) == Reading(-5.0, 950.0, 0.0)  # hex in either case


def test_checksum_of_single_bytes_is_the_byte():
    # XOR over one byte is that byte; over a byte twice is 0 (the definition, nothing computed by the code).
    assert checksum(b"M") == 0x4D
    assert checksum(b"MM") == 0
    assert checksum(b"") == 0


def _with_checksum(body: bytes) -> bytes:
    return b"$" + body + b"*" + f"{checksum(body):02X}".encode() + b"\r\n"


@pytest.mark.parametrize(
    "line, reason",
    [
        (GOLDEN_1.replace(b"*18", b"*19"), "bad checksum"),
        (GOLDEN_1.replace(b"*18", b"*1"), "checksum field"),
        (GOLDEN_1.replace(b"*18", b""), "missing '*checksum'"),
        (GOLDEN_1[1:], "does not start with '$'"),
        (b"\r\n", "empty line"),
        (b"", "empty line"),
        (_with_checksum(b"MET,T=20.31,P=1013.25"), "fields missing"),
        (_with_checksum(b"MET,P=1013.25,T=20.31,H=45.2"), "fields missing"),
        (_with_checksum(b"MET,T=20.31,P=1013.25,H=45.2,X=1"), "fields missing"),
        (_with_checksum(b"MET,T=nan,P=1013.25,H=45.2"), "not numeric"),
        (_with_checksum(b"MET,T=inf,P=1013.25,H=45.2"), "not numeric"),
        (_with_checksum(b"MET,T=2e1,P=1013.25,H=45.2"), "not numeric"),
        (_with_checksum(b"MET,T=+20.0,P=1013.25,H=45.2"), "not numeric"),
        (_with_checksum(b"MET,T=2_0,P=1013.25,H=45.2"), "not numeric"),
        (_with_checksum(b"MET,T= 20.0,P=1013.25,H=45.2"), "not numeric"),
        (_with_checksum(b"GGA,T=20.31,P=1013.25,H=45.2"), "unknown sentence"),
        # physical limits: T -40..85 degC, P 300..1200 hPa, H 0..100 %RH (meteo-protocol.md)
        (_with_checksum(b"MET,T=85.01,P=1013.25,H=45.2"), "outside the physical range"),
        (_with_checksum(b"MET,T=-40.01,P=1013.25,H=45.2"), "outside the physical range"),
        (_with_checksum(b"MET,T=20.00,P=299.99,H=45.2"), "outside the physical range"),
        (_with_checksum(b"MET,T=20.00,P=1200.01,H=45.2"), "outside the physical range"),
        (_with_checksum(b"MET,T=20.00,P=1013.25,H=100.1"), "outside the physical range"),
        (_with_checksum(b"MET,T=20.00,P=1013.25,H=-0.1"), "outside the physical range"),
        (_with_checksum(b"MET,T=20.31,P=1013.25,H=45.2\x00"), "non-printable"),
        (GOLDEN_1.replace(b"20.31", b"20\xe9.3"), "non-printable"),
        (b"$" + b"MET," + b"0" * 80 + b"*00\r\n", "exceeds"),
    ],
)
def test_bad_lines_raise_protocol_error(line, reason):
    with pytest.raises(ProtocolError, match=re.escape(reason)):
        parse_line(line)


def test_range_limits_are_inclusive():
    assert parse_line(_with_checksum(b"MET,T=-40.00,P=300.00,H=0.0")) == Reading(-40.0, 300.0, 0.0)
    assert parse_line(_with_checksum(b"MET,T=85.00,P=1200.00,H=100.0")) == Reading(85.0, 1200.0, 100.0)


def test_encode_refuses_unphysical_values():
    with pytest.raises(ValueError):
        encode_reading(Reading(90.0, 1013.25, 45.0))


# The longest legal answer ("$MET,T=-40.00,P=1200.00,H=100.0*hh\r\n", 36 bytes) is far under the 82-byte cap.
def test_longest_answer_fits_the_cap():
    assert len(encode_reading(Reading(-40.0, 1200.0, 100.0))) <= MAX_LINE_BYTES


# ---------------------------------------------------------------- properties and fuzz
readings = st.builds(
    Reading,
    st.floats(-40.0, 85.0),
    st.floats(300.0, 1200.0),
    st.floats(0.0, 100.0),
)


@given(readings)
def test_round_trip_to_wire_resolution(r):
    back = parse_line(encode_reading(r))
    # Wire resolution 0.01 degC, 0.01 hPa, 0.1 %RH: rounding error at most half a step.
    assert abs(back.temperature_c - r.temperature_c) <= 0.005 + 1e-9
    assert abs(back.pressure_hpa - r.pressure_hpa) <= 0.005 + 1e-9
    assert abs(back.humidity_pct - r.humidity_pct) <= 0.05 + 1e-9


@settings(max_examples=500, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=200))
def test_fuzz_random_bytes_only_protocol_error(data):
    try:
        result = parse_line(data)
    except ProtocolError:
        return
    assert isinstance(result, Reading)


@settings(max_examples=300)
@given(readings, st.data())
def test_fuzz_truncation_and_bit_flips(r, data):
    line = encode_reading(r)
    cut = data.draw(st.integers(0, len(line) - 3))  # drop at least the whole checksum end or CR LF
    with pytest.raises(ProtocolError):
        parse_line(line[:cut])
    # One byte of the body or the '*' (not the hex digits: flipping bit 5 of 'A'..'F' only changes their case,
    # which the protocol accepts).
    pos = data.draw(st.integers(1, line.rindex(b"*")))
    flipped = bytearray(line)
    flipped[pos] ^= 1 << data.draw(st.integers(0, 7))
    # A single flipped bit in the body changes its XOR by that bit; a flipped '*' breaks the framing.
    with pytest.raises(ProtocolError):
        parse_line(bytes(flipped))


@settings(max_examples=300)
@given(st.text(alphabet="$MET,=.*-0123456789ABCDEFHP\r\n", max_size=90))
def test_fuzz_protocol_alphabet_only_protocol_error(text):
    with contextlib.suppress(ProtocolError):
        parse_line(text.encode("ascii"))


# ---------------------------------------------------------------- mock determinism
def test_mock_readings_pure_in_seed_and_request_count():
    assert reading_for(3, 17) == reading_for(3, 17)
    assert reading_for(3, 17) != reading_for(4, 17)
    assert reading_for(3, 17) != reading_for(3, 18)
    # Drift + noise stay close to the base: |drift| <= 0.3 degC / 0.5 hPa / 2 %RH, noise sigma 0.01/0.02/0.1
    # (mocks/servers/meteo.py); 6 sigma bound on the noise over 1000 draws.
    for n in range(1000):
        r = reading_for(3, n)
        assert abs(r.temperature_c - 20.0) <= 0.3 + 6 * 0.01
        assert abs(r.pressure_hpa - 1013.25) <= 0.5 + 6 * 0.02
        assert abs(r.humidity_pct - 45.0) <= 2.0 + 6 * 0.1


# ---------------------------------------------------------------- SerialMeteo end to end on a pty
@pytest.fixture
def meteo():
    mock = MockMeteo(seed=11, clock=VirtualClock()).start()
    client = SerialMeteo(mock.port_path, timeout_s=0.3)
    client.connect()
    yield mock, client
    client.close()
    mock.stop()


def test_serial_meteo_implements_interface(meteo):
    _, client = meteo
    assert isinstance(client, Meteo)


def test_reads_are_the_mock_readings_in_order(meteo):
    mock, client = meteo
    got = [client.read() for _ in range(5)]
    want = [parse_line(encode_reading(reading_for(11, n))).to_environment() for n in range(5)]
    assert got == want
    assert all(isinstance(e, Environment) for e in got)


def test_same_seed_same_bytes():
    lines = []
    for _ in range(2):
        with MockMeteo(seed=5, clock=VirtualClock()) as mock:
            client = SerialMeteo(mock.port_path, timeout_s=0.3)
            client.connect()
            for _ in range(3):
                client.read()
            client.close()
            lines.append(list(mock.answers))
    assert lines[0] == lines[1] and len(lines[0]) == 3


def test_silence_times_out_then_recovers(meteo):
    mock, client = meteo
    mock.inject(MeteoFault.SILENCE)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match=mock.port_path):
        client.read()
    assert time.monotonic() - t0 < 0.3 + 0.2  # timeout plus one poll slice and scheduling slack
    # request 0 was silenced; the next answer is request 1's reading
    assert client.read() == parse_line(encode_reading(reading_for(11, 1))).to_environment()


def test_bad_checksum_is_protocol_error(meteo):
    mock, client = meteo
    mock.inject(MeteoFault.BAD_CHECKSUM)
    with pytest.raises(ProtocolError, match="bad checksum"):
        client.read()
    client.read()


def test_garbage_line_is_protocol_error(meteo):
    mock, client = meteo
    mock.inject(MeteoFault.GARBAGE, times=3)
    for _ in range(3):
        with pytest.raises(ProtocolError):
            client.read()
    client.read()


def test_overlong_line_is_protocol_error(meteo):
    mock, client = meteo
    mock.inject(MeteoFault.OVERLONG)
    with pytest.raises(ProtocolError, match="no line end within 82 bytes"):
        client.read()
    client.read()


def test_read_before_connect_and_bad_port():
    with pytest.raises(ConnectionLost):
        SerialMeteo("/dev/nonexistent-meteo", timeout_s=0.1).read()
    with pytest.raises(ConnectionLost, match="/dev/nonexistent-meteo"):
        SerialMeteo("/dev/nonexistent-meteo", timeout_s=0.1).connect()


# ---------------------------------------------------------------- answers matched to requests (issue 27, item 8)
def _wire(seed: int, n: int) -> Environment:
    """What the mock answers to request number n, as the client returns it (wire resolution)."""
    return parse_line(encode_reading(reading_for(seed, n))).to_environment()


def test_a_second_reader_and_a_stale_answer_never_shift_a_reading():
    """Issue 27: "a second process reading the meteo port shifts every later row's meteo by one answer". Every
    read of the first client is the mock's answer to its own request, whoever else asks on the same pty."""
    # a real clock and a 0.1 s answer delay (well inside the sensor's 200 ms, meteo-protocol.md), so the stale
    # answer below is written after the first client has flushed its input and sent its own request
    with MockMeteo(seed=11, clock=RealClock(), response_delay_s=0.1) as mock:
        first = SerialMeteo(mock.port_path, timeout_s=5.0)  # 5 s only bounds a hang
        second = SerialMeteo(mock.port_path, timeout_s=5.0)
        stray = serial.serial_for_url(mock.port_path, timeout=0.1)
        with first, second, contextlib.closing(stray):
            got = []
            for k in range(4):
                got.append(first.read())
                second.read()  # a second process taking answers on the same port
                second.read()
                stray.write(b"M%d\r\n" % (1000 + k))  # a request nobody reads: its answer lands in the buffer
            assert got == [_wire(11, k) for k in range(4)]
            assert mock.requests >= 4 * 3
    with pytest.raises(ValueError):
        encode_reading(Reading(20.0, 1013.25, 45.0, 65536))


def test_unnumbered_answer_is_refused():
    """A line without N= cannot be matched to the request: refused with a one-line ProtocolError."""
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        client = SerialMeteo(os.ttyname(slave), timeout_s=5.0)
        with client:
            sent = threading.Event()

            def sensor():  # answers the request with the unnumbered line of the protocol's golden example
                buf = b""
                while b"\n" not in buf:
                    buf += os.read(master, 64)
                sent.set()
                os.write(master, GOLDEN_1)

            threading.Thread(target=sensor, daemon=True).start()
            with pytest.raises(ProtocolError, match=r"carries no request number N= \(sent M0\)"):
                client.read()
            assert sent.is_set()
    finally:
        os.close(master)
        os.close(slave)


@given(readings, st.integers(0, MAX_SEQ))
def test_numbered_round_trip(r, n):
    numbered = Reading(r.temperature_c, r.pressure_hpa, r.humidity_pct, n)
    line = encode_reading(numbered)
    assert len(line) <= MAX_LINE_BYTES and parse_line(line).seq == n
    assert parse_request(request(n)) == n


@settings(max_examples=300)
@given(st.text(alphabet="$MET,=.*-0123456789ABCDEFHPN\r\n", max_size=90))
def test_fuzz_numbered_alphabet_only_protocol_error(text):
    with contextlib.suppress(ProtocolError):
        parse_line(text.encode("ascii"))
    assert parse_request(text.encode("ascii")) is None or text.startswith("M")
