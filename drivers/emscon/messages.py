"""The messages of Leica emScon TPI, binary C variant: command requests (client -> tracker) and everything the
tracker sends (answers, errors, results, status changes), as dataclasses, with the struct layouts that encode and
decode them. Pure functions, no I/O; drivers/emscon/framing.py frames them and tells the two directions apart.

Sources (public copies of the Leica emScon TPI/SDK V3.6 headers and of open-source clients), read through the
project's code index; every struct layout below was written from them:

  [H]  beckjac/emscon_ros  include/emscon_ros/ES_C_API_Def.h   (full-featured V3.6 header): the structs
       PacketHeaderT, ReturnDataT, BasicCommandCT/RT, ErrorResponseT, SystemStatusChangeT, SingleMeasResultT,
       SingleMeasResult2T, ReflectorPosResultT, SystemUnitsDataT, SystemSettingsDataT, StationaryModeDataT and
       the *CT/*RT command structs used here.  `#pragma pack (push, 4)`: no padding before the doubles.
  [A]  MuffinSpawn/Leica  Include/ES_C_API_Def.h  (AT4xx extract of the same header; same layouts).
  [K]  shohty/Leica_KEK  CESAPI/packet.py  (CESAPI Python client): BasicCommandCT 12 bytes, BasicCommandRT 16
       bytes -- i.e. `long` is 32 bits on the wire (the header is written for MSVC, where long is 32 bits; [H]
       even `#define long int32_t` for this reason): every long, enum and ES_BOOL below is "i".
  [C]  MuffinSpawn/Leica  CESAPI/command.py: StartMeasurement is answered by the command acknowledgement and
       then a separate ES_DT_SingleMeasResult packet, or an ES_DT_SingleMeasResult2 one (it accepts both);
       ES_DT_Error packets (ErrorResponseT) report a failed command.
  [L]  drivers/emscon/layouts.py: the CT/RT layout of every ES_Command of [H], for the sizes of answers to
       commands outside the subset decoded here.

A refusal (a status other than ES_RS_AllOK) comes in one of two forms, and [H] gives the layouts, not which
one a server sends: just BasicCommandRT's 16 bytes (a CommandAnswer), or the full *RT of that command with a
zeroed payload (`encode_refusal`; it decodes as that command's answer with zero values), which a client that
unpacks the fixed struct of each answer can read. Both decode.

Command requests and their answers share ES_DT_Command and the command id and are told apart only by direction
(e.g. SetReflectorCT and SetReflectorRT are both 16 bytes): `decode_request` reads the one, `decode_from_tracker`
the other. Sizes are checked exactly against the struct layouts. Every struct starts with PacketHeaderT (see
framing.py), so the packed bytes are whole packets.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass, fields
from typing import ClassVar

from trackcal.drivers.emscon.enums import (
    ADMStatus,
    AngleUnit,
    Command,
    CoordinateSystemType,
    DataType,
    HumidityUnit,
    LaserProcessorStatus,
    LengthUnit,
    LTSensorType,
    MeasMode,
    PressureUnit,
    ResultStatus,
    StatisticMode,
    SystemStatusChange,
    TemperatureUnit,
    TrackerProcessorStatus,
    TrackerStatus,
    TrkAccuracyModel,
    WeatherMonitorStatus,
    enum_value,
)
from trackcal.drivers.emscon.layouts import LAYOUTS
from trackcal.drivers.errors import ProtocolError


# -------------------- validation helpers
def _bool(value: int, what: str) -> bool:
    if value not in (0, 1):
        raise ProtocolError(f"{what}: ES_BOOL must be 0 or 1, got {value}")
    return bool(value)


def _finite(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise ProtocolError(f"{what}: non-finite double {value!r}")
    return value


def _check_finite_out(values: tuple, what: str) -> None:
    for v in values:
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{what}: cannot encode the non-finite value {v!r}")


# -------------------- requests (client -> tracker)
_CT_PREFIX = "<iii"  # BasicCommandCT {PacketHeaderT; ES_Command command}
_RT_PREFIX = "<iiii"  # BasicCommandRT {PacketHeaderT; ES_Command command; ES_ResultStatus status}


@dataclass(frozen=True)
class Request:
    """Base of the command requests. Subclasses set COMMAND and PAYLOAD.

    PAYLOAD is the struct format of what follows BasicCommandCT; the dataclass fields are its values in order.
    """

    COMMAND: ClassVar[Command]
    PAYLOAD: ClassVar[str] = ""

    def payload(self) -> tuple:
        return tuple(
            int(v) if isinstance(v, bool | enum.IntEnum) else v for v in (getattr(self, f.name) for f in fields(self))
        )

    @classmethod
    def from_payload(cls, values: tuple) -> Request:
        return cls(*values)


@dataclass(frozen=True)
class Initialize(Request):  # InitializeCT
    COMMAND: ClassVar[Command] = Command.INITIALIZE


@dataclass(frozen=True)
class GetSystemStatus(Request):  # GetSystemStatusCT
    COMMAND: ClassVar[Command] = Command.GET_SYSTEM_STATUS


@dataclass(frozen=True)
class GetTrackerInfo(Request):  # GetTrackerInfoCT: the tracker's type, name, serial number, LCP firmware
    COMMAND: ClassVar[Command] = Command.GET_TRACKER_INFO


@dataclass(frozen=True)
class GetSystemSoftwareVersion(Request):  # GetSystemSoftwareVersionCT (TPI V3.6): the server's software version
    COMMAND: ClassVar[Command] = Command.GET_SYSTEM_SOFTWARE_VERSION


@dataclass(frozen=True)
class GetTrackerStatus(Request):  # GetTrackerStatusCT
    COMMAND: ClassVar[Command] = Command.GET_TRACKER_STATUS


@dataclass(frozen=True)
class GetMeasurementStatusInfo(Request):  # GetMeasurementStatusInfoCT
    COMMAND: ClassVar[Command] = Command.GET_MEASUREMENT_STATUS_INFO


@dataclass(frozen=True)
class StartMeasurement(Request):  # StartMeasurementCT
    COMMAND: ClassVar[Command] = Command.START_MEASUREMENT


@dataclass(frozen=True)
class GoBirdBath(Request):  # GoBirdBathCT
    COMMAND: ClassVar[Command] = Command.GO_BIRD_BATH


@dataclass(frozen=True)
class SetUnits(Request):  # SetUnitsCT {BasicCommandCT; SystemUnitsDataT {5 enums}}
    COMMAND: ClassVar[Command] = Command.SET_UNITS
    PAYLOAD: ClassVar[str] = "iiiii"
    length: LengthUnit = LengthUnit.MILLIMETER
    angle: AngleUnit = AngleUnit.DEGREE
    temperature: TemperatureUnit = TemperatureUnit.CELSIUS
    pressure: PressureUnit = PressureUnit.HPASCAL
    humidity: HumidityUnit = HumidityUnit.RH

    @classmethod
    def from_payload(cls, values: tuple) -> SetUnits:
        lu, au, tu, pu, hu = values
        return cls(
            enum_value(LengthUnit, lu, "SetUnits.lenUnitType"),
            enum_value(AngleUnit, au, "SetUnits.angUnitType"),
            enum_value(TemperatureUnit, tu, "SetUnits.tempUnitType"),
            enum_value(PressureUnit, pu, "SetUnits.pressUnitType"),
            enum_value(HumidityUnit, hu, "SetUnits.humUnitType"),
        )


@dataclass(frozen=True)
class SetCoordinateSystemType(Request):  # SetCoordinateSystemTypeCT {BasicCommandCT; enum coordSysType}
    COMMAND: ClassVar[Command] = Command.SET_COORDINATE_SYSTEM_TYPE
    PAYLOAD: ClassVar[str] = "i"
    coordinate_system: CoordinateSystemType = CoordinateSystemType.RHR

    @classmethod
    def from_payload(cls, values: tuple) -> SetCoordinateSystemType:
        return cls(enum_value(CoordinateSystemType, values[0], "SetCoordinateSystemType.coordSysType"))


@dataclass(frozen=True)
class SetEnvironmentParams(Request):  # SetEnvironmentParamsCT {BasicCommandCT; EnvironmentDataT {3 doubles}}
    COMMAND: ClassVar[Command] = Command.SET_ENVIRONMENT_PARAMS
    PAYLOAD: ClassVar[str] = "ddd"
    temperature: float
    pressure: float
    humidity: float

    @classmethod
    def from_payload(cls, values: tuple) -> SetEnvironmentParams:
        t, p, h = (
            _finite(v, f"SetEnvironmentParams.{n}")
            for v, n in zip(values, ("dTemperature", "dPressure", "dHumidity"), strict=True)
        )
        return cls(t, p, h)


@dataclass(frozen=True)
class SetReflector(Request):  # SetReflectorCT {BasicCommandCT; int iInternalReflectorId}
    COMMAND: ClassVar[Command] = Command.SET_REFLECTOR
    PAYLOAD: ClassVar[str] = "i"
    reflector_id: int


@dataclass(frozen=True)
class SetMeasurementMode(Request):  # SetMeasurementModeCT {BasicCommandCT; enum ES_MeasMode measMode}
    COMMAND: ClassVar[Command] = Command.SET_MEASUREMENT_MODE
    PAYLOAD: ClassVar[str] = "i"
    mode: MeasMode = MeasMode.STATIONARY

    @classmethod
    def from_payload(cls, values: tuple) -> SetMeasurementMode:
        return cls(enum_value(MeasMode, values[0], "SetMeasurementMode.measMode"))


@dataclass(frozen=True)
class SetStationaryModeParams(Request):  # SetStationaryModeParamsCT {BasicCommandCT; {long lMeasTime; ES_BOOL bUseADM}}
    COMMAND: ClassVar[Command] = Command.SET_STATIONARY_MODE_PARAMS
    PAYLOAD: ClassVar[str] = "ii"
    meas_time_ms: int  # lMeasTime; unit not stated in the header, taken as milliseconds (see the driver)
    use_adm: bool = False

    @classmethod
    def from_payload(cls, values: tuple) -> SetStationaryModeParams:
        return cls(values[0], _bool(values[1], "SetStationaryModeParams.bUseADM"))


@dataclass(frozen=True)
class SetSearchParams(Request):  # SetSearchParamsCT {BasicCommandCT; {double dSearchRadius; long lTimeOut /*ms*/}}
    COMMAND: ClassVar[Command] = Command.SET_SEARCH_PARAMS
    PAYLOAD: ClassVar[str] = "di"
    search_radius: float
    timeout_ms: int

    @classmethod
    def from_payload(cls, values: tuple) -> SetSearchParams:
        return cls(_finite(values[0], "SetSearchParams.dSearchRadius"), values[1])


@dataclass(frozen=True)
class GoPosition(Request):  # GoPositionCT {BasicCommandCT; double dVal1, dVal2, dVal3; ES_BOOL bUseADM}
    COMMAND: ClassVar[Command] = Command.GO_POSITION
    PAYLOAD: ClassVar[str] = "dddi"
    x: float
    y: float
    z: float
    use_adm: bool = True

    @classmethod
    def from_payload(cls, values: tuple) -> GoPosition:
        x, y, z = (_finite(v, f"GoPosition.dVal{i + 1}") for i, v in enumerate(values[:3]))
        return cls(x, y, z, _bool(values[3], "GoPosition.bUseADM"))


@dataclass(frozen=True)
class FindReflector(Request):  # FindReflectorCT {BasicCommandCT; double dAproxDistance}
    COMMAND: ClassVar[Command] = Command.FIND_REFLECTOR
    PAYLOAD: ClassVar[str] = "d"
    approx_distance: float

    @classmethod
    def from_payload(cls, values: tuple) -> FindReflector:
        return cls(_finite(values[0], "FindReflector.dAproxDistance"))


@dataclass(frozen=True)
class SetSystemSettings(Request):  # SetSystemSettingsCT {BasicCommandCT; SystemSettingsDataT {enum; 8 ES_BOOL}}
    COMMAND: ClassVar[Command] = Command.SET_SYSTEM_SETTINGS
    PAYLOAD: ClassVar[str] = "iiiiiiiii"
    weather_monitor: WeatherMonitorStatus  # weatherMonitorStatus
    apply_transformation: bool  # bApplyTransformationParams: results in the user's transformed frame
    apply_station_orientation: bool  # bApplyStationOrientationParams
    keep_last_position: bool  # bKeepLastPosition: the beam stays where it was when it is broken
    send_unsolicited_messages: bool  # bSendUnsolicitedMessages
    send_reflector_position: bool  # bSendReflectorPositionData: ReflectorPosResultT while locked
    try_mode: bool  # bTryMeasurementMode: every result delivered in try mode
    has_nivel: bool  # bHasNivel
    has_video_camera: bool  # bHasVideoCamera

    @classmethod
    def from_payload(cls, values: tuple) -> SetSystemSettings:
        names = [f.name for f in fields(cls)]
        flags = (_bool(v, f"SystemSettingsDataT.{n}") for v, n in zip(values[1:], names[1:], strict=True))
        return cls(enum_value(WeatherMonitorStatus, values[0], "SystemSettingsDataT.weatherMonitorStatus"), *flags)


@dataclass(frozen=True)
class SetStatisticMode(Request):  # SetStatisticModeCT {BasicCommandCT; ES_StatisticMode stationary, continuous}
    COMMAND: ClassVar[Command] = Command.SET_STATISTIC_MODE
    PAYLOAD: ClassVar[str] = "ii"
    stationary: StatisticMode = StatisticMode.STANDARD
    continuous: StatisticMode = StatisticMode.STANDARD

    @classmethod
    def from_payload(cls, values: tuple) -> SetStatisticMode:
        return cls(
            enum_value(StatisticMode, values[0], "SetStatisticMode.stationaryMeasurements"),
            enum_value(StatisticMode, values[1], "SetStatisticMode.continuousMeasurements"),
        )


@dataclass(frozen=True)
class GetUnits(Request):  # GetUnitsCT
    COMMAND: ClassVar[Command] = Command.GET_UNITS


@dataclass(frozen=True)
class GetMeasurementMode(Request):  # GetMeasurementModeCT
    COMMAND: ClassVar[Command] = Command.GET_MEASUREMENT_MODE


@dataclass(frozen=True)
class GetCoordinateSystemType(Request):  # GetCoordinateSystemTypeCT
    COMMAND: ClassVar[Command] = Command.GET_COORDINATE_SYSTEM_TYPE


@dataclass(frozen=True)
class GetStationaryModeParams(Request):  # GetStationaryModeParamsCT
    COMMAND: ClassVar[Command] = Command.GET_STATIONARY_MODE_PARAMS


@dataclass(frozen=True)
class GetSystemSettings(Request):  # GetSystemSettingsCT
    COMMAND: ClassVar[Command] = Command.GET_SYSTEM_SETTINGS


@dataclass(frozen=True)
class GetStatisticMode(Request):  # GetStatisticModeCT
    COMMAND: ClassVar[Command] = Command.GET_STATISTIC_MODE


REQUEST_TYPES: dict[Command, type[Request]] = {
    cls.COMMAND: cls
    for cls in (
        Initialize,
        GetSystemStatus,
        GetTrackerStatus,
        GetTrackerInfo,
        GetSystemSoftwareVersion,
        GetMeasurementStatusInfo,
        StartMeasurement,
        GoBirdBath,
        SetUnits,
        SetCoordinateSystemType,
        SetEnvironmentParams,
        SetReflector,
        SetMeasurementMode,
        SetStationaryModeParams,
        SetSearchParams,
        GoPosition,
        FindReflector,
        SetSystemSettings,
        SetStatisticMode,
        GetUnits,
        GetMeasurementMode,
        GetCoordinateSystemType,
        GetStationaryModeParams,
        GetSystemSettings,
        GetStatisticMode,
    )
}
# Get*RT of a setting carries the payload of the matching Set*CT ([H]: SystemUnitsDataT, coordSysType, measMode,
# StationaryModeDataT, SystemSettingsDataT, the two ES_StatisticMode), so it is read as that request.
READBACK: dict[Command, type[Request]] = {
    Command.GET_UNITS: SetUnits,
    Command.GET_COORDINATE_SYSTEM_TYPE: SetCoordinateSystemType,
    Command.GET_MEASUREMENT_MODE: SetMeasurementMode,
    Command.GET_STATIONARY_MODE_PARAMS: SetStationaryModeParams,
    Command.GET_SYSTEM_SETTINGS: SetSystemSettings,
    Command.GET_STATISTIC_MODE: SetStatisticMode,
}
_REQUEST_STRUCTS = {cmd: struct.Struct(_CT_PREFIX + cls.PAYLOAD) for cmd, cls in REQUEST_TYPES.items()}


# -------------------- answers (tracker -> client)
@dataclass(frozen=True)
class CommandAnswer:
    """BasicCommandRT: the answer to a command whose *RT adds nothing, or a short answer carrying an error."""

    command: Command
    status: ResultStatus


@dataclass(frozen=True)
class SystemStatusAnswer:
    """GetSystemStatusRT."""

    status: ResultStatus
    last_result_status: ResultStatus
    tracker_processor_status: TrackerProcessorStatus
    laser_status: LaserProcessorStatus
    adm_status: ADMStatus
    version: tuple[int, int, int]  # ESVersionNumberT {major, minor, build}
    weather_monitor_status: WeatherMonitorStatus
    flags: int  # lFlagsValue
    tracker_serial_number: int  # lTrackerSerialNumber
    command: ClassVar[Command] = Command.GET_SYSTEM_STATUS


@dataclass(frozen=True)
class TrackerStatusAnswer:
    """GetTrackerStatusRT."""

    status: ResultStatus
    tracker_status: TrackerStatus
    command: ClassVar[Command] = Command.GET_TRACKER_STATUS


@dataclass(frozen=True)
class TrackerInfoAnswer:
    """GetTrackerInfoRT [H]: what the tracker says it is (its identity on a certificate: type, name, serial number,
    LCP firmware), and its features."""

    status: ResultStatus
    tracker_type: LTSensorType  # trackerType
    tracker_name: str  # cTrackerName[32], a UNICODE string (see unicode_field)
    serial_number: int  # lSerialNumber
    compensation_id: int  # lCompensationIdNumber: identifies the compensation
    has_adm: bool  # bHasADM
    has_overview_camera: bool  # bHasOverviewCamera
    has_nivel: bool  # bHasNivel
    nivel_mount_offset: float  # dNivelMountOffset
    max_distance: float  # dMaxDistance: the laser's maximal distance (length unit set)
    min_distance: float  # dMinDistance
    max_data_rate: int  # iMaxDataRate: measurements per second
    faces: int  # iNumberOfFaces
    hz_angle_range: float  # dHzAngleRange, e.g. +/- 240
    vt_angle_range: float  # dVtAngleRange
    accuracy_model: TrkAccuracyModel  # accuracyModel
    lcp_firmware: tuple[int, int]  # iMajLCPFirmwareVersion, iMinLCPFirmwareVersion
    command: ClassVar[Command] = Command.GET_TRACKER_INFO


@dataclass(frozen=True)
class SoftwareVersionAnswer:
    """GetSystemSoftwareVersionRT [H] (TPI V3.6): the emScon server's software version, a UNICODE string."""

    status: ResultStatus
    version: str  # cSoftwareVersion[32]
    command: ClassVar[Command] = Command.GET_SYSTEM_SOFTWARE_VERSION


