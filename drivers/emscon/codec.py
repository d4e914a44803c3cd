"""Wire codec of Leica emScon TPI, binary C variant (TCP port 700): pure functions, no I/O.

Sources (public copies of the Leica emScon TPI/SDK V3.6 headers and of an open-source client), read through
the project's code index; every enum value and struct layout below was written from them:

  [H]  beckjac/emscon_ros  include/emscon_ros/ES_C_API_Def.h   (full-featured V3.6 header, all tracker types
       incl. ES_LTS_AT901_B/MR/LR): ES_DataType, ES_Command, ES_MeasMode, ES_ResultStatus, ES_TrackerStatus,
       ES_TrackerProcessorStatus, ES_LaserProcessorStatus, ES_ADMStatus, ES_WeatherMonitorStatus,
       ES_SystemStatusChange, ES_MeasurementStatusInfo, ES_StatisticMode, and the structs PacketHeaderT,
       ReturnDataT, BasicCommandCT/RT, ErrorResponseT, SystemStatusChangeT, SingleMeasResultT,
       SingleMeasResult2T, ReflectorPosResultT, SystemUnitsDataT, SystemSettingsDataT, StationaryModeDataT and
       the *CT/*RT command structs used here.  `#pragma pack (push, 4)`: no padding before the doubles.
  [E]  beckjac/emscon_ros  include/emscon_ros/Enum.h   ES_LengthUnit, ES_AngleUnit, ES_TemperatureUnit,
       ES_PressureUnit, ES_HumidityUnit, ES_CoordinateSystemType.
  [A]  MuffinSpawn/Leica  Include/ES_C_API_Def.h  (AT4xx extract of the same header; same layouts).
  [K]  shohty/Leica_KEK  CESAPI/packet.py  (CESAPI Python client): PacketHeaderT packed as '<i I' (8 bytes),
       BasicCommandCT 12 bytes, BasicCommandRT 16 bytes -- i.e. `long` is 32 bits on the wire (the header is
       written for MSVC, where long is 32 bits; [H] even `#define long int32_t` for this reason).
       MuffinSpawn/Leica's CESAPI packs lPacketSize in 4 bytes too at its current head (its CESAPI/sniff.py
       frames `PACKET_HEADER_SIZE = 8  # lPacketSize, type`); only early commits of its CESAPI/packet.py,
       generated on 64-bit Linux, packed it as '<q' (a 12-byte header).
  [C]  MuffinSpawn/Leica  CESAPI/command.py: StartMeasurement is answered by the command acknowledgement and
       then a separate ES_DT_SingleMeasResult packet, or an ES_DT_SingleMeasResult2 one (it accepts both);
       ES_DT_Error packets (ErrorResponseT) report a failed command.
  [L]  drivers/emscon/layouts.py: the CT/RT layout of every ES_Command of [H], for the sizes of answers to
       commands outside the subset decoded here.

A refusal (a status other than ES_RS_AllOK) comes in one of two forms, and [H] gives the layouts, not which
one a server sends: just BasicCommandRT's 16 bytes (a CommandAnswer), or the full *RT of that command with a
zeroed payload (`encode_refusal`; it decodes as that command's answer with zero values), which a client that
unpacks the fixed struct of each answer can read. Both decode.

Frame: every packet starts with PacketHeaderT {int32 lPacketSize (whole packet, bytes); int32 type
(ES_DataType)}, little-endian.  Command requests and their answers share ES_DT_Command and the command id and
are told apart only by direction (e.g. SetReflectorCT and SetReflectorRT are both 16 bytes), so
`decode_packet` takes the direction.  Sizes are checked exactly against the struct layouts.

`decode_packet` is total: for any bytes it returns a message or raises ProtocolError (fuzzed in
tests/test_emscon_codec.py).  `PacketReader` frames a byte stream into packets and never buffers more than one
packet of at most MAX_PACKET_BYTES plus the chunk being fed.
"""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass, fields
from typing import ClassVar

from trackcal.drivers.emscon.layouts import LAYOUTS
from trackcal.drivers.errors import ProtocolError

DEFAULT_PORT = 700
HEADER = struct.Struct("<ii")  # PacketHeaderT {long lPacketSize; enum ES_DataType type}  [H], [K]
HEADER_SIZE = HEADER.size  # 8
# The largest struct of the V3.6 header is a few hundred bytes (e.g. GetCompensations2RT with its UNICODE
# strings); 64 KiB is a sane cap that still rejects a corrupted size field before any allocation.
MAX_PACKET_BYTES = 64 * 1024


