"""A third-party emScon client's own command sequence against the mock tracker, over a real socket.

The client is MuffinSpawn/Leica's CESAPI (a Python emScon client used against real AT4xx trackers): the
sequence of its bin/command-example.py (`initialize()`: SetUnits, GetSystemStatus, Initialize,
SetMeasurementMode, SetStationaryModeParams, SetCoordinateSystemType(ES_CS_SCC), SetSystemSettings; then
`measure()`: CESAPI/refract.py's GetRefractionParams, SetRefractionParams, GetEnvironmentParams,
SetRefractionParams, and StartMeasurement), then the commands of its CESAPI/command.py that the issue found the
mock hanging up on (SetSystemSettings, GetUnits, GetReflectors, GetRefractionParams, GetDirection, GetTrackerInfo,
SetStatisticMode) and a measurement in the extended statistic mode it selects. The reflector is on the bird bath
(GoBirdBath, also one of its commands) before each measurement.

Its way of waiting is CESAPI/command.py's CommandSync.execute: send one *CT, then read packets until one of type
ES_DT_Command with the same command id (for StartMeasurement: until the ES_DT_SingleMeasResult or
ES_DT_SingleMeasResult2 after it), skipping status changes and reflector positions; an ES_DT_Error fails the
command. Its reader (CESAPI/connection.py) frames by lPacketSize and unpacks the fixed struct of each answer, so
every answer must have the size of that command's *RT.

The packets are built here from ES_C_API_Def.h (beckjac/emscon_ros, TPI V3.6) by hand, not with trackcal's
codec: every struct below is the header's, `#pragma pack(4)`, 4-byte long / enum / ES_BOOL, little-endian.
"""

from __future__ import annotations

import math
import socket
import struct

import pytest

from trackcal.campaign.cells.hardware import load_hardware
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.emscon import MockEmscon

# ES_DataType
ES_DT_COMMAND, ES_DT_ERROR, ES_DT_SINGLE_MEAS, ES_DT_SYSTEM_STATUS_CHANGE, ES_DT_SINGLE_MEAS2 = 0, 1, 2, 8, 9
ES_DT_REFLECTOR_POS = 7
ES_C_START_MEASUREMENT = 49
ES_RS_ALL_OK, ES_RS_NOT_IMPLEMENTED = 0, 2
# the reflector on the bird bath, tracker frame (mm): 1.5 m from the tracker, in its horizontal plane
BIRD_BATH = (1200.0, 900.0, 0.0)