@dataclass(frozen=True)
class MeasurementStatusInfoAnswer:
    """GetMeasurementStatusInfoRT {BasicCommandRT; ES_ResultStatus lastResultStatus;
    long lMeasurementStatusInfo}"""

    status: ResultStatus
    last_result_status: ResultStatus
    info: int  # ES_MeasurementStatusInfo bit flags
    command: ClassVar[Command] = Command.GET_MEASUREMENT_STATUS_INFO


@dataclass(frozen=True)
class SettingAnswer:
    """Get*RT of a setting (READBACK): the setting as the Set* request that would set it."""

    command: Command
    status: ResultStatus
    setting: Request


@dataclass(frozen=True)
class ErrorResponse:
    """ErrorResponseT (type ES_DT_Error): the command that failed and why."""

    command: Command
    status: ResultStatus


@dataclass(frozen=True)
class StatusChange:
    """SystemStatusChangeT (type ES_DT_SystemStatusChange), sent by the tracker at any time."""

    change: SystemStatusChange


@dataclass(frozen=True)
class SingleMeasResult:
    """SingleMeasResultT (type ES_DT_SingleMeasResult): the result of a stationary measurement.

    Values are in the units and coordinate system type set with SetUnits / SetCoordinateSystemType.
    """

    status: ResultStatus
    meas_mode: MeasMode
    is_try_mode: bool
    val1: float
    val2: float
    val3: float
    std1: float
    std2: float
    std3: float
    std_total: float
    pointing_error1: float
    pointing_error2: float
    pointing_error3: float
    apriori_std1: float
    apriori_std2: float
    apriori_std3: float
    apriori_std_total: float
    temperature: float
    pressure: float
    humidity: float