# -------------------- enums [H], [E]
class DataType(enum.IntEnum):  # ES_DataType
    COMMAND = 0
    ERROR = 1
    SINGLE_MEAS_RESULT = 2
    MULTI_MEAS_RESULT = 3
    STATIONARY_PROBE_MEAS_RESULT = 4
    CONTINUOUS_PROBE_MEAS_RESULT = 5
    NIVEL_RESULT = 6
    REFLECTOR_POS_RESULT = 7
    SYSTEM_STATUS_CHANGE = 8
    SINGLE_MEAS_RESULT2 = 9
    MULTI_MEAS_RESULT2 = 10
    PROBE_POS_RESULT = 11


class Command(enum.IntEnum):  # ES_Command: the subset this driver speaks
    GET_SYSTEM_STATUS = 1
    GET_TRACKER_STATUS = 2
    SET_UNITS = 5
    GET_UNITS = 6
    INITIALIZE = 7
    SET_ENVIRONMENT_PARAMS = 20
    SET_MEASUREMENT_MODE = 24
    GET_MEASUREMENT_MODE = 25
    SET_COORDINATE_SYSTEM_TYPE = 26
    GET_COORDINATE_SYSTEM_TYPE = 27
    SET_STATIONARY_MODE_PARAMS = 28
    GET_STATIONARY_MODE_PARAMS = 29
    SET_REFLECTOR = 40
    SET_SEARCH_PARAMS = 43
    SET_SYSTEM_SETTINGS = 47
    GET_SYSTEM_SETTINGS = 48
    START_MEASUREMENT = 49
    GO_BIRD_BATH = 54
    GO_POSITION = 55
    FIND_REFLECTOR = 63
    SET_STATISTIC_MODE = 80
    GET_STATISTIC_MODE = 81
    GET_MEASUREMENT_STATUS_INFO = 122


class MeasMode(enum.IntEnum):  # ES_MeasMode
    STATIONARY = 0
    CONTINUOUS_TIME = 1
    CONTINUOUS_DISTANCE = 2
    GRID = 3
    SPHERE_CENTER = 4
    CIRCLE_CENTER = 5
    STATIONARY_6D = 6
    CONTINUOUS_TIME_6D = 7
    CONTINUOUS_DISTANCE_6D = 8
    GRID_6D = 9
    SPHERE_CENTER_6D = 10
    CIRCLE_CENTER_6D = 11


class LengthUnit(enum.IntEnum):  # ES_LengthUnit [E]
    METER = 0
    MILLIMETER = 1
    MICRON = 2
    FOOT = 3
    YARD = 4
    INCH = 5


class AngleUnit(enum.IntEnum):  # ES_AngleUnit [E]
    RADIAN = 0
    DEGREE = 1
    GON = 2


class TemperatureUnit(enum.IntEnum):  # ES_TemperatureUnit [E]
    CELSIUS = 0
    FAHRENHEIT = 1


class PressureUnit(enum.IntEnum):  # ES_PressureUnit [E]
    MBAR = 0
    HPASCAL = 1
    KPASCAL = 2
    MMHG = 3
    PSI = 4
    INH2O = 5
    INHG = 6


class HumidityUnit(enum.IntEnum):  # ES_HumidityUnit [E]
    RH = 0


class CoordinateSystemType(enum.IntEnum):  # ES_CoordinateSystemType [E]
    RHR = 0  # right-handed rectangular (Cartesian)
    LHRX = 1
    LHRY = 2
    LHRZ = 3
    CCW = 4
    CCC = 5
    SCW = 6
    SCC = 7


class StatisticMode(enum.IntEnum):  # ES_StatisticMode [H]
    STANDARD = 0  # stationary results as SingleMeasResultT (ES_DT_SingleMeasResult, 156 bytes)
    EXTENDED = 1  # ... as SingleMeasResult2T (ES_DT_SingleMeasResult2, 204 bytes, with covariances)


class TrackerStatus(enum.IntEnum):  # ES_TrackerStatus
    NOT_READY = 0
    BUSY = 1
    READY = 2
    STATUS_6D_INVALID = 3


class TrackerProcessorStatus(enum.IntEnum):  # ES_TrackerProcessorStatus
    NO_TP_FOUND = 0
    TP_FOUND = 1
    NB_OPEN = 2
    BOOTED = 3
    COMPENSATION_SET = 4
    INITIALIZED = 5


class LaserProcessorStatus(enum.IntEnum):  # ES_LaserProcessorStatus
    LCP_COMM_FAILED = 0
    LCP_NOT_AVAIL = 1
    LASER_HEATING_UP = 2
    LASER_READY = 3
    UNABLE_TO_STABILIZE = 4
    LASER_OFF = 5