# (ES_Command, name, format and values of what follows BasicCommandCT, format of what follows BasicCommandRT)
SEQUENCE = [
    # command-example.py initialize(): SystemUnitsDataT {ES_LU_Millimeter 1; ES_AU_Radian 0; ES_TU_Celsius 0;
    # ES_PU_Mbar 0; ES_HU_RH 0} (the fields it does not set stay int(0))
    (5, "SetUnits", "5i", (1, 0, 0, 0, 0), ""),
    (1, "GetSystemStatus", "", (), "iiii" + "iii" + "iii"),  # GetSystemStatusRT
    (7, "Initialize", "", (), ""),
    (24, "SetMeasurementMode", "i", (0,), ""),  # ES_MM_Stationary
    (28, "SetStationaryModeParams", "ii", (1000, 0), ""),  # StationaryModeDataT {lMeasTime 1000; bUseADM 0}
    (26, "SetCoordinateSystemType", "i", (7,), ""),  # ES_CS_SCC
    # SystemSettingsDataT {ES_WMS_ReadAndCalculateRefractions 2; bApplyTransformationParams 0 (not set);
    # bApplyStationOrientationParams 1; bKeepLastPosition 1; bSendUnsolicitedMessages 1;
    # bSendReflectorPositionData 0; bTryMeasurementMode 0; bHasNivel 1; bHasVideoCamera 1}
    (47, "SetSystemSettings", "9i", (2, 0, 1, 1, 1, 0, 0, 1, 1), ""),
    # refract.py SetRefractionIndex(): RefractionDataT {dIfmRefractionIndex; dAdmRefractionIndex}
    (23, "GetRefractionParams", "", (), "dd"),
    (22, "SetRefractionParams", "dd", (1.000331, 0.0), ""),  # its RI_MAX
    (21, "GetEnvironmentParams", "", (), "ddd"),  # EnvironmentDataT
    (22, "SetRefractionParams", "dd", (1.0002405, 0.0), ""),  # (RI_MIN + RI_MAX) / 2
    (54, "GoBirdBath", "", (), ""),
    (49, "StartMeasurement", "", (), ""),
    # the rest of what the issue found
    (6, "GetUnits", "", (), "5i"),  # GetUnitsRT {SystemUnitsDataT}
    (48, "GetSystemSettings", "", (), "9i"),  # GetSystemSettingsRT {SystemSettingsDataT}
    (42, "GetReflectors", "", (), "iiid32H"),  # {iTotalReflectors; iInternalReflectorId; targetType;
    #                                             dSurfaceOffset; unsigned short cReflectorName[32]}
    (66, "GetDirection", "", (), "dd"),  # GetDirectionRT {dHzAngle; dVtAngle}
    # GetTrackerInfoRT {trackerType; cTrackerName[32]; lSerialNumber; lCompensationIdNumber; bHasADM;
    # bHasOverviewCamera; bHasNivel; dNivelMountOffset; dMaxDistance; dMinDistance; iMaxDataRate; iNumberOfFaces;
    # dHzAngleRange; dVtAngleRange; accuracyModel; iMajLCPFirmwareVersion; iMinLCPFirmwareVersion}
    (132, "GetTrackerInfo", "", (), "i32Hiiiii" + "ddd" + "ii" + "dd" + "iii"),
    # SetStatisticModeCT {stationaryMeasurements ES_SM_Extended 1; continuousMeasurements ES_SM_Extended 1}
    (80, "SetStatisticMode", "ii", (1, 1), ""),
    (81, "GetStatisticMode", "", (), "ii"),
    (54, "GoBirdBath", "", (), ""),
    (49, "StartMeasurement", "", (), ""),
]
SINGLE_MEAS = "<iiiii" + "17d"  # SingleMeasResultT: ReturnDataT {size; type; status}; measMode; bIsTryMode; 17 d
SINGLE_MEAS2 = "<iiiii" + "23d"  # SingleMeasResult2T: ... 23 doubles


class CommandSync:
    """MuffinSpawn/Leica CESAPI/command.py CommandSync.execute, reduced to the bytes: one command at a time."""

    def __init__(self, sock: socket.socket):
        self.sock, self.buf = sock, b""

    def packet(self) -> bytes:
        while len(self.buf) < 8 or len(self.buf) < struct.unpack_from("<i", self.buf)[0]:
            data = self.sock.recv(4096)
            assert data, "the tracker closed the connection"
            self.buf += data
        size = struct.unpack_from("<i", self.buf)[0]
        out, self.buf = self.buf[:size], self.buf[size:]
        return out

    def execute(self, command: int, fmt: str, values: tuple) -> tuple[bytes, bytes | None]:
        """(the *RT, the measurement result for StartMeasurement). A StartMeasurement refused in its *RT ends
        there (CommandSync would wait out its time-out for a result that cannot come)."""
        ct = struct.pack("<iii" + fmt, struct.calcsize("<iii" + fmt), ES_DT_COMMAND, command, *values)
        self.sock.sendall(ct)
        answer = None
        while True:
            p = self.packet()
            size, data_type = struct.unpack_from("<ii", p)
            assert data_type != ES_DT_ERROR, f"ErrorResponseT {struct.unpack_from('<ii', p, 8)} for {command}"
            if data_type == ES_DT_COMMAND and struct.unpack_from("<i", p, 8)[0] == command:
                if command != ES_C_START_MEASUREMENT or struct.unpack_from("<i", p, 12)[0] != ES_RS_ALL_OK:
                    return p, None
                answer = p
            elif data_type in (ES_DT_SINGLE_MEAS, ES_DT_SINGLE_MEAS2):
                assert answer is not None, "a result before the acknowledgement"
                return answer, p
            else:
                assert data_type in (ES_DT_SYSTEM_STATUS_CHANGE, ES_DT_REFLECTOR_POS), p


@pytest.fixture
def server():
    srv = MockEmscon(lambda expected: (*(expected or BIRD_BATH), 0.01, 0.01, 0.01), VirtualClock()).start()
    yield srv
    srv.stop()


