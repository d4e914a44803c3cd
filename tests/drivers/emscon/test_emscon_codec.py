"""emScon TPI codec: golden byte vectors from the public header layouts, round trips, fuzzing.

Golden vectors are written by hand from the struct layouts and enum values of the Leica emScon TPI V3.6 header
(beckjac/emscon_ros include/emscon_ros/ES_C_API_Def.h, `#pragma pack(4)`, int32 `long`/enums as in
shohty/Leica_KEK CESAPI/packet.py), NOT from running the encoder: all integers little-endian int32, all
doubles IEEE-754 binary64 little-endian. The doubles are chosen exactly representable so that their bit
patterns can be written by hand:
    1000.0  = 1.953125 * 2**9  -> 0x408F400000000000      -500.0 = -1.953125 * 2**8 -> 0xC07F400000000000
    250.0   = 1.953125 * 2**7  -> 0x406F400000000000      2**-7 (7.8 um)            -> 0x3F80000000000000
    2**-6   -> 0x3F90000000000000                          2**-5                     -> 0x3FA0000000000000
    20.0    = 1.25 * 2**4      -> 0x4034000000000000      50.0 = 1.5625 * 2**5      -> 0x4049000000000000
    1013.25 = 0b1111110101.01 = 1.9790039 * 2**9          -> 0x408FAA0000000000
20 degC / 1013.25 hPa are the ISO 2533 standard-atmosphere sea-level values, 50 %RH a mid-range humidity; the
coordinates are a plausible reflector position a metre or so from the tracker; the standard deviations are of
the order of the AT901 accuracy (micrometres).
"""

from __future__ import annotations

import contextlib
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.drivers.emscon.enums import (
    ADMStatus,
    AngleUnit,
    Command,
    CoordinateSystemType,
    DataType,
    HumidityUnit,
    LaserProcessorStatus,
    LengthUnit,
    MeasMode,
    PressureUnit,
    ResultStatus,
    StatisticMode,
    SystemStatusChange,
    TemperatureUnit,
    TrackerProcessorStatus,
    TrackerStatus,
    WeatherMonitorStatus,
)
from trackcal.drivers.emscon.framing import (
    HEADER_SIZE,
    MAX_PACKET_BYTES,
    Direction,
    PacketReader,
    decode_packet,
    encode,
)
from trackcal.drivers.emscon.layouts import LAYOUTS
from trackcal.drivers.emscon.messages import (
    _ANSWER_STRUCTS,
    _REQUEST_STRUCTS,
    READBACK,
    REQUEST_TYPES,
    CommandAnswer,
    ErrorResponse,
    FindReflector,
    GetMeasurementStatusInfo,
    GetSystemSettings,
    GetSystemStatus,
    GetTrackerStatus,
    GetUnits,
    GoBirdBath,
    GoPosition,
    Initialize,
    MeasurementStatusInfoAnswer,
    ReflectorPosResult,
    SetCoordinateSystemType,
    SetEnvironmentParams,
    SetMeasurementMode,
    SetReflector,
    SetSearchParams,
    SetStationaryModeParams,
    SetStatisticMode,
    SetSystemSettings,
    SettingAnswer,
    SetUnits,
    SingleMeasResult,
    SingleMeasResult2,
    StartMeasurement,
    StatusChange,
    SystemStatusAnswer,
    TrackerStatusAnswer,
    encode_command,
    encode_refusal,
)
from trackcal.drivers.errors import ProtocolError

TO, FROM = Direction.TO_TRACKER, Direction.FROM_TRACKER


def h(text: str) -> bytes:
    return bytes.fromhex("".join(text.split()))


# Doubles, little-endian byte order of the bit patterns in the module docstring.
D_1000, D_M500, D_250 = "0000000000408f40", "0000000000407fc0", "0000000000406f40"
D_2M7, D_2M6, D_2M5, D_0 = "000000000000803f", "000000000000903f", "000000000000a03f", "00" * 8
D_20, D_1013_25, D_50 = "0000000000003440", "0000000000aa8f40", "0000000000004940"

