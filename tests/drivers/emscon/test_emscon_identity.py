"""The tracker's identity over emScon (#39): GetTrackerInfo (ES_C_GetTrackerInfo = 132) and GetSystemSoftwareVersion
(ES_C_GetSystemSoftwareVersion = 142) in the codec, the mock's answers and the client's `identity()`.

The golden packets are built here by hand from beckjac/emscon_ros include/emscon_ros/ES_C_API_Def.h (TPI V3.6), not
with trackcal's codec: `#pragma pack (push, 4)`, 4-byte long / enum / ES_BOOL, little-endian, and

    struct GetTrackerInfoRT { BasicCommandRT packetInfo; enum ES_LTSensorType trackerType;
        unsigned short cTrackerName[32]; /* UNICODE string */ long lSerialNumber; long lCompensationIdNumber;
        ES_BOOL bHasADM; ES_BOOL bHasOverviewCamera; ES_BOOL bHasNivel; double dNivelMountOffset; double dMaxDistance;
        double dMinDistance; int iMaxDataRate; int iNumberOfFaces; double dHzAngleRange; double dVtAngleRange;
        enum ES_TrkAccuracyModel accuracyModel; int iMajLCPFirmwareVersion; int iMinLCPFirmwareVersion; };
    struct GetSystemSoftwareVersionRT { BasicCommandRT packetInfo; unsigned short cSoftwareVersion[32]; };

ES_LTS_AT901_LR = 15, ES_TAM_2005 = 1 (the header's enums). The UNICODE strings are UTF-16 code units (MSVC's
UNICODE, the header's compiler), NUL-terminated. The values are arbitrary but representable exactly.
"""

from __future__ import annotations

import math
import socket
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from trackcal.drivers.emscon.client import EmsconTracker
from trackcal.drivers.emscon.enums import LTSensorType, ResultStatus, TrkAccuracyModel
from trackcal.drivers.emscon.framing import Direction, decode_packet, encode
from trackcal.drivers.emscon.messages import (
    GetSystemSoftwareVersion,
    GetTrackerInfo,
    SoftwareVersionAnswer,
    TrackerInfoAnswer,
    encode_command,
)
from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.interfaces import READ_FROM_DEVICE, DeviceIdentity
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.emscon import MockEmscon
from trackcal.mocks.servers.emscon_identity import TrackerIdentity

RT = "<iiii"  # BasicCommandRT {PacketHeaderT {lPacketSize; type}; command; status}
TRACKER_INFO = RT + "i32H" + "iiiii" + "ddd" + "ii" + "dd" + "iii"
SOFTWARE = RT + "32H"


def units(text: str) -> list[int]:
    """A UNICODE string field by hand: its UTF-16 code units, then NULs to 32."""
    code = [ord(c) for c in text]  # BMP characters: one unit each
    return code + [0] * (32 - len(code))


def ask(sock: socket.socket, packet: bytes, n: int) -> bytes:
    """Send one packet, read the n bytes of its answer."""
    sock.sendall(packet)
    got = b""
    while len(got) < n:
        data = sock.recv(4096)
        assert data, "the mock closed the connection"
        got += data
    assert len(got) == n
    return got


def test_golden_tracker_info_answer():
    # ES_DT_Command 0, ES_C_GetTrackerInfo 132, ES_RS_AllOK 0; an AT901-LR (15), serial 390123, compensation 7,
    # ADM and overview camera, no nivel, 80 m range, 3000 measurements/s, 2 faces, +-360 / +-145 deg, ES_TAM_2005,
    # LCP firmware 3.6
    raw = struct.pack(
        TRACKER_INFO,
        164,
        0,
        132,
        0,
        15,
        *units("AT901-LR"),
        390123,
        7,
        1,
        1,
        0,
        0.0,
        80000.0,
        0.0,
        3000,
        2,
        360.0,
        145.0,
        1,
        3,
        6,
    )
    assert len(raw) == 164  # sizeof(GetTrackerInfoRT), as tests/drivers/emscon/test_emscon_codec.py works it out
    answer = TrackerInfoAnswer(
        ResultStatus.ALL_OK,
        LTSensorType.AT901_LR,
        "AT901-LR",
        390123,
        7,
        True,
        True,
        False,
        0.0,
        80000.0,
        0.0,
        3000,
        2,
        360.0,
        145.0,
        TrkAccuracyModel.TAM_2005,
        (3, 6),
    )
    assert decode_packet(raw) == answer
    assert encode(answer) == raw


def test_golden_software_version_answer_and_requests():
    raw = struct.pack(SOFTWARE, 80, 0, 142, 0, *units("3.6.1.2"))  # 16 + 32 unsigned short = 80 bytes
    assert decode_packet(raw) == SoftwareVersionAnswer(ResultStatus.ALL_OK, "3.6.1.2")
    assert encode(SoftwareVersionAnswer(ResultStatus.ALL_OK, "3.6.1.2")) == raw
    # GetTrackerInfoCT / GetSystemSoftwareVersionCT: BasicCommandCT only, 12 bytes
    assert encode_command(GetTrackerInfo()) == struct.pack("<iii", 12, 0, 132)
    assert encode_command(GetSystemSoftwareVersion()) == struct.pack("<iii", 12, 0, 142)
    assert decode_packet(struct.pack("<iii", 12, 0, 132), Direction.TO_TRACKER) == GetTrackerInfo()