class ADMStatus(enum.IntEnum):  # ES_ADMStatus
    NO_ADM = 0
    ADM_COMM_FAILED = 1
    ADM_READY = 2
    ADM_BUSY = 3
    HW_ERROR = 4
    SECURITY_LOCK_ACTIVE = 5
    NOT_COMPENSATED = 6


class WeatherMonitorStatus(enum.IntEnum):  # ES_WeatherMonitorStatus
    NOT_CONNECTED = 0
    READ_ONLY = 1
    READ_AND_CALCULATE_REFRACTIONS = 2


class MeasurementStatusInfo(enum.IntFlag):  # ES_MeasurementStatusInfo (bit flags)
    TRACKER_FOUND = 1
    TRACKER_COMPENSATION_FOUND = 2
    ADM_FOUND = 4
    ADM_COMPENSATION_FOUND = 8
    MEASUREMENT_CAMERA_FOUND = 16
    INTERNAL_CAMERA_PARAMS_OK = 32
    CAMERA_TO_TRACKER_PARAMS_FOUND = 64
    MEASUREMENT_PROBE_FOUND = 128
    PROBE_PARAMS_FOUND = 256
    MEASUREMENT_TIP_FOUND = 512
    TIP_PARAMS_FOUND = 1024
    REFLECTOR_FOUND = 2048
    IN_FACE1 = 4096
    SHANK_PARAMS_FOUND = 8192
    SENSOR_BATTERY_MOUNTED = 16384
    NIVEL_IN_WORKING_RANGE = 32768
    INITIALIZED = 65536


_API_ERROR_OFFSET = 10000  # ES_API_ERROR_OFFSET [H]