# -------------------- golden vectors
GOLDEN_TO_TRACKER = [
    # StartMeasurementCT = BasicCommandCT {lPacketSize 12; type ES_DT_Command 0;
    #                                     command ES_C_StartMeasurement 49}
    (StartMeasurement(), h("0c000000 00000000 31000000")),
    # GoBirdBathCT {12; 0; ES_C_GoBirdBath 54 = 0x36}
    (GoBirdBath(), h("0c000000 00000000 36000000")),
    # SetEnvironmentParamsCT {36 = 0x24; 0; ES_C_SetEnvironmentParams 20 = 0x14; 20.0; 1013.25; 50.0}
    (SetEnvironmentParams(20.0, 1013.25, 50.0), h(f"24000000 00000000 14000000 {D_20} {D_1013_25} {D_50}")),
    # SetUnitsCT {32 = 0x20; 0; ES_C_SetUnits 5; ES_LU_Millimeter 1; ES_AU_Degree 1; ES_TU_Celsius 0;
    #             ES_PU_HPascal 1; ES_HU_RH 0}   (Enum.h)
    (SetUnits(), h("20000000 00000000 05000000 01000000 01000000 00000000 01000000 00000000")),
    # GoPositionCT {40 = 0x28; 0; ES_C_GoPosition 55 = 0x37; 1000.0; -500.0; 250.0; bUseADM TRUE = 1}
    (
        GoPosition(1000.0, -500.0, 250.0, True),
        h(f"28000000 00000000 37000000 {D_1000} {D_M500} {D_250} 01000000"),
    ),
    # FindReflectorCT {20 = 0x14; 0; ES_C_FindReflector 63 = 0x3f; dAproxDistance 1000.0}
    (FindReflector(1000.0), h(f"14000000 00000000 3f000000 {D_1000}")),
    # SetStationaryModeParamsCT {20; 0; ES_C_SetStationaryModeParams 28 = 0x1c; lMeasTime 1000 = 0x3e8;
    #                            bUseADM 0}
    (SetStationaryModeParams(1000, False), h("14000000 00000000 1c000000 e8030000 00000000")),
    # SetStatisticModeCT {20 = 0x14; 0; ES_C_SetStatisticMode 80 = 0x50; stationaryMeasurements ES_SM_Extended 1;
    #                     continuousMeasurements ES_SM_Standard 0}
    (
        SetStatisticMode(StatisticMode.EXTENDED, StatisticMode.STANDARD),
        h("14000000 00000000 50000000 01000000 00000000"),
    ),
    # SetSystemSettingsCT {48 = 0x30; 0; ES_C_SetSystemSettings 47 = 0x2f; SystemSettingsDataT {weatherMonitorStatus
    #   ES_WMS_ReadAndCalculateRefractions 2; bApplyTransformationParams 0; bApplyStationOrientationParams 1;
    #   bKeepLastPosition 1; bSendUnsolicitedMessages 1; bSendReflectorPositionData 0; bTryMeasurementMode 0;
    #   bHasNivel 1; bHasVideoCamera 1}}: the settings of MuffinSpawn/Leica bin/command-example.py
    (
        SetSystemSettings(
            WeatherMonitorStatus.READ_AND_CALCULATE_REFRACTIONS, False, True, True, True, False, False, True, True
        ),
        h(
            "30000000 00000000 2f000000 02000000 00000000 01000000 01000000 01000000 00000000 00000000"
            " 01000000 01000000"
        ),
    ),
    # GetUnitsCT {12; 0; ES_C_GetUnits 6}
    (GetUnits(), h("0c000000 00000000 06000000")),
]

