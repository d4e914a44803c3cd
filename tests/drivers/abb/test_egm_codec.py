"""EGM's EgmRobot on the protobuf wire (drivers/abb/egm_codec.py): the encoding guide's own example, a round trip and
any bytes fuzzed (an EgmRobot or EgmError, never another exception). abb-robot-client's generated protobuf code reads
the mock's stream in tests/mocks/servers/abb/test_abb_judge.py."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from trackcal.drivers.abb.egm_codec import EgmError, EgmRobot, decode, encode


def test_the_header_is_the_encoding_guides_varint_example():
    # protobuf "Encoding" guide: field 1 = 150 is 08 96 01; then tm = 0 (10 00) and mtype MSGTYPE_DATA = 2 (18 02),
    # the whole header a length-delimited field 1 of EgmRobot (0a 07)
    data = encode(EgmRobot(150, 0, (0.0,) * 6, (0.0,) * 6, True, True))
    assert data[:9] == bytes.fromhex("0a0708960110001802")
    # then feedBack (field 2) holding joints (field 1) holding six unpacked doubles (key 09, eight bytes each)
    assert data[9] == 0x12 and data[11] == 0x0A and data[13:14] == b"\x09"


def test_packed_joints_are_read_too():
    # proto2 writes repeated doubles unpacked; a packed run (one length-delimited field 1) is valid on the wire too
    packed = b"\x0a\x30" + struct.pack("<6d", 1, 2, 3, 4, 5, 6)
    data = b"\x12" + bytes([len(packed) + 2]) + b"\x0a" + bytes([len(packed)]) + packed
    assert decode(data).joints_deg == (1, 2, 3, 4, 5, 6)


finite = st.floats(allow_nan=False, allow_infinity=False)


@given(
    st.integers(0, 2**32 - 1),
    st.integers(0, 2**32 - 1),
    st.lists(finite, min_size=6, max_size=6),
    st.lists(finite, min_size=6, max_size=6),
    st.booleans(),
    st.booleans(),
)
def test_round_trip(seqno, tm, joints, planned, motors, rapid):
    msg = EgmRobot(seqno, tm, tuple(joints), tuple(planned), motors, rapid)
    assert decode(encode(msg)) == msg


@given(st.binary(max_size=300))
def test_any_bytes_are_a_message_or_an_egm_error(data):
    try:
        msg = decode(data)
    except EgmError:
        return
    assert isinstance(msg, EgmRobot) and all(isinstance(v, float) for v in msg.joints_deg)


@pytest.mark.parametrize("data", [b"\x0a\x05\x08", b"\x08", b"\x0b", b"\x12\x02\x0a\x03"])
def test_truncated_or_foreign_bytes_are_refused(data):
    with pytest.raises(EgmError):
        decode(data)