class ResultStatus(enum.IntEnum):  # ES_ResultStatus, complete as of TPI V3.6 [H]
    ALL_OK = 0
    SERVER_BUSY = 1
    NOT_IMPLEMENTED = 2
    WRONG_PARAMETER = 3
    WRONG_PARAMETER1 = 4
    WRONG_PARAMETER2 = 5
    WRONG_PARAMETER3 = 6
    WRONG_PARAMETER4 = 7
    WRONG_PARAMETER5 = 8
    WRONG_PARAMETER6 = 9
    WRONG_PARAMETER7 = 10
    PARAMETER1_OUT_OF_RANGE_OK = 11
    PARAMETER1_OUT_OF_RANGE_NOK = 12
    PARAMETER2_OUT_OF_RANGE_OK = 13
    PARAMETER2_OUT_OF_RANGE_NOK = 14
    PARAMETER3_OUT_OF_RANGE_OK = 15
    PARAMETER3_OUT_OF_RANGE_NOK = 16
    PARAMETER4_OUT_OF_RANGE_OK = 17
    PARAMETER4_OUT_OF_RANGE_NOK = 18
    PARAMETER5_OUT_OF_RANGE_OK = 19
    PARAMETER5_OUT_OF_RANGE_NOK = 20
    PARAMETER6_OUT_OF_RANGE_OK = 21
    PARAMETER6_OUT_OF_RANGE_NOK = 22
    WRONG_CURRENT_REFLECTOR = 23
    NO_CIRCLE_CENTER_FOUND = 24
    NO_SPHERE_CENTER_FOUND = 25
    NO_TP_FOUND = 26
    NO_WEATHERMONITOR_FOUND = 27
    NO_LAST_MEASURED_POINT = 28
    NO_VIDEO_CAMERA = 29
    NO_ADM = 30
    NO_NIVEL = 31
    WRONG_TP_FIRMWARE = 32
    DATA_BASE_NOT_FOUND = 33
    LICENSE_EXPIRED = 34
    USAGE_CONFLICT = 35
    UNKNOWN = 36
    NO_DISTANCE_SET = 37
    NO_TRACKER_CONNECTED = 38
    TRACKER_NOT_INITIALIZED = 39
    MODULE_NOT_STARTED = 40
    MODULE_TIMED_OUT = 41
    ERROR_READING_MODULE_DB = 42
    ERROR_WRITING_MODULE_DB = 43
    NOT_IN_CAMERA_POSITION = 44
    TP_HAS_SERVICE_FIRMWARE = 45
    TP_EXTERNAL_CONTROL = 46
    WRONG_PARAMETER8 = 47
    WRONG_PARAMETER9 = 48
    WRONG_PARAMETER10 = 49
    WRONG_PARAMETER11 = 50
    WRONG_PARAMETER12 = 51
    WRONG_PARAMETER13 = 52
    WRONG_PARAMETER14 = 53
    WRONG_PARAMETER15 = 54
    WRONG_PARAMETER16 = 55
    NO_SUCH_COMPENSATION = 56
    METEO_DATA_OUT_OF_RANGE = 57
    IN_COMPENSATION_MODE = 58
    INTERNAL_PROCESS_ACTIVE = 59
    NO_COPY_PROTECTION_DONGLE_FOUND = 60
    MODULE_NOT_ACTIVATED = 61
    MODULE_WRONG_VERSION = 62
    DEMO_DONGLE_EXPIRED = 63
    PARAMETER_IMPORT_FROM_PROBE_FAILED = 64
    PARAMETER_EXPORT_TO_PROBE_FAILED = 65
    TRK_COMP_MEAS_CAMERA_MISMATCH = 66
    NO_MEASUREMENT_CAMERA = 67
    NO_ACTIVE_MEASUREMENT_CAMERA = 68
    NO_MEASUREMENT_CAMERAS_IN_DB = 69
    NO_CAMERA_TO_TRACKER_COMP_SET = 70
    NO_CAMERA_TO_TRACKER_COMP_IN_DB = 71
    PROBLEM_STORING_CAMERA_TO_TRACKER_FACTORY_SET = 72
    PROBLEM_WITH_CAMERA_INTERNAL_CALIBRATION = 73
    COMMUNICATION_WITH_MEASUREMENT_CAMERA_FAILED = 74
    NO_MEASUREMENT_PROBE = 75
    NO_ACTIVE_MEASUREMENT_PROBE = 76
    NO_MEASUREMENT_PROBES_IN_DB = 77
    NO_MEASUREMENT_PROBE_COMP_SET = 78
    NO_MEASUREMENT_PROBE_COMP_IN_DB = 79
    PROBLEM_STORING_PROBE_FACTORY_SET = 80
    WRONG_ACTIVE_MEASUREMENT_PROBE_COMP_IN_DB = 81
    COMMUNICATION_WITH_MEASUREMENT_PROBE_FAILED = 82
    NO_MEASUREMENT_TIP = 83
    NO_ACTIVE_MEASUREMENT_TIP = 84
    NO_MEASUREMENT_TIPS_IN_DB = 85
    NO_MEASUREMENT_TIP_COMP_IN_DB = 86
    NO_MEASUREMENT_TIP_COMP_SET = 87
    PROBLEM_STORING_TIP_ASSEMBLY = 88
    PROBLEM_READING_COMPENSATION_DB = 89
    NO_DATA_TO_IMPORT = 90
    PROBLEM_SETTING_TRIGGER_SOURCE = 91
    MODE_6D_NOT_ALLOWED = 92
    BAD_6D_RESULT = 93
    NO_TEMPERATURE_FROM_WM = 94
    NO_PRESSURE_FROM_WM = 95
    NO_HUMIDITY_FROM_WM = 96
    MEASUREMENT_6D_FACE2_NOT_ALLOWED = 97
    INVALID_INPUT_DATA = 98
    NO_TRIGGER_BOARD = 99
    NO_MEASUREMENT_SHANK_COMP_SET = _API_ERROR_OFFSET + 1
    NO_VALID_ADM_COMPENSATION = _API_ERROR_OFFSET + 2
    PRESSURE_SENSOR_PROBLEM = _API_ERROR_OFFSET + 3
    MEASUREMENT_STATUS_NOT_READY = _API_ERROR_OFFSET + 4
    AIFM_START_UP_BUSY = _API_ERROR_OFFSET + 5  # alias ES_RS_ADMStartUpBusy
    INVALID_TIP_ADAPTER = _API_ERROR_OFFSET + 6
    NO_ATR = _API_ERROR_OFFSET + 7
    NO_OVC = _API_ERROR_OFFSET + 8
    NO_STATIONARY_RESULT = _API_ERROR_OFFSET + 9
    SENSOR_NOT_LEVELED = _API_ERROR_OFFSET + 10
    MULTI_CONNECTIONS_NOT_ALLOWED = _API_ERROR_OFFSET + 11
    SENSOR_NOT_WARMED_UP = _API_ERROR_OFFSET + 12
    SENSOR_NOT_STABLE = _API_ERROR_OFFSET + 13
    SYSTEM_NOT_READY_FOR_MEASUREMENT = _API_ERROR_OFFSET + 14
    COMMUNICATION_WITH_SENSOR_FAILED = _API_ERROR_OFFSET + 15
    NO_SENSOR_BATTERY = _API_ERROR_OFFSET + 16
    COMPENSATOR_NOT_ALLOWED = _API_ERROR_OFFSET + 17
    WARMED_UP_STATE_REACHED = _API_ERROR_OFFSET + 18
    NOT_LEVELED_FOR_INITIALIZATION = _API_ERROR_OFFSET + 19
    ADM_HARDWARE_PROBLEM = _API_ERROR_OFFSET + 20
    ATR_HARDWARE_PROBLEM = _API_ERROR_OFFSET + 21