GOLDEN_FROM_TRACKER = [
    # StartMeasurementRT = BasicCommandRT {16; ES_DT_Command 0; 49; ES_RS_AllOK 0}: the acknowledgement
    (CommandAnswer(Command.START_MEASUREMENT, ResultStatus.ALL_OK), h("10000000 00000000 31000000 00000000")),
    # ErrorResponseT {16; ES_DT_Error 1; ES_C_StartMeasurement 49; ES_RS_TrackerNotInitialized 39 = 0x27}
    (
        ErrorResponse(Command.START_MEASUREMENT, ResultStatus.TRACKER_NOT_INITIALIZED),
        h("10000000 01000000 31000000 27000000"),
    ),
    # ErrorResponseT {16; 1; 49; ES_RS_NoStationaryResult = ES_API_ERROR_OFFSET + 9 = 10009 = 0x2719}
    (
        ErrorResponse(Command.START_MEASUREMENT, ResultStatus.NO_STATIONARY_RESULT),
        h("10000000 01000000 31000000 19270000"),
    ),
    # SystemStatusChangeT {12; ES_DT_SystemStatusChange 8; ES_SSC_MeasStatus_NotReady 25 = 0x19}
    (StatusChange(SystemStatusChange.MEAS_STATUS_NOT_READY), h("0c000000 08000000 19000000")),
    # SingleMeasResultT {ReturnDataT {156 = 0x9c; ES_DT_SingleMeasResult 2; ES_RS_AllOK 0};
    #   measMode ES_MM_Stationary 0; bIsTryMode 0; dVal1..3; dStd1..3; dStdTotal; dPointingError1..3;
    #   dAprioriStd1..3; dAprioriStdTotal; dTemperature; dPressure; dHumidity}   12 + 8 + 17 * 8 = 156 bytes
    (
        SingleMeasResult(
            ResultStatus.ALL_OK,
            MeasMode.STATIONARY,
            False,
            1000.0,
            -500.0,
            250.0,
            2**-7,
            2**-7,
            2**-6,
            2**-5,
            0.0,
            0.0,
            0.0,
            2**-7,
            2**-7,
            2**-6,
            2**-5,
            20.0,
            1013.25,
            50.0,
        ),
        h(
            f"9c000000 02000000 00000000 00000000 00000000 {D_1000} {D_M500} {D_250}"
            f" {D_2M7} {D_2M7} {D_2M6} {D_2M5}"
            f" {D_0} {D_0} {D_0} {D_2M7} {D_2M7} {D_2M6} {D_2M5} {D_20} {D_1013_25} {D_50}"
        ),
    ),
    # GetTrackerStatusRT {20 = 0x14; 0; ES_C_GetTrackerStatus 2; ES_RS_AllOK 0; ES_TS_Ready 2}
    (
        TrackerStatusAnswer(ResultStatus.ALL_OK, TrackerStatus.READY),
        h("14000000 00000000 02000000 00000000 02000000"),
    ),
    # GetUnitsRT {BasicCommandRT {36 = 0x24; 0; ES_C_GetUnits 6; ES_RS_AllOK 0}; SystemUnitsDataT {ES_LU_Micron 2;
    #   ES_AU_Radian 0; ES_TU_Fahrenheit 1; ES_PU_Psi 4; ES_HU_RH 0}}
    (
        SettingAnswer(
            Command.GET_UNITS,
            ResultStatus.ALL_OK,
            SetUnits(LengthUnit.MICRON, AngleUnit.RADIAN, TemperatureUnit.FAHRENHEIT, PressureUnit.PSI),
        ),
        h("24000000 00000000 06000000 00000000 02000000 00000000 01000000 04000000 00000000"),
    ),
    # SingleMeasResult2T {ReturnDataT {204 = 0xcc; ES_DT_SingleMeasResult2 9; ES_RS_AllOK 0}; measMode 0;
    #   bIsTryMode 0; dVal1..3; dStd1..3; dStdTotal; dCovar12, 13, 23; dPointingErrorH, V, D; dAprioriStd1..3;
    #   dAprioriStdTotal; dAprioriCovar12, 13, 23; dTemperature; dPressure; dHumidity}   12 + 8 + 23 * 8 = 204
    (
        SingleMeasResult2(
            ResultStatus.ALL_OK,
            MeasMode.STATIONARY,
            False,
            1000.0,
            -500.0,
            250.0,
            2**-7,
            2**-7,
            2**-6,
            2**-5,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            2**-7,
            2**-7,
            2**-6,
            2**-5,
            0.0,
            0.0,
            0.0,
            20.0,
            1013.25,
            50.0,
        ),
        h(
            f"cc000000 09000000 00000000 00000000 00000000 {D_1000} {D_M500} {D_250}"
            f" {D_2M7} {D_2M7} {D_2M6} {D_2M5} {D_0} {D_0} {D_0} {D_0} {D_0} {D_0}"
            f" {D_2M7} {D_2M7} {D_2M6} {D_2M5} {D_0} {D_0} {D_0} {D_20} {D_1013_25} {D_50}"
        ),
    ),
]


@pytest.mark.parametrize(("message", "golden"), GOLDEN_TO_TRACKER, ids=lambda v: type(v).__name__)
def test_golden_requests(message, golden):
    assert encode_command(message) == golden
    assert decode_packet(golden, TO) == message


@pytest.mark.parametrize(("message", "golden"), GOLDEN_FROM_TRACKER, ids=lambda v: type(v).__name__)
def test_golden_answers(message, golden):
    assert encode(message) == golden
    assert decode_packet(golden, FROM) == message


