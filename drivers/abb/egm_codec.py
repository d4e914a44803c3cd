"""EGM's EgmRobot message (what an IRC5 sends every EGM cycle over UDP), encoded and decoded by hand on the protobuf
wire format: a pure function each way, no generated code and no protobuf runtime in trackcal.

The message: ABB's `egm.proto` ("Definition of ABB sensor interface V1.1", proto2, package abb.egm), as
ros-industrial/abb_libegm distributes it (proto/egm.proto, BSD-3-Clause): EgmRobot { header = 1 (EgmHeader: seqno =
1, tm = 2 ms, mtype = 3, MSGTYPE_DATA = 2); feedBack = 2 (EgmFeedBack: joints = 1, EgmJoints { repeated double
joints = 1 }, degrees); planned = 3 (EgmPlanned: joints = 1); motorState = 4 (state = 1: MOTORS_ON 1, MOTORS_OFF 2);
mciState = 5 (state = 1: MCI_STOPPED 2, MCI_RUNNING 3); rapidExecState = 8 (state = 1: RAPID_STOPPED 1,
RAPID_RUNNING 2) }. Wire format (protobuf encoding guide): a field is a varint key (number << 3 | wire type), wire
type 0 a varint, 1 eight little-endian bytes (a double), 2 a varint length and that many bytes (a sub-message, or a
packed repeated field), 5 four bytes; proto2's repeated doubles are not packed, a parser accepts both.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

MSGTYPE_DATA = 2
MOTORS_ON, MOTORS_OFF = 1, 2
MCI_STOPPED, MCI_RUNNING = 2, 3
RAPID_STOPPED, RAPID_RUNNING = 1, 2


class EgmError(ValueError):
    """Bytes that are not an EgmRobot message."""


@dataclass(frozen=True)
class EgmRobot:
    seqno: int
    tm_ms: int
    joints_deg: tuple[float, ...]  # feedBack: the actual joints
    planned_deg: tuple[float, ...]
    motors_on: bool
    rapid_running: bool


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _field(number: int, wire: int, payload: bytes) -> bytes:
    key = _varint(number << 3 | wire)
    return key + (_varint(len(payload)) + payload if wire == 2 else payload)


def _joints(values) -> bytes:
    return b"".join(_field(1, 1, struct.pack("<d", float(v))) for v in values)


def _state(value: int) -> bytes:
    return _field(1, 0, _varint(value))


def encode(msg: EgmRobot) -> bytes:
    """The EgmRobot message's bytes."""
    header = _field(1, 0, _varint(msg.seqno)) + _field(2, 0, _varint(msg.tm_ms)) + _field(3, 0, _varint(MSGTYPE_DATA))
    return b"".join(
        (
            _field(1, 2, header),
            _field(2, 2, _field(1, 2, _joints(msg.joints_deg))),
            _field(3, 2, _field(1, 2, _joints(msg.planned_deg))),
            _field(4, 2, _state(MOTORS_ON if msg.motors_on else MOTORS_OFF)),
            _field(5, 2, _state(MCI_RUNNING if msg.rapid_running else MCI_STOPPED)),
            _field(8, 2, _state(RAPID_RUNNING if msg.rapid_running else RAPID_STOPPED)),
        )
    )


def _read_varint(data: bytes, i: int) -> tuple[int, int]:
    n = shift = 0
    while True:
        if i >= len(data):
            raise EgmError("truncated varint")
        byte = data[i]
        i += 1
        n |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return n, i
        shift += 7
        if shift > 63:
            raise EgmError("varint longer than 64 bits")


def fields(data: bytes) -> dict[int, list]:
    """Field number -> its values in order (int for varints and fixed32, bytes for fixed64 and length-delimited)."""
    out: dict[int, list] = {}
    i = 0
    while i < len(data):
        key, i = _read_varint(data, i)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise EgmError("field number 0")
        if wire == 0:
            value, i = _read_varint(data, i)
        elif wire in (1, 5):
            size = 8 if wire == 1 else 4
            if i + size > len(data):
                raise EgmError("truncated fixed-size field")
            value, i = data[i : i + size], i + size
        elif wire == 2:
            size, i = _read_varint(data, i)
            if i + size > len(data):
                raise EgmError("truncated length-delimited field")
            value, i = data[i : i + size], i + size
        else:
            raise EgmError(f"wire type {wire} is not used by egm.proto")
        out.setdefault(number, []).append(value)
    return out


def _message(msg: dict[int, list], number: int) -> dict[int, list]:
    """The sub-message of field `number` ({} when absent; proto2: the last occurrence is taken), or EgmError."""
    values = msg.get(number)
    if not values:
        return {}
    if not isinstance(values[-1], bytes):
        raise EgmError(f"field {number} is not a message")
    return fields(values[-1])


def _doubles(values: list) -> tuple[float, ...]:
    out: list[float] = []
    for v in values:
        if not isinstance(v, bytes) or len(v) % 8:
            raise EgmError("a joint value is not a double")
        out += struct.unpack(f"<{len(v) // 8}d", v)  # one unpacked double, or a packed run of them
    return tuple(out)


def _state_of(msg: dict[int, list], number: int) -> int:
    state = _message(msg, number).get(1, [0])[-1]
    if not isinstance(state, int):
        raise EgmError(f"field {number}'s state is not a varint")
    return state


def decode(data: bytes) -> EgmRobot:
    """An EgmRobot from its bytes, or EgmError."""
    top = fields(data)
    header = _message(top, 1)
    seqno, tm = header.get(1, [0])[-1], header.get(2, [0])[-1]
    if not (isinstance(seqno, int) and isinstance(tm, int)):
        raise EgmError("header seqno / tm are not varints")
    joints = _doubles(_message(_message(top, 2), 1).get(1, []))
    planned = _doubles(_message(_message(top, 3), 1).get(1, []))
    return EgmRobot(
        seqno=seqno,
        tm_ms=tm,
        joints_deg=joints,
        planned_deg=planned,
        motors_on=_state_of(top, 4) == MOTORS_ON,
        rapid_running=_state_of(top, 8) == RAPID_RUNNING,
    )