@dataclass(frozen=True)
class SingleMeasResult2:
    """SingleMeasResult2T (type ES_DT_SingleMeasResult2): a stationary result in the extended statistic mode
    (ES_SM_Extended), with the covariances of the result and of its a-priori accuracy."""

    status: ResultStatus
    meas_mode: MeasMode
    is_try_mode: bool
    val1: float
    val2: float
    val3: float
    std1: float
    std2: float
    std3: float
    std_total: float
    covar12: float
    covar13: float
    covar23: float
    pointing_error_h: float
    pointing_error_v: float
    pointing_error_d: float
    apriori_std1: float
    apriori_std2: float
    apriori_std3: float
    apriori_std_total: float
    apriori_covar12: float
    apriori_covar13: float
    apriori_covar23: float
    temperature: float
    pressure: float
    humidity: float


@dataclass(frozen=True)
class ReflectorPosResult:
    """ReflectorPosResultT (type ES_DT_ReflectorPosResult): unsolicited position while locked (if enabled)."""

    status: ResultStatus
    val1: float
    val2: float
    val3: float


Answer = (
    CommandAnswer
    | SystemStatusAnswer
    | TrackerStatusAnswer
    | MeasurementStatusInfoAnswer
    | SettingAnswer
    | TrackerInfoAnswer
    | SoftwareVersionAnswer
)
ANSWER_TYPES = (
    CommandAnswer,
    SystemStatusAnswer,
    TrackerStatusAnswer,
    MeasurementStatusInfoAnswer,
    SettingAnswer,
    TrackerInfoAnswer,
    SoftwareVersionAnswer,
)
MeasResult = SingleMeasResult | SingleMeasResult2
FromTracker = Answer | ErrorResponse | StatusChange | MeasResult | ReflectorPosResult
Message = Request | FromTracker