class SystemStatusChange(enum.IntEnum):  # ES_SystemStatusChange [H]
    DISTANCE_SET = 0
    LASER_WARMED_UP = 1
    ENVIRONMENT_PARAMS_CHANGED = 2
    REFRACTION_PARAMS_CHANGED = 3
    SEARCH_PARAMS_CHANGED = 4
    ADM_PARAMS_CHANGED = 5
    UNITS_CHANGED = 6
    REFLECTOR_CHANGED = 7
    SYSTEM_SETTINGS_CHANGED = 8
    TEMPERATURE_RANGE_CHANGED = 9
    CAMERA_PARAMS_CHANGED = 10
    COMPENSATION_CHANGED = 11
    COORDINATE_SYSTEM_TYPE_CHANGED = 12
    BOX_REGION_PARAMS_CHANGED = 13
    SPHERE_REGION_PARAMS_CHANGED = 14
    STATION_ORIENTATION_PARAMS_CHANGED = 15
    TRANSFORMATION_PARAMS_CHANGED = 16
    MEASUREMENT_MODE_CHANGED = 17
    STATIONARY_MODE_PARAMS_CHANGED = 18
    CONTINUOUS_TIME_MODE_PARAMS_CHANGED = 19
    CONTINUOUS_DISTANCE_MODE_PARAMS_CHANGED = 20
    GRID_MODE_PARAMS_CHANGED = 21
    CIRCLE_CENTER_MODE_PARAMS_CHANGED = 22
    SPHERE_CENTER_MODE_PARAMS_CHANGED = 23
    STATISTIC_MODE_CHANGED = 24
    MEAS_STATUS_NOT_READY = 25
    MEAS_STATUS_BUSY = 26
    MEAS_STATUS_READY = 27
    MEASUREMENT_COUNT_REACHED = 28
    TRIGGER_SOURCE_CHANGED = 29
    IS_FACE1 = 30
    IS_FACE2 = 31
    EXTERNAL_CONTROL_ACTIVE = 32
    SERVICE_SOFTWARE_ACTIVE = 33
    MEASUREMENT_CAMERA_CHANGED = 34
    MEASUREMENT_CAMERA_MODE_CHANGED = 35
    PROBE_CHANGED = 36
    TIP_CHANGED = 37
    TCAM_TO_TRACKER_COMPENSATION_CHANGED = 38
    PROBE_COMPENSATION_CHANGED = 39
    TIP_TO_PROBE_COMPENSATION_CHANGED = 40
    EXTERN_TRIGGER_PARAMS_CHANGED = 41
    TCAM_TO_TRACKER_COMPENSATION_DELETED = 42
    MEASUREMENT_PROBE_COMPENSATION_DELETED = 43
    MEASUREMENT_TIP_COMPENSATION_DELETED = 44
    MANY_MECHANICAL_COMPENSATIONS_IN_DB = 45
    MEAS_STATUS_6D_STATUS_INVALID = 99
    MEASUREMENT_PROBE_BUTTON_DOWN = 100
    MEASUREMENT_PROBE_BUTTON_UP = 101
    EXTERNAL_TRIGGER_EVENT = 102
    EXTERNAL_TRIGGER_START_EVENT = 103
    EXTERNAL_TRIGGER_STOP_EVENT = 104
    OBJECT_TEMPERATURE_CHANGED = 105
    OVERVIEW_CAMERA_CHANGED = 106
    NIVEL_SENSOR_CHANGED = 107
    PROBE_BUTTON1_DOWN = 110
    PROBE_BUTTON1_UP = 111
    PROBE_BUTTON1_DOUBLE_CLICK = 112
    PROBE_BUTTON2_DOWN = 120
    PROBE_BUTTON2_UP = 121
    PROBE_BUTTON2_DOUBLE_CLICK = 122
    PROBE_BUTTON3_DOWN = 130
    PROBE_BUTTON3_UP = 131
    PROBE_BUTTON3_DOUBLE_CLICK = 132
    PROBE_BUTTON4_DOWN = 140
    PROBE_BUTTON4_UP = 141
    PROBE_BUTTON4_DOUBLE_CLICK = 142
    QUICK_RELEASE_OPENED = 143
    QUICK_RELEASE_CLOSED = 144
    LASER_REACHING_LIMIT = 145
    LASER_NOT_STABILIZED = 146
    MULTIPLE_TIP_ADAPTER_CONNECTED = 150
    INITIALIZATION_STATUS_CHANGED = 151  # spelled ES_SCC_... in the header
    TILT_SENSOR_STATUS_CHANGED = 152  # spelled ES_SCC_... in the header
    COMPENSATION_MODE_START = 800
    COMPENSATION_MODE_END = 801
    EMSYS_FILES_IMPORTED = 820
    SENSOR_DETECTED = 850
    SENSOR_DISCONNECTED = 851
    COMPENSATOR_STATUS_CHANGED = 852
    BATTERY_STATUS_CHANGED = 853
    COPY_PROTECTION_REMOVED = 996
    TP_CONNECTION_CLOSING = 997
    SERVER_CLOSING = 998
    SERVER_STARTED = 999