def test_golden_sizes_match_header_layouts():
    # sizeof() of the structs under #pragma pack(4) with 32-bit long/enum/int and 64-bit double
    assert HEADER_SIZE == 8  # PacketHeaderT
    assert len(encode_command(Initialize())) == 12  # BasicCommandCT
    assert len(encode(CommandAnswer(Command.INITIALIZE, ResultStatus.ALL_OK))) == 16  # BasicCommandRT
    # GetSystemStatusRT: BasicCommandRT 16 + 4 enums + ESVersionNumberT (3 int) + enum + 2 long = 56
    answer = SystemStatusAnswer(
        ResultStatus.ALL_OK,
        ResultStatus.ALL_OK,
        TrackerProcessorStatus.INITIALIZED,
        LaserProcessorStatus.LASER_READY,
        ADMStatus.ADM_READY,
        (3, 6, 0),
        WeatherMonitorStatus.NOT_CONNECTED,
        0,
        0,
    )
    assert len(encode(answer)) == 56
    assert len(encode(ReflectorPosResult(ResultStatus.ALL_OK, 0.0, 0.0, 0.0))) == 12 + 3 * 8


def test_layout_table_sizes_from_the_header():
    # sizeof() of a few *RT structs of ES_C_API_Def.h worked out by hand (pack 4, 4-byte long/enum/ES_BOOL):
    # GetReflectorsRT: 16 + 3 * 4 + double 8 + unsigned short[32] 64 = 100
    assert LAYOUTS[42].answer_size == 100
    # GetTrackerInfoRT: 16 + enum 4 + name 64 + 2 long + 3 ES_BOOL 20 + 3 doubles 24 + 2 int 8 + 2 doubles 16
    #                   + enum + 2 int 12 = 164
    assert LAYOUTS[132].answer_size == 164
    # SetSystemSettingsCT: BasicCommandCT 12 + SystemSettingsDataT (enum + 8 ES_BOOL) 36 = 48
    assert LAYOUTS[47].request_size == 48
    assert set(LAYOUTS) == set(range(143)) - {50, 64, 141}  # every ES_Command value with structs


def test_codec_structs_agree_with_the_layout_table():
    for command, st_ in _REQUEST_STRUCTS.items():
        assert st_.size == LAYOUTS[command].request_size, command.name
    for command in Command:
        size = _ANSWER_STRUCTS[command].size if command in _ANSWER_STRUCTS else 16
        assert size == LAYOUTS[command].answer_size, command.name
    assert set(READBACK) <= set(_ANSWER_STRUCTS)


def test_full_size_refusals():
    # the *RT of ES_C_GetTrackerInfo (132 = 0x84), 164 = 0xa4 bytes, ES_RS_NotImplemented 2, zero payload
    assert encode_refusal(132, ResultStatus.NOT_IMPLEMENTED) == h("a4000000 00000000 84000000 02000000") + bytes(148)
    # an id that is no ES_Command (50 = 0x32): a bare BasicCommandRT
    assert encode_refusal(50, ResultStatus.NOT_IMPLEMENTED) == h("10000000 00000000 32000000 02000000")
    # a refused Get* of the subset decodes as its answer with the status and zero values
    refused = decode_packet(encode_refusal(Command.GET_SYSTEM_SETTINGS, ResultStatus.NOT_IMPLEMENTED))
    assert refused == SettingAnswer(
        Command.GET_SYSTEM_SETTINGS,
        ResultStatus.NOT_IMPLEMENTED,
        SetSystemSettings(WeatherMonitorStatus.NOT_CONNECTED, *([False] * 8)),
    )
    with pytest.raises(ValueError, match="payload"):
        encode_refusal(Command.GET_UNITS, ResultStatus.ALL_OK)
    with pytest.raises(ValueError):
        encode(SettingAnswer(Command.GET_UNITS, ResultStatus.ALL_OK, GetSystemSettings()))


def test_request_and_answer_of_same_size_need_the_direction():
    # SetReflectorCT {12 + int} and SetReflectorRT {12 + status} are both 16 bytes: only the direction tells.
    raw = encode_command(SetReflector(0))
    assert decode_packet(raw, TO) == SetReflector(0)
    assert decode_packet(raw, FROM) == CommandAnswer(Command.SET_REFLECTOR, ResultStatus.ALL_OK)