_BASIC_RT = struct.Struct(_RT_PREFIX)  # 16
_SYSTEM_STATUS_RT = struct.Struct(_RT_PREFIX + "iiii" + "iii" + "iii")  # 56
_TRACKER_STATUS_RT = struct.Struct(_RT_PREFIX + "i")  # 20
_MEAS_STATUS_INFO_RT = struct.Struct(_RT_PREFIX + "ii")  # 24
# GetTrackerInfoRT: trackerType; cTrackerName[32]; 2 long; 3 ES_BOOL; 3 double; 2 int; 2 double; enum; 2 int = 164
_TRACKER_INFO_RT = struct.Struct(_RT_PREFIX + "i32H" + "iiiii" + "ddd" + "ii" + "dd" + "iii")
_SOFTWARE_VERSION_RT = struct.Struct(_RT_PREFIX + "32H")  # GetSystemSoftwareVersionRT: cSoftwareVersion[32] = 80
UNICODE_UNITS = 32  # unsigned short c...[32]: 32 UTF-16 code units, the last one the terminating 0 when full
_ERROR = struct.Struct("<iiii")  # ErrorResponseT, 16
_STATUS_CHANGE = struct.Struct("<iii")  # SystemStatusChangeT, 12
_SINGLE_MEAS = struct.Struct("<iii" + "ii" + "d" * 17)  # SingleMeasResultT, 156
_SINGLE_MEAS2 = struct.Struct("<iii" + "ii" + "d" * 23)  # SingleMeasResult2T, 204
_REFLECTOR_POS = struct.Struct("<iii" + "ddd")  # ReflectorPosResultT, 36
_ANSWER_STRUCTS: dict[Command, struct.Struct] = {
    Command.GET_SYSTEM_STATUS: _SYSTEM_STATUS_RT,
    Command.GET_TRACKER_STATUS: _TRACKER_STATUS_RT,
    Command.GET_MEASUREMENT_STATUS_INFO: _MEAS_STATUS_INFO_RT,
    Command.GET_TRACKER_INFO: _TRACKER_INFO_RT,
    Command.GET_SYSTEM_SOFTWARE_VERSION: _SOFTWARE_VERSION_RT,
    **{cmd: struct.Struct(_RT_PREFIX + cls.PAYLOAD) for cmd, cls in READBACK.items()},
}
_MEAS_TYPES: dict[type, tuple[DataType, struct.Struct]] = {
    SingleMeasResult: (DataType.SINGLE_MEAS_RESULT, _SINGLE_MEAS),
    SingleMeasResult2: (DataType.SINGLE_MEAS_RESULT2, _SINGLE_MEAS2),
}
_MEAS_FLOATS = {cls: tuple(f.name for f in fields(cls))[3:] for cls in _MEAS_TYPES}