def test_muffinspawn_sequence_is_answered_command_by_command(server):
    results: list[bytes] = []
    with socket.create_connection(server.address, timeout=5.0) as sock:
        client = CommandSync(sock)
        for command, name, fmt, values, rt in SEQUENCE:
            answer, result = client.execute(command, fmt, values)
            # the *RT of that command: BasicCommandRT {lPacketSize; type; command; status} + its payload
            assert len(answer) == struct.calcsize("<iiii" + rt), name
            status = struct.unpack_from("<i", answer, 12)[0]
            assert status in (ES_RS_ALL_OK, ES_RS_NOT_IMPLEMENTED), (name, status)
            if result is not None:
                results.append(result)
        assert server.connections_accepted == 1 and server.connections_dropped_on_garbage == 0

    standard, extended = results
    # standard statistic mode: SingleMeasResultT (156 bytes), values in ES_CS_SCC with mm and radians, which is
    # how command-example.py prints them: theta (rad), phi (rad), r (mm)
    assert len(standard) == struct.calcsize(SINGLE_MEAS) == 156
    _, data_type, status, meas_mode, try_mode, theta, phi, r = struct.unpack_from("<iiiiiddd", standard)
    assert (data_type, status, meas_mode, try_mode) == (ES_DT_SINGLE_MEAS, ES_RS_ALL_OK, 0, 0)
    assert r == pytest.approx(1500.0, rel=1e-12)  # |(1200, 900, 0)| = 1500 mm
    assert theta == pytest.approx(math.atan2(900.0, 1200.0), rel=1e-12)
    assert phi == pytest.approx(math.pi / 2, rel=1e-12)  # in the horizontal plane: 90 deg from the zenith
    # after SetStatisticMode(extended): SingleMeasResult2T, type 9, 204 bytes
    assert len(extended) == struct.calcsize(SINGLE_MEAS2) == 204
    assert struct.unpack_from("<ii", extended) == (204, ES_DT_SINGLE_MEAS2)
    assert struct.unpack_from("<d", extended, 36)[0] == pytest.approx(1500.0, rel=1e-12)  # dVal3


@pytest.mark.slow  # a process start; the same sequence runs against the mock server above in every `make test`
def test_muffinspawn_sequence_against_trackcal_mock(mock_cell):  # noqa: F811 (the imported fixture)
    """The same sequence against `trackcal mock` in its own process (the twin's tracker: no reflector on a nest
    and no station yet, so its measurements are refused with ES_RS_MeasurementStatusNotReady, 10004)."""
    _, hw = mock_cell
    tracker = load_hardware(hw).tracker
    with socket.create_connection((tracker["host"], tracker["port"]), timeout=5.0) as sock:
        client = CommandSync(sock)
        for command, name, fmt, values, rt in SEQUENCE:
            answer, _ = client.execute(command, fmt, values)
            assert len(answer) == struct.calcsize("<iiii" + rt), name
            assert struct.unpack_from("<i", answer, 12)[0] in (ES_RS_ALL_OK, ES_RS_NOT_IMPLEMENTED, 10004), name


def test_every_command_of_the_header_is_answered_in_its_own_answer_packet(server):
    """Every parameterless ES_Command of the header, one after the other on one connection: answered, never
    hung up on. Motion and measurement commands are left out: they need a set-up tracker."""
    no_parameters = [
        0,
        1,
        2,
        4,
        6,
        8,
        9,
        10,
        13,
        15,
        17,
        19,
        21,
        23,
        25,
        27,
        29,
        31,
        33,
        35,
        37,
        39,
        41,
        42,
        44,
        46,
        48,
        52,
        53,
        62,
        66,
        67,
        68,
        69,
        73,
        74,
        75,
        76,
        78,
        81,
        84,
        85,
        86,
        87,
        88,
        89,
        90,
        91,
        93,
        97,
        98,
        99,
        100,
        102,
        103,
        104,
        105,
        106,
        107,
        108,
        110,
        111,
        113,
        114,
        116,
        118,
        119,
        122,
        123,
        124,
        127,
        128,
        129,
        131,
        132,
        133,
        134,
        136,
        138,
        139,
        140,
        142,
    ]
    with socket.create_connection(server.address, timeout=5.0) as sock:
        client = CommandSync(sock)
        for command in no_parameters:
            answer, _ = client.execute(command, "", ())
            assert struct.unpack_from("<ii", answer) == (len(answer), ES_DT_COMMAND), command
    assert server.connections_dropped_on_garbage == 0