class Direction(enum.Enum):
    TO_TRACKER = "client -> tracker"  # command requests (*CT structs)
    FROM_TRACKER = "tracker -> client"  # answers (*RT), errors, results, status changes


# -------------------- validation helpers
def _enum(cls: type[enum.IntEnum], value: int, what: str) -> enum.IntEnum:
    try:
        return cls(value)
    except ValueError:
        raise ProtocolError(f"{what}: {value} is not a known {cls.__name__} value") from None


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
            int(v) if isinstance(v, bool | enum.IntEnum) else v
            for v in (getattr(self, f.name) for f in fields(self))
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
            _enum(LengthUnit, lu, "SetUnits.lenUnitType"),
            _enum(AngleUnit, au, "SetUnits.angUnitType"),
            _enum(TemperatureUnit, tu, "SetUnits.tempUnitType"),
            _enum(PressureUnit, pu, "SetUnits.pressUnitType"),
            _enum(HumidityUnit, hu, "SetUnits.humUnitType"),
        )


@dataclass(frozen=True)
class SetCoordinateSystemType(Request):  # SetCoordinateSystemTypeCT {BasicCommandCT; enum coordSysType}
    COMMAND: ClassVar[Command] = Command.SET_COORDINATE_SYSTEM_TYPE
    PAYLOAD: ClassVar[str] = "i"
    coordinate_system: CoordinateSystemType = CoordinateSystemType.RHR

    @classmethod
    def from_payload(cls, values: tuple) -> SetCoordinateSystemType:
        return cls(_enum(CoordinateSystemType, values[0], "SetCoordinateSystemType.coordSysType"))


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
        return cls(_enum(MeasMode, values[0], "SetMeasurementMode.measMode"))


@dataclass(frozen=True)
class SetStationaryModeParams(
    Request
):  # SetStationaryModeParamsCT {BasicCommandCT; {long lMeasTime; ES_BOOL bUseADM}}
    COMMAND: ClassVar[Command] = Command.SET_STATIONARY_MODE_PARAMS
    PAYLOAD: ClassVar[str] = "ii"
    meas_time_ms: int  # lMeasTime; unit not stated in the header, taken as milliseconds (see the driver)
    use_adm: bool = False

    @classmethod
    def from_payload(cls, values: tuple) -> SetStationaryModeParams:
        return cls(values[0], _bool(values[1], "SetStationaryModeParams.bUseADM"))


@dataclass(frozen=True)
class SetSearchParams(
    Request
):  # SetSearchParamsCT {BasicCommandCT; {double dSearchRadius; long lTimeOut /*ms*/}}
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
        return cls(_enum(WeatherMonitorStatus, values[0], "SystemSettingsDataT.weatherMonitorStatus"), *flags)