# -------------------- UNICODE strings
def unicode_units(text: str, what: str) -> tuple[int, ...]:
    """`text` as an `unsigned short c...[32]` UNICODE string: UTF-16 code units (the header is written for MSVC, where
    a UNICODE string is UTF-16 and the wire little-endian like every other field [H]), 0-terminated and 0-padded to
    32 units; at most 31 units of text, so a C reader always finds the terminator."""
    data = text.encode("utf-16-le")
    units = struct.unpack(f"<{len(data) // 2}H", data)
    if len(units) >= UNICODE_UNITS or 0 in units:
        raise ValueError(f"{what}: {text!r} does not fit a {UNICODE_UNITS}-unit UNICODE string (31 units, no NUL)")
    return units + (0,) * (UNICODE_UNITS - len(units))


def unicode_field(units: tuple[int, ...], what: str) -> str:
    """The text of a UNICODE string field: its units up to the first 0 (all 32 if none), read as UTF-16; a lone
    surrogate is a ProtocolError."""
    end = units.index(0) if 0 in units else len(units)
    try:
        return struct.pack(f"<{end}H", *units[:end]).decode("utf-16-le")
    except UnicodeDecodeError as exc:
        raise ProtocolError(f"{what}: not a UTF-16 string ({exc.reason})") from None


