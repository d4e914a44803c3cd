"""Line codec of the serial meteo sensor (temperature, pressure, humidity): pure functions, no I/O.

The protocol is documented in configs/hardware/meteo-protocol.md. In short:

    host   -> sensor   b"M17\\r\\n"                                 (measurement request number 17)
    sensor -> host     b"$MET,N=17,T=20.31,P=1013.25,H=45.2*41\\r\\n"   (its answer, echoing N=17)

The checksum is the NMEA 0183 one: the XOR of every byte strictly between '$' and '*', written as two
hexadecimal digits. A line is at most 82 bytes including '$' and CR LF, the NMEA 0183 sentence limit.

`parse_line` is total: for any input bytes it returns a `Reading` or raises `ProtocolError`, never anything
else (fuzzed in tests/test_meteo.py).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.interfaces import Environment

MAX_SEQ = 65535  # request numbers run 0..MAX_SEQ and wrap
TERMINATOR = b"\r\n"
SENTENCE = "MET"
MAX_LINE_BYTES = 82  # NMEA 0183: "$" + up to 79 characters + CR LF

# Physical plausibility limits (inclusive); a value outside them is a broken sensor or a broken line.
# They are the operating ranges of common industrial combined T/P/H sensors (e.g. Bosch BME280 datasheet:
# -40..85 degC; pressure 300..1100 hPa, widened here to 1200 hPa; 0..100 %RH).
T_RANGE_C = (-40.0, 85.0)
P_RANGE_HPA = (300.0, 1200.0)
H_RANGE_PCT = (0.0, 100.0)

# Decimal places on the wire: 0.01 degC, 0.01 hPa, 0.1 %RH.
T_DECIMALS = 2
P_DECIMALS = 2
H_DECIMALS = 1

# A number on the wire: optional minus sign, 1..4 integer digits, optional 1..3 decimals. No '+', no exponent,
# no 'nan'/'inf', no underscores or spaces (all of which Python's float() would otherwise accept).
_NUMBER = r"-?[0-9]{1,4}(?:\.[0-9]{1,3})?"
# The request number echoed in the answer: decimal 0..65535, no sign, no leading zero.
_SEQ = r"0|[1-9][0-9]{0,4}"
_BODY_RE = re.compile(rf"MET,(?:N=(?P<n>{_SEQ}),)?T=(?P<t>{_NUMBER}),P=(?P<p>{_NUMBER}),H=(?P<h>{_NUMBER})")
_HEX2_RE = re.compile(r"[0-9A-Fa-f]{2}")


@dataclass(frozen=True)
class Reading:
    temperature_c: float
    pressure_hpa: float
    humidity_pct: float
    seq: int | None = None  # the request number the answer echoes (None: an unnumbered line)

    def to_environment(self) -> Environment:
        return Environment(self.temperature_c, self.pressure_hpa, self.humidity_pct)


def checksum(body: bytes) -> int:
    """NMEA 0183 checksum: XOR of all bytes of `body` (the text between '$' and '*')."""
    value = 0
    for byte in body:
        value ^= byte
    return value


def request(seq: int) -> bytes:
    """The measurement request number `seq` (0..MAX_SEQ), CR LF terminated."""
    if not 0 <= seq <= MAX_SEQ:
        raise ValueError(f"request number {seq} outside 0..{MAX_SEQ}")
    return b"M%d" % seq + TERMINATOR


def parse_request(line: bytes) -> int | None:
    """The number of a request line (with or without its CR LF), or None for any other line (ignored)."""
    match = re.fullmatch(rb"M(" + _SEQ.encode("ascii") + rb")\r?\n?", bytes(line))
    seq = None if match is None else int(match.group(1))
    return seq if seq is not None and seq <= MAX_SEQ else None


def _check_range(name: str, value: float, bounds: tuple[float, float], unit: str) -> None:
    low, high = bounds
    if not low <= value <= high:
        raise ProtocolError(f"{name}={value} {unit} outside the physical range {low}..{high} {unit}")


def encode_reading(reading: Reading) -> bytes:
    """One sensor answer line, CR LF terminated. Raises ValueError for values outside the physical ranges."""
    try:
        _check_range("T", reading.temperature_c, T_RANGE_C, "degC")
        _check_range("P", reading.pressure_hpa, P_RANGE_HPA, "hPa")
        _check_range("H", reading.humidity_pct, H_RANGE_PCT, "%RH")
    except ProtocolError as exc:
        raise ValueError(str(exc)) from None
    if reading.seq is not None and not 0 <= reading.seq <= MAX_SEQ:
        raise ValueError(f"request number {reading.seq} outside 0..{MAX_SEQ}")
    number = "" if reading.seq is None else f"N={reading.seq},"
    body = (
        f"{SENTENCE},{number}T={reading.temperature_c:.{T_DECIMALS}f},P={reading.pressure_hpa:.{P_DECIMALS}f},"
        f"H={reading.humidity_pct:.{H_DECIMALS}f}"
    ).encode("ascii")
    return b"$" + body + b"*" + f"{checksum(body):02X}".encode("ascii") + TERMINATOR


def parse_line(line: bytes) -> Reading:
    """Parse one sensor line (with or without its CR LF) into a Reading, or raise ProtocolError."""
    if not isinstance(line, bytes | bytearray):
        raise ProtocolError(f"expected bytes, got {type(line).__name__}")
    if len(line) > MAX_LINE_BYTES:
        raise ProtocolError(f"line of {len(line)} bytes exceeds the {MAX_LINE_BYTES}-byte limit")
    raw = bytes(line)
    if raw.endswith(TERMINATOR):
        raw = raw[: -len(TERMINATOR)]
    elif raw.endswith(b"\n"):
        raw = raw[:-1]
    if not raw:
        raise ProtocolError("empty line")
    if any(b < 0x20 or b > 0x7E for b in raw):
        raise ProtocolError(f"non-printable or non-ASCII byte in line {raw[:40]!r}")
    if raw[:1] != b"$":
        raise ProtocolError(f"line does not start with '$': {raw[:40]!r}")
    star = raw.rfind(b"*")
    if star < 0:
        raise ProtocolError(f"missing '*checksum' in {raw!r}")
    body, given = raw[1:star], raw[star + 1 :].decode("ascii")
    if not _HEX2_RE.fullmatch(given):
        raise ProtocolError(f"checksum field {given!r} is not two hexadecimal digits")
    expected = checksum(body)
    if int(given, 16) != expected:
        raise ProtocolError(f"bad checksum: line says {given.upper()}, content gives {expected:02X}")
    text = body.decode("ascii")
    sentence = text.split(",", 1)[0]
    if sentence != SENTENCE:
        raise ProtocolError(f"unknown sentence {sentence!r} (expected {SENTENCE!r})")
    match = _BODY_RE.fullmatch(text)
    if match is None:
        raise ProtocolError(f"fields missing, out of order or not numeric in {text!r} (expected [N=,]T=,P=,H=)")
    seq = None if match.group("n") is None else int(match.group("n"))
    if seq is not None and seq > MAX_SEQ:
        raise ProtocolError(f"request number N={seq} outside 0..{MAX_SEQ}")
    t, p, h = (float(match.group(k)) for k in ("t", "p", "h"))
    _check_range("T", t, T_RANGE_C, "degC")
    _check_range("P", p, P_RANGE_HPA, "hPa")
    _check_range("H", h, H_RANGE_PCT, "%RH")
    return Reading(t, p, h, seq)