def test_short_error_answer_to_a_command_with_payload():
    raw = encode(CommandAnswer(Command.GET_SYSTEM_STATUS, ResultStatus.SERVER_BUSY))
    assert decode_packet(raw) == CommandAnswer(Command.GET_SYSTEM_STATUS, ResultStatus.SERVER_BUSY)
    with pytest.raises(ValueError):
        encode(CommandAnswer(Command.GET_SYSTEM_STATUS, ResultStatus.ALL_OK))
    ok_but_short = struct.pack("<iiii", 16, DataType.COMMAND, Command.GET_SYSTEM_STATUS, ResultStatus.ALL_OK)
    with pytest.raises(ProtocolError, match="payload"):
        decode_packet(ok_but_short)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_values_refused_both_ways(bad):
    with pytest.raises(ValueError):
        encode_command(GoPosition(bad, 0.0, 0.0))
    raw = bytearray(encode_command(GoPosition(1.0, 2.0, 3.0)))
    struct.pack_into("<d", raw, 12, bad)
    with pytest.raises(ProtocolError, match="non-finite"):
        decode_packet(bytes(raw), TO)


def test_out_of_range_integer_refused_by_encoder():
    with pytest.raises(ValueError):
        encode_command(SetReflector(2**31))


# -------------------- strategies
int32 = st.integers(-(2**31), 2**31 - 1)
finite = st.floats(allow_nan=False, allow_infinity=False)


def members(enum_cls):
    return st.sampled_from(list(enum_cls))


requests = st.one_of(
    st.sampled_from(
        [
            Initialize(),
            GetSystemStatus(),
            GetTrackerStatus(),
            GetMeasurementStatusInfo(),
            StartMeasurement(),
            GoBirdBath(),
        ]
    ),
    st.builds(
        SetUnits,
        members(LengthUnit),
        members(AngleUnit),
        members(TemperatureUnit),
        members(PressureUnit),
        members(HumidityUnit),
    ),
    st.builds(SetCoordinateSystemType, members(CoordinateSystemType)),
    st.builds(SetEnvironmentParams, finite, finite, finite),
    st.builds(SetReflector, int32),
    st.builds(SetMeasurementMode, members(MeasMode)),
    st.builds(SetStationaryModeParams, int32, st.booleans()),
    st.builds(SetSearchParams, finite, int32),
    st.builds(GoPosition, finite, finite, finite, st.booleans()),
    st.builds(FindReflector, finite),
    st.builds(SetStatisticMode, members(StatisticMode), members(StatisticMode)),
    st.builds(SetSystemSettings, members(WeatherMonitorStatus), *([st.booleans()] * 8)),
    st.sampled_from([cls() for cmd, cls in REQUEST_TYPES.items() if cmd.name.startswith("GET_")]),
)
statuses = members(ResultStatus)
from_tracker = st.one_of(
    st.builds(CommandAnswer, members(Command), statuses).filter(
        lambda a: not (a.status == ResultStatus.ALL_OK and a.command in _ANSWER_STRUCTS)
    ),
    st.sampled_from(list(READBACK.items())).flatmap(
        lambda item: st.builds(SettingAnswer, st.just(item[0]), statuses, requests.filter(lambda r: type(r) is item[1]))
    ),
    st.builds(
        SystemStatusAnswer,
        statuses,
        statuses,
        members(TrackerProcessorStatus),
        members(LaserProcessorStatus),
        members(ADMStatus),
        st.tuples(int32, int32, int32),
        members(WeatherMonitorStatus),
        int32,
        int32,
    ),
    st.builds(TrackerStatusAnswer, statuses, members(TrackerStatus)),
    st.builds(MeasurementStatusInfoAnswer, statuses, statuses, int32),
    st.builds(ErrorResponse, members(Command), statuses),
    st.builds(StatusChange, members(SystemStatusChange)),
    st.builds(SingleMeasResult, statuses, members(MeasMode), st.booleans(), *([finite] * 17)),
    st.builds(SingleMeasResult2, statuses, members(MeasMode), st.booleans(), *([finite] * 23)),
    st.builds(ReflectorPosResult, statuses, finite, finite, finite),
)
packets = st.one_of(requests.map(encode_command), from_tracker.map(encode))


# -------------------- properties
@given(requests)
def test_request_round_trip(request):
    assert decode_packet(encode_command(request), TO) == request


@given(from_tracker)
def test_answer_round_trip(message):
    raw = encode(message)
    assert struct.unpack_from("<i", raw)[0] == len(raw)
    assert decode_packet(raw, FROM) == message


def _decode_or_protocol_error(raw: bytes) -> None:
    for direction in (TO, FROM):
        with contextlib.suppress(ProtocolError):
            decode_packet(raw, direction)