# -------------------- encode
def _pack(st: struct.Struct, *values) -> bytes:
    _check_finite_out(values, "encode")
    try:
        return st.pack(*values)
    except struct.error as exc:
        raise ValueError(f"cannot encode {values!r}: {exc}") from None


def encode_command(request: Request) -> bytes:
    """The bytes of one command request (client -> tracker)."""
    st = _REQUEST_STRUCTS[request.COMMAND]
    return _pack(st, st.size, DataType.COMMAND, request.COMMAND, *request.payload())


def encode_refusal(command_id: int, status: ResultStatus) -> bytes:
    """The answer (*RT) to any command id with `status` and a zeroed payload, as long as that command's *RT is
    in [H] (LAYOUTS); a bare BasicCommandRT for an id that is no ES_Command. ALL_OK only where the *RT has
    no payload."""
    layout = LAYOUTS.get(command_id)
    size = layout.answer_size if layout is not None else _BASIC_RT.size
    if status == ResultStatus.ALL_OK and size != _BASIC_RT.size:
        raise ValueError(f"an ALL_OK answer to command {command_id} carries a payload: use its own type")
    return _pack(_BASIC_RT, size, DataType.COMMAND, command_id, status) + bytes(size - _BASIC_RT.size)


def encode_from_tracker(message: FromTracker) -> bytes:
    """The bytes of anything the tracker sends (tracker -> client)."""
    if isinstance(message, CommandAnswer):
        if message.command in _ANSWER_STRUCTS and message.status == ResultStatus.ALL_OK:
            raise ValueError(f"an ALL_OK answer to {message.command.name} carries a payload: use its own type")
        return _pack(_BASIC_RT, _BASIC_RT.size, DataType.COMMAND, message.command, message.status)
    if isinstance(message, SettingAnswer):
        m = message
        if type(m.setting) is not READBACK.get(m.command):
            raise ValueError(f"{type(m.setting).__name__} is not what {m.command.name} answers")
        st = _ANSWER_STRUCTS[m.command]
        return _pack(st, st.size, DataType.COMMAND, m.command, m.status, *m.setting.payload())
    if isinstance(message, SystemStatusAnswer):
        m, st = message, _SYSTEM_STATUS_RT
        return _pack(
            st,
            st.size,
            DataType.COMMAND,
            m.command,
            m.status,
            m.last_result_status,
            m.tracker_processor_status,
            m.laser_status,
            m.adm_status,
            *m.version,
            m.weather_monitor_status,
            m.flags,
            m.tracker_serial_number,
        )
    if isinstance(message, TrackerInfoAnswer):
        return _encode_tracker_info(message)
    if isinstance(message, SoftwareVersionAnswer):
        m, st = message, _SOFTWARE_VERSION_RT
        units = unicode_units(m.version, "GetSystemSoftwareVersion.cSoftwareVersion")
        return _pack(st, st.size, DataType.COMMAND, m.command, m.status, *units)
    if isinstance(message, TrackerStatusAnswer):
        st = _TRACKER_STATUS_RT
        return _pack(st, st.size, DataType.COMMAND, message.command, message.status, message.tracker_status)
    if isinstance(message, MeasurementStatusInfoAnswer):
        m, st = message, _MEAS_STATUS_INFO_RT
        return _pack(st, st.size, DataType.COMMAND, m.command, m.status, m.last_result_status, m.info)
    if isinstance(message, ErrorResponse):
        return _pack(_ERROR, _ERROR.size, DataType.ERROR, message.command, message.status)
    if isinstance(message, StatusChange):
        return _pack(_STATUS_CHANGE, _STATUS_CHANGE.size, DataType.SYSTEM_STATUS_CHANGE, message.change)
    if isinstance(message, SingleMeasResult | SingleMeasResult2):
        m = message
        data_type, st = _MEAS_TYPES[type(m)]
        floats = tuple(getattr(m, n) for n in _MEAS_FLOATS[type(m)])
        return _pack(st, st.size, data_type, m.status, m.meas_mode, int(m.is_try_mode), *floats)
    if isinstance(message, ReflectorPosResult):
        m = message
        return _pack(
            _REFLECTOR_POS,
            _REFLECTOR_POS.size,
            DataType.REFLECTOR_POS_RESULT,
            m.status,
            m.val1,
            m.val2,
            m.val3,
        )
    raise TypeError(f"not an emScon message: {message!r}")