@dataclass(frozen=True)
class SetStatisticMode(Request):  # SetStatisticModeCT {BasicCommandCT; ES_StatisticMode stationary, continuous}
    COMMAND: ClassVar[Command] = Command.SET_STATISTIC_MODE
    PAYLOAD: ClassVar[str] = "ii"
    stationary: StatisticMode = StatisticMode.STANDARD
    continuous: StatisticMode = StatisticMode.STANDARD

    @classmethod
    def from_payload(cls, values: tuple) -> SetStatisticMode:
        return cls(
            _enum(StatisticMode, values[0], "SetStatisticMode.stationaryMeasurements"),
            _enum(StatisticMode, values[1], "SetStatisticMode.continuousMeasurements"),
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


Answer = CommandAnswer | SystemStatusAnswer | TrackerStatusAnswer | MeasurementStatusInfoAnswer | SettingAnswer
MeasResult = SingleMeasResult | SingleMeasResult2
FromTracker = Answer | ErrorResponse | StatusChange | MeasResult | ReflectorPosResult
Message = Request | FromTracker

_BASIC_RT = struct.Struct(_RT_PREFIX)  # 16
_SYSTEM_STATUS_RT = struct.Struct(_RT_PREFIX + "iiii" + "iii" + "iii")  # 56
_TRACKER_STATUS_RT = struct.Struct(_RT_PREFIX + "i")  # 20
_MEAS_STATUS_INFO_RT = struct.Struct(_RT_PREFIX + "ii")  # 24
_ERROR = struct.Struct("<iiii")  # ErrorResponseT, 16
_STATUS_CHANGE = struct.Struct("<iii")  # SystemStatusChangeT, 12
_SINGLE_MEAS = struct.Struct("<iii" + "ii" + "d" * 17)  # SingleMeasResultT, 156
_SINGLE_MEAS2 = struct.Struct("<iii" + "ii" + "d" * 23)  # SingleMeasResult2T, 204
_REFLECTOR_POS = struct.Struct("<iii" + "ddd")  # ReflectorPosResultT, 36
_ANSWER_STRUCTS: dict[Command, struct.Struct] = {
    Command.GET_SYSTEM_STATUS: _SYSTEM_STATUS_RT,
    Command.GET_TRACKER_STATUS: _TRACKER_STATUS_RT,
    Command.GET_MEASUREMENT_STATUS_INFO: _MEAS_STATUS_INFO_RT,
    **{cmd: struct.Struct(_RT_PREFIX + cls.PAYLOAD) for cmd, cls in READBACK.items()},
}
_MEAS_TYPES: dict[type, tuple[DataType, struct.Struct]] = {
    SingleMeasResult: (DataType.SINGLE_MEAS_RESULT, _SINGLE_MEAS),
    SingleMeasResult2: (DataType.SINGLE_MEAS_RESULT2, _SINGLE_MEAS2),
}
_MEAS_FLOATS = {cls: tuple(f.name for f in fields(cls))[3:] for cls in _MEAS_TYPES}


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


def encode(message: Message) -> bytes:
    """The bytes of any message, in its own direction (requests -> tracker, everything else -> client)."""
    if isinstance(message, Request):
        return encode_command(message)
    if isinstance(message, CommandAnswer):
        if message.command in _ANSWER_STRUCTS and message.status == ResultStatus.ALL_OK:
            raise ValueError(
                f"an ALL_OK answer to {message.command.name} carries a payload: use its own type"
            )
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


# -------------------- decode
def _expect_size(buf: bytes, st: struct.Struct, what: str) -> tuple:
    if len(buf) != st.size:
        raise ProtocolError(f"{what}: packet of {len(buf)} bytes, the layout needs exactly {st.size}")
    return st.unpack(buf)


def _decode_request(buf: bytes) -> Request:
    if len(buf) < 12:
        raise ProtocolError(f"command packet of {len(buf)} bytes is shorter than BasicCommandCT (12)")
    (cmd_value,) = struct.unpack_from("<i", buf, 8)
    command = _enum(Command, cmd_value, "command request")
    cls = REQUEST_TYPES[command]
    values = _expect_size(buf, _REQUEST_STRUCTS[command], f"{cls.__name__} request")
    return cls.from_payload(values[3:])


def _status(value: int, what: str) -> ResultStatus:
    return _enum(ResultStatus, value, what)


def _decode_answer(buf: bytes) -> Answer:
    if len(buf) < _BASIC_RT.size:
        raise ProtocolError(f"command answer of {len(buf)} bytes is shorter than BasicCommandRT (16)")
    _, _, cmd_value, status_value = _BASIC_RT.unpack_from(buf)
    command = _enum(Command, cmd_value, "command answer")
    status = _status(status_value, f"answer to {command.name}.status")
    st = _ANSWER_STRUCTS.get(command)
    if st is None or len(buf) == _BASIC_RT.size:
        if st is not None and status == ResultStatus.ALL_OK:
            raise ProtocolError(
                f"answer to {command.name} says ALL_OK but lacks its {st.size - 16}-byte payload"
            )
        _expect_size(buf, _BASIC_RT, f"answer to {command.name}")
        return CommandAnswer(command, status)
    v = _expect_size(buf, st, f"answer to {command.name}")[4:]
    if command in READBACK:
        return SettingAnswer(command, status, READBACK[command].from_payload(v))
    if command == Command.GET_SYSTEM_STATUS:
        return SystemStatusAnswer(
            status,
            _status(v[0], "GetSystemStatus.lastResultStatus"),
            _enum(TrackerProcessorStatus, v[1], "GetSystemStatus.trackerProcessorStatus"),
            _enum(LaserProcessorStatus, v[2], "GetSystemStatus.laserStatus"),
            _enum(ADMStatus, v[3], "GetSystemStatus.admStatus"),
            (v[4], v[5], v[6]),
            _enum(WeatherMonitorStatus, v[7], "GetSystemStatus.weatherMonitorStatus"),
            v[8],
            v[9],
        )
    if command == Command.GET_TRACKER_STATUS:
        return TrackerStatusAnswer(status, _enum(TrackerStatus, v[0], "GetTrackerStatus.trackerStatus"))
    return MeasurementStatusInfoAnswer(
        status, _status(v[0], "GetMeasurementStatusInfo.lastResultStatus"), v[1]
    )


def _decode_from_tracker(buf: bytes, data_type: DataType) -> FromTracker:
    if data_type == DataType.COMMAND:
        return _decode_answer(buf)
    if data_type == DataType.ERROR:
        _, _, cmd_value, status_value = _expect_size(buf, _ERROR, "error packet (ErrorResponseT)")
        return ErrorResponse(
            _enum(Command, cmd_value, "error packet command"), _status(status_value, "error status")
        )
    if data_type == DataType.SYSTEM_STATUS_CHANGE:
        _, _, change = _expect_size(buf, _STATUS_CHANGE, "status-change packet (SystemStatusChangeT)")
        return StatusChange(_enum(SystemStatusChange, change, "status-change packet"))
    meas = next((cls for cls, (t, _) in _MEAS_TYPES.items() if t == data_type), None)
    if meas is not None:
        name = meas.__name__
        v = _expect_size(buf, _MEAS_TYPES[meas][1], f"measurement result ({name}T)")
        floats = tuple(_finite(x, f"{name}.{n}") for x, n in zip(v[5:], _MEAS_FLOATS[meas], strict=True))
        return meas(
            _status(v[2], f"{name}.status"),
            _enum(MeasMode, v[3], f"{name}.measMode"),
            _bool(v[4], f"{name}.bIsTryMode"),
            *floats,
        )
    if data_type == DataType.REFLECTOR_POS_RESULT:
        v = _expect_size(buf, _REFLECTOR_POS, "reflector position (ReflectorPosResultT)")
        x, y, z = (_finite(x, f"ReflectorPosResult.dVal{i + 1}") for i, x in enumerate(v[3:]))
        return ReflectorPosResult(_status(v[2], "ReflectorPosResult.status"), x, y, z)
    raise ProtocolError(f"packet type {data_type.name} ({int(data_type)}) is not supported by this driver")


def decode_packet(buf: bytes, direction: Direction = Direction.FROM_TRACKER) -> Message:
    """Decode one complete packet, or raise ProtocolError. `direction` tells requests from answers."""
    if not isinstance(buf, bytes | bytearray | memoryview):
        raise ProtocolError(f"expected bytes, got {type(buf).__name__}")
    buf = bytes(buf)
    if len(buf) < HEADER_SIZE:
        raise ProtocolError(
            f"packet of {len(buf)} bytes is shorter than the {HEADER_SIZE}-byte PacketHeaderT"
        )
    size, type_value = HEADER.unpack_from(buf)
    if size != len(buf):
        raise ProtocolError(f"lPacketSize says {size} bytes but the packet has {len(buf)}")
    data_type = _enum(DataType, type_value, "PacketHeaderT.type")
    if direction == Direction.TO_TRACKER:
        if data_type != DataType.COMMAND:
            raise ProtocolError(f"a client sends only command packets, not {data_type.name}")
        return _decode_request(buf)
    return _decode_from_tracker(buf, data_type)


# -------------------- framing
class PacketReader:
    """Stream framer: feed(bytes) -> the complete packets so far (each still to be decoded).

    Survives partial reads and several packets per read. A size field below the header size or above
    `max_packet_bytes` raises ProtocolError at once (before buffering the body); the stream cannot be
    resynchronised after that, so the reader stays failed and the caller should drop the connection.
    """

    def __init__(self, max_packet_bytes: int = MAX_PACKET_BYTES) -> None:
        if max_packet_bytes < HEADER_SIZE:
            raise ValueError("max_packet_bytes must hold at least a header")
        self.max_packet_bytes = max_packet_bytes
        self._buf = bytearray()
        self._failed: str | None = None

    @property
    def pending(self) -> int:
        """Bytes received but not yet part of a complete packet."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        if self._failed is not None:
            raise ProtocolError(f"stream already out of sync: {self._failed}")
        self._buf += data
        packets: list[bytes] = []
        while len(self._buf) >= 4:
            (size,) = struct.unpack_from("<i", self._buf, 0)
            if size < HEADER_SIZE or size > self.max_packet_bytes:
                self._failed = f"lPacketSize {size} outside {HEADER_SIZE}..{self.max_packet_bytes} bytes"
                self._buf.clear()
                raise ProtocolError(self._failed)
            if len(self._buf) < size:
                break
            packets.append(bytes(self._buf[:size]))
            del self._buf[:size]
        return packets