@given(st.binary(max_size=300))
def test_decode_random_bytes_only_protocol_error(raw):
    _decode_or_protocol_error(raw)


@given(st.binary(min_size=HEADER_SIZE, max_size=200), st.sampled_from(list(DataType)))
def test_decode_random_body_with_plausible_header(body, data_type):
    raw = struct.pack("<ii", len(body), data_type) + body[HEADER_SIZE:]
    _decode_or_protocol_error(raw)


@given(packets, st.data())
def test_truncated_packets_rejected(raw, data):
    cut = data.draw(st.integers(0, len(raw) - 1))
    for direction in (TO, FROM):
        with pytest.raises(ProtocolError):
            decode_packet(raw[:cut], direction)


@given(packets, int32)
def test_wrong_length_field_rejected(raw, size):
    if size == len(raw):
        size += 1
    bad = struct.pack("<i", size) + raw[4:]
    for direction in (TO, FROM):
        with pytest.raises(ProtocolError):
            decode_packet(bad, direction)


@given(packets, int32)
def test_unknown_type_rejected(raw, type_value):
    if type_value in set(DataType):
        type_value = 12  # first value past ES_DT_ProbePosResult = 11
    bad = raw[:4] + struct.pack("<i", type_value) + raw[8:]
    for direction in (TO, FROM):
        with pytest.raises(ProtocolError, match="ES_DataType|DataType"):
            decode_packet(bad, direction)


@given(packets, int32)
def test_unknown_command_or_status_enum_rejected(raw, value):
    # offset 8 is the command of command/error packets, the status of results, the change of status changes
    valid = set(Command) | set(ResultStatus) | set(SystemStatusChange)
    if value in valid:
        value = -1
    bad = raw[:8] + struct.pack("<i", value) + raw[12:]
    for direction in (TO, FROM):
        with pytest.raises(ProtocolError):
            decode_packet(bad, direction)


@given(st.builds(SingleMeasResult, statuses, members(MeasMode), st.booleans(), *([finite] * 17)), int32)
def test_result_status_and_bool_fields_validated(result, value):
    raw = bytearray(encode(result))
    if value in set(ResultStatus):
        value = 100  # unused between ES_RS_NoTriggerBoard 99 and ES_API_ERROR_OFFSET + 1
    struct.pack_into("<i", raw, 8, value)
    with pytest.raises(ProtocolError):
        decode_packet(bytes(raw))
    raw = bytearray(encode(result))
    struct.pack_into("<i", raw, 16, 2 if value in (0, 1) else value)  # bIsTryMode must be 0 or 1
    with pytest.raises(ProtocolError, match="ES_BOOL"):
        decode_packet(bytes(raw))


# -------------------- framer
@given(st.lists(packets, max_size=8), st.data())
def test_framer_reassembles_any_chunking(raws, data):
    stream = b"".join(raws)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=20)))
    reader, got = PacketReader(), []
    for start, end in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        got += reader.feed(stream[start:end])
    assert got == raws
    assert reader.pending == 0


def test_framer_one_byte_at_a_time_and_several_per_read():
    a = encode_command(StartMeasurement())
    b = encode(StatusChange(SystemStatusChange.MEAS_STATUS_BUSY))
    reader = PacketReader()
    out = []
    for byte in a:
        out += reader.feed(bytes([byte]))
    assert out == [a]
    assert reader.feed(a + b + a[:5]) == [a, b]
    assert reader.pending == 5
    assert reader.feed(a[5:]) == [a]


@pytest.mark.parametrize("size", [-(2**31), -1, 0, HEADER_SIZE - 1, MAX_PACKET_BYTES + 1, 2**31 - 1])
def test_framer_rejects_absurd_sizes_before_buffering(size):
    reader = PacketReader()
    with pytest.raises(ProtocolError, match="lPacketSize"):
        reader.feed(struct.pack("<i", size))  # the size field alone is enough to refuse
    assert reader.pending == 0
    with pytest.raises(ProtocolError, match="out of sync"):
        reader.feed(encode_command(StartMeasurement()))


@settings(max_examples=200)
@given(st.lists(st.binary(max_size=64), max_size=20))
def test_framer_random_bytes_bounded(chunks):
    reader = PacketReader(max_packet_bytes=1024)
    for chunk in chunks:
        try:
            for packet in reader.feed(chunk):
                assert HEADER_SIZE <= len(packet) <= 1024
                _decode_or_protocol_error(packet)
        except ProtocolError:
            return
        assert reader.pending < 1024