def _encode_tracker_info(m: TrackerInfoAnswer) -> bytes:
    st = _TRACKER_INFO_RT
    name = unicode_units(m.tracker_name, "GetTrackerInfo.cTrackerName")
    return _pack(
        st,
        st.size,
        DataType.COMMAND,
        m.command,
        m.status,
        m.tracker_type,
        *name,
        m.serial_number,
        m.compensation_id,
        int(m.has_adm),
        int(m.has_overview_camera),
        int(m.has_nivel),
        m.nivel_mount_offset,
        m.max_distance,
        m.min_distance,
        m.max_data_rate,
        m.faces,
        m.hz_angle_range,
        m.vt_angle_range,
        m.accuracy_model,
        *m.lcp_firmware,
    )


def _decode_tracker_info(status: ResultStatus, v: tuple) -> TrackerInfoAnswer:
    """GetTrackerInfoRT from the values after BasicCommandRT."""
    w = "GetTrackerInfo"
    doubles = [
        _finite(x, f"{w}.{n}")
        for x, n in zip(v[38:41], ("dNivelMountOffset", "dMaxDistance", "dMinDistance"), strict=True)
    ]
    ranges = [_finite(x, f"{w}.{n}") for x, n in zip(v[43:45], ("dHzAngleRange", "dVtAngleRange"), strict=True)]
    return TrackerInfoAnswer(
        status,
        enum_value(LTSensorType, v[0], f"{w}.trackerType"),
        unicode_field(v[1:33], f"{w}.cTrackerName"),
        v[33],
        v[34],
        _bool(v[35], f"{w}.bHasADM"),
        _bool(v[36], f"{w}.bHasOverviewCamera"),
        _bool(v[37], f"{w}.bHasNivel"),
        *doubles,
        v[41],
        v[42],
        *ranges,
        enum_value(TrkAccuracyModel, v[45], f"{w}.accuracyModel"),
        (v[46], v[47]),
    )


# -------------------- decode
def _expect_size(buf: bytes, st: struct.Struct, what: str) -> tuple:
    if len(buf) != st.size:
        raise ProtocolError(f"{what}: packet of {len(buf)} bytes, the layout needs exactly {st.size}")
    return st.unpack(buf)