def test_unicode_strings_as_the_header_has_them():
    # a name filling all 32 units has no terminator: a C reader stops at the array's end
    full = struct.pack(SOFTWARE, 80, 0, 142, 0, *([ord("9")] * 32))
    assert decode_packet(full).version == "9" * 32
    # a character outside the BMP is two UTF-16 units (a surrogate pair): U+1F600 = D83D DE00
    pair = struct.pack(SOFTWARE, 80, 0, 142, 0, 0xD83D, 0xDE00, *([0] * 30))
    assert decode_packet(pair).version == "\U0001f600"
    # a lone surrogate is no UTF-16 text
    with pytest.raises(ProtocolError, match="cSoftwareVersion"):
        decode_packet(struct.pack(SOFTWARE, 80, 0, 142, 0, 0xD83D, *([0] * 31)))
    # what cannot be sent: 32 units leave no room for the NUL, a NUL inside would end the text early
    for text in ("x" * 32, "a\0b"):
        with pytest.raises(ValueError):
            encode(SoftwareVersionAnswer(ResultStatus.ALL_OK, text))


int32 = st.integers(-(2**31), 2**31 - 1)
finite = st.floats(allow_nan=False, allow_infinity=False)
# texts of at most 31 UTF-16 units and no NUL (surrogates are not characters of a str that encodes)
names = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\0"), max_size=31).filter(
    lambda t: len(t.encode("utf-16-le")) // 2 <= 31
)
statuses = st.sampled_from(list(ResultStatus))
tracker_infos = st.builds(
    TrackerInfoAnswer,
    statuses,
    st.sampled_from(list(LTSensorType)),
    names,
    int32,
    int32,
    st.booleans(),
    st.booleans(),
    st.booleans(),
    finite,
    finite,
    finite,
    int32,
    int32,
    finite,
    finite,
    st.sampled_from(list(TrkAccuracyModel)),
    st.tuples(int32, int32),
)


@given(st.one_of(tracker_infos, st.builds(SoftwareVersionAnswer, statuses, names)))
def test_identity_answers_round_trip(answer):
    assert decode_packet(encode(answer)) == answer


@given(st.binary(min_size=148, max_size=148), st.sampled_from([(132, 164), (142, 80)]))
def test_decoding_any_payload_is_an_answer_or_a_protocol_error(body, command_size):
    command, size = command_size
    raw = struct.pack(RT, size, 0, command, 0) + body[: size - 16]
    try:
        answer = decode_packet(raw)
    except ProtocolError:
        return  # a value outside its enum, an ES_BOOL not 0/1, a non-finite double, a lone surrogate
    assert isinstance(answer, TrackerInfoAnswer | SoftwareVersionAnswer)


def test_mock_answers_its_identity_in_the_units_set():
    """A raw client, before any SetUnits: the mock's power-on units are metres and degrees (mocks/servers/emscon.py),
    so the 80 m range reads 80.0; after SetUnits (mm, radians) the same answer reads 80000 and 2 pi."""
    identity = TrackerIdentity(LTSensorType.AT901_LR, "AT901-LR", 391234, (3, 6), "3.6.0")
    server = MockEmscon(lambda expected: (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), VirtualClock(), identity=identity).start()
    try:
        with socket.create_connection(server.address, timeout=2.0) as raw:
            v = struct.unpack(TRACKER_INFO, ask(raw, struct.pack("<iii", 12, 0, 132), 164))
            assert v[:5] == (164, 0, 132, 0, 15)
            assert v[5:13] == tuple(units("AT901-LR")[:8]) and v[37] == 391234
            assert (v[43], v[47]) == (80.0, 360.0)
            assert v[-2:] == (3, 6)
            # SetUnits {ES_LU_Millimeter 1; ES_AU_Radian 0; Celsius 0; mbar 0; RH 0}: SetUnitsRT (16), then a change
            ask(raw, struct.pack("<iii5i", 32, 0, 5, 1, 0, 0, 0, 0), 16 + 12)
            v = struct.unpack(TRACKER_INFO, ask(raw, struct.pack("<iii", 12, 0, 132), 164))
            assert v[43] == 80000.0 and v[47] == pytest.approx(2 * math.pi, rel=1e-15)
    finally:
        server.stop()


def test_client_reads_the_identity_from_the_mock():
    identity = TrackerIdentity(LTSensorType.AT901_LR, "AT901-LR", 391234, (3, 6), "3.6.0")
    server = MockEmscon(lambda expected: (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), VirtualClock(), identity=identity).start()
    tracker = EmsconTracker(*server.address, timeout_s=2.0)
    try:
        tracker.connect()
        assert tracker.identity() == DeviceIdentity(
            "391234", "AT901-LR (ES_LTSensorType 15)", "LCP firmware 3.6, emScon 3.6.0", READ_FROM_DEVICE
        )
        assert "serial=391234" in tracker.status().detail  # GetSystemStatusRT's lTrackerSerialNumber: the same one
    finally:
        tracker.close()
        server.stop()