def decode_request(buf: bytes) -> Request:
    if len(buf) < 12:
        raise ProtocolError(f"command packet of {len(buf)} bytes is shorter than BasicCommandCT (12)")
    (cmd_value,) = struct.unpack_from("<i", buf, 8)
    command = enum_value(Command, cmd_value, "command request")
    cls = REQUEST_TYPES[command]
    values = _expect_size(buf, _REQUEST_STRUCTS[command], f"{cls.__name__} request")
    return cls.from_payload(values[3:])


def _status(value: int, what: str) -> ResultStatus:
    return enum_value(ResultStatus, value, what)


def _decode_answer(buf: bytes) -> Answer:
    if len(buf) < _BASIC_RT.size:
        raise ProtocolError(f"command answer of {len(buf)} bytes is shorter than BasicCommandRT (16)")
    _, _, cmd_value, status_value = _BASIC_RT.unpack_from(buf)
    command = enum_value(Command, cmd_value, "command answer")
    status = _status(status_value, f"answer to {command.name}.status")
    st = _ANSWER_STRUCTS.get(command)
    if st is None or len(buf) == _BASIC_RT.size:
        if st is not None and status == ResultStatus.ALL_OK:
            raise ProtocolError(f"answer to {command.name} says ALL_OK but lacks its {st.size - 16}-byte payload")
        _expect_size(buf, _BASIC_RT, f"answer to {command.name}")
        return CommandAnswer(command, status)
    v = _expect_size(buf, st, f"answer to {command.name}")[4:]
    if command in READBACK:
        return SettingAnswer(command, status, READBACK[command].from_payload(v))
    if command == Command.GET_SYSTEM_STATUS:
        return SystemStatusAnswer(
            status,
            _status(v[0], "GetSystemStatus.lastResultStatus"),
            enum_value(TrackerProcessorStatus, v[1], "GetSystemStatus.trackerProcessorStatus"),
            enum_value(LaserProcessorStatus, v[2], "GetSystemStatus.laserStatus"),
            enum_value(ADMStatus, v[3], "GetSystemStatus.admStatus"),
            (v[4], v[5], v[6]),
            enum_value(WeatherMonitorStatus, v[7], "GetSystemStatus.weatherMonitorStatus"),
            v[8],
            v[9],
        )
    if command == Command.GET_TRACKER_INFO:
        return _decode_tracker_info(status, v)
    if command == Command.GET_SYSTEM_SOFTWARE_VERSION:
        return SoftwareVersionAnswer(status, unicode_field(v, "GetSystemSoftwareVersion.cSoftwareVersion"))
    if command == Command.GET_TRACKER_STATUS:
        return TrackerStatusAnswer(status, enum_value(TrackerStatus, v[0], "GetTrackerStatus.trackerStatus"))
    return MeasurementStatusInfoAnswer(status, _status(v[0], "GetMeasurementStatusInfo.lastResultStatus"), v[1])


def decode_from_tracker(buf: bytes, data_type: DataType) -> FromTracker:
    if data_type == DataType.COMMAND:
        return _decode_answer(buf)
    if data_type == DataType.ERROR:
        _, _, cmd_value, status_value = _expect_size(buf, _ERROR, "error packet (ErrorResponseT)")
        return ErrorResponse(
            enum_value(Command, cmd_value, "error packet command"), _status(status_value, "error status")
        )
    if data_type == DataType.SYSTEM_STATUS_CHANGE:
        _, _, change = _expect_size(buf, _STATUS_CHANGE, "status-change packet (SystemStatusChangeT)")
        return StatusChange(enum_value(SystemStatusChange, change, "status-change packet"))
    meas = next((cls for cls, (t, _) in _MEAS_TYPES.items() if t == data_type), None)
    if meas is not None:
        name = meas.__name__
        v = _expect_size(buf, _MEAS_TYPES[meas][1], f"measurement result ({name}T)")
        floats = tuple(_finite(x, f"{name}.{n}") for x, n in zip(v[5:], _MEAS_FLOATS[meas], strict=True))
        return meas(
            _status(v[2], f"{name}.status"),
            enum_value(MeasMode, v[3], f"{name}.measMode"),
            _bool(v[4], f"{name}.bIsTryMode"),
            *floats,
        )
    if data_type == DataType.REFLECTOR_POS_RESULT:
        v = _expect_size(buf, _REFLECTOR_POS, "reflector position (ReflectorPosResultT)")
        x, y, z = (_finite(x, f"ReflectorPosResult.dVal{i + 1}") for i, x in enumerate(v[3:]))
        return ReflectorPosResult(_status(v[2], "ReflectorPosResult.status"), x, y, z)
    raise ProtocolError(f"packet type {data_type.name} ({int(data_type)}) is not supported by this driver")
