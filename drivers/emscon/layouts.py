"""The wire layout of every emScon TPI command, request and answer: the source of truth for packet sizes.

Written from [H] beckjac/emscon_ros include/emscon_ros/ES_C_API_Def.h (TPI/SDK V3.6, the full header for all
tracker types), one entry per value of its `enum ES_Command`: the name, the struct format of what follows
BasicCommandCT in the *CT request and of what follows BasicCommandRT in the *RT answer. `#pragma pack (push, 4)`
and no member wider than 4 bytes before a double means no padding (Python struct "<" adds none either);
`long` and every enum and ES_BOOL are 4 bytes on the wire ([H] redefines long as int32_t for this reason);
`unsigned short c...[32]` UNICODE strings are "32H". The one exception is GetStillImageRT, whose trailing
`char cFileStart` opens a variable-length image: its fixed part is padded to the 4-byte pack ("ii" + 1 + 3).

Nothing here interprets a value: drivers/emscon/messages.py does that for the commands trackcal speaks; the mock
uses the sizes to answer every other command in the answer packet of that command (mocks/servers/emscon.py).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

CT_PREFIX = "<iii"  # BasicCommandCT {PacketHeaderT {long lPacketSize; ES_DataType type}; ES_Command command}
RT_PREFIX = "<iiii"  # BasicCommandRT {PacketHeaderT; ES_Command command; ES_ResultStatus status}


@dataclass(frozen=True)
class CommandLayout:
    name: str  # ES_C_<name>
    request: str  # struct format after BasicCommandCT
    answer: str  # struct format after BasicCommandRT

    @property
    def request_size(self) -> int:
        return struct.calcsize(CT_PREFIX + self.request)

    @property
    def answer_size(self) -> int:
        return struct.calcsize(RT_PREFIX + self.answer)


_NAME = "32H"  # unsigned short c...[32]
_COMMENT = "128H"  # unsigned short c...[128]

# ES_Command value -> layout, in the header's order ([H], `enum ES_Command` and the *CT / *RT structs).
# Values 50, 64 (ES_C_Unknown has no structs) and 141 are not commands.
LAYOUTS: dict[int, CommandLayout] = {
    0: CommandLayout("ExitApplication", "", ""),
    1: CommandLayout("GetSystemStatus", "", "iiii" + "iii" + "iii"),  # ..ESVersionNumberT, wms, flags, serial
    2: CommandLayout("GetTrackerStatus", "", "i"),
    3: CommandLayout("SetTemperatureRange", "i", ""),
    4: CommandLayout("GetTemperatureRange", "", "i"),
    5: CommandLayout("SetUnits", "iiiii", ""),  # SystemUnitsDataT
    6: CommandLayout("GetUnits", "", "iiiii"),
    7: CommandLayout("Initialize", "", ""),
    8: CommandLayout("ReleaseMotors", "", ""),
    9: CommandLayout("ActivateCameraView", "", ""),
    10: CommandLayout("Park", "", ""),
    11: CommandLayout("SwitchLaser", "i", ""),
    12: CommandLayout("SetStationOrientationParams", "6d", ""),  # StationOrientationDataT
    13: CommandLayout("GetStationOrientationParams", "", "6d"),
    14: CommandLayout("SetTransformationParams", "7d", ""),  # TransformationDataT
    15: CommandLayout("GetTransformationParams", "", "7d"),
    16: CommandLayout("SetBoxRegionParams", "6d", ""),  # BoxRegionDataT
    17: CommandLayout("GetBoxRegionParams", "", "6d"),
    18: CommandLayout("SetSphereRegionParams", "4d", ""),  # SphereRegionDataT
    19: CommandLayout("GetSphereRegionParams", "", "4d"),
    20: CommandLayout("SetEnvironmentParams", "3d", ""),  # EnvironmentDataT
    21: CommandLayout("GetEnvironmentParams", "", "3d"),
    22: CommandLayout("SetRefractionParams", "2d", ""),  # RefractionDataT
    23: CommandLayout("GetRefractionParams", "", "2d"),
    24: CommandLayout("SetMeasurementMode", "i", ""),
    25: CommandLayout("GetMeasurementMode", "", "i"),
    26: CommandLayout("SetCoordinateSystemType", "i", ""),
    27: CommandLayout("GetCoordinateSystemType", "", "i"),
    28: CommandLayout("SetStationaryModeParams", "ii", ""),  # StationaryModeDataT
    29: CommandLayout("GetStationaryModeParams", "", "ii"),
    30: CommandLayout("SetContinuousTimeModeParams", "iiii", ""),  # ContinuousTimeModeDataT
    31: CommandLayout("GetContinuousTimeModeParams", "", "iiii"),
    32: CommandLayout("SetContinuousDistanceModeParams", "diii", ""),  # ContinuousDistanceModeDataT
    33: CommandLayout("GetContinuousDistanceModeParams", "", "diii"),
    34: CommandLayout("SetSphereCenterModeParams", "diid", ""),  # SphereCenterModeDataT
    35: CommandLayout("GetSphereCenterModeParams", "", "diid"),
    36: CommandLayout("SetCircleCenterModeParams", "diid", ""),  # CircleCenterModeDataT
    37: CommandLayout("GetCircleCenterModeParams", "", "diid"),
    38: CommandLayout("SetGridModeParams", "dddiii", ""),  # GridModeDataT
    39: CommandLayout("GetGridModeParams", "", "dddiii"),
    40: CommandLayout("SetReflector", "i", ""),
    41: CommandLayout("GetReflector", "", "i"),
    42: CommandLayout("GetReflectors", "", "iiid" + _NAME),  # one packet per reflector
    43: CommandLayout("SetSearchParams", "di", ""),  # SearchParamsDataT
    44: CommandLayout("GetSearchParams", "", "di"),
    45: CommandLayout("SetAdmParams", "dii", ""),  # AdmParamsDataT
    46: CommandLayout("GetAdmParams", "", "dii"),
    47: CommandLayout("SetSystemSettings", "9i", ""),  # SystemSettingsDataT
    48: CommandLayout("GetSystemSettings", "", "9i"),
    49: CommandLayout("StartMeasurement", "", ""),
    51: CommandLayout("StartNivelMeasurement", "", ""),
    52: CommandLayout("StopMeasurement", "", ""),
    53: CommandLayout("ChangeFace", "", ""),
    54: CommandLayout("GoBirdBath", "", ""),
    55: CommandLayout("GoPosition", "dddi", ""),
    56: CommandLayout("GoPositionHVD", "dddi", ""),
    57: CommandLayout("PositionRelativeHV", "dd", ""),
    58: CommandLayout("PointLaser", "ddd", ""),
    59: CommandLayout("PointLaserHVD", "ddd", ""),
    60: CommandLayout("MoveHV", "ii", ""),
    61: CommandLayout("GoNivelPosition", "i", ""),
    62: CommandLayout("GoLastMeasuredPoint", "", ""),
    63: CommandLayout("FindReflector", "d", ""),
    65: CommandLayout("LookForTarget", "dddd", "dd"),
    66: CommandLayout("GetDirection", "", "dd"),
    67: CommandLayout("CallOrientToGravity", "", "dd"),
    68: CommandLayout("ClearTransformationNominalPointList", "", ""),
    69: CommandLayout("ClearTransformationActualPointList", "", ""),
    70: CommandLayout("AddTransformationNominalPoint", "9d", ""),  # TransformationPointT
    71: CommandLayout("AddTransformationActualPoint", "9d", ""),
    72: CommandLayout("SetTransformationInputParams", "i14d", ""),  # TransformationInputDataT
    73: CommandLayout("GetTransformationInputParams", "", "i14d"),
    74: CommandLayout("CallTransformation", "", "17d"),
    75: CommandLayout("GetTransformedPoints", "", "i13d"),  # one packet per point
    76: CommandLayout("ClearDrivePointList", "", ""),
    77: CommandLayout("AddDrivePoint", "iddd", ""),
    78: CommandLayout("CallIntermediateCompensation", "", "ddi"),
    79: CommandLayout("SetCompensation", "i", ""),
    80: CommandLayout("SetStatisticMode", "ii", ""),  # stationaryMeasurements, continuousMeasurements
    81: CommandLayout("GetStatisticMode", "", "ii"),
    82: CommandLayout("GetStillImage", "i", "iib3x"),  # + the image bytes (variable length)
    83: CommandLayout("SetCameraParams", "iii", ""),  # CameraParamsDataT
    84: CommandLayout("GetCameraParams", "", "iii"),
    85: CommandLayout("GetCompensation", "", "i"),
    86: CommandLayout("GetCompensations", "", "ii" + _NAME + _COMMENT + _NAME + "i"),
    87: CommandLayout("CheckBirdBath", "", "6d"),
    88: CommandLayout("GetTrackerDiagnostics", "", "10d" + "i" + "d" + "ii"),
    89: CommandLayout("GetADMInfo", "", "iii"),
    90: CommandLayout("GetTPInfo", "", "10i"),
    91: CommandLayout("GetNivelInfo", "", "iii"),
    92: CommandLayout("SetLaserOnTimer", "ii", ""),
    93: CommandLayout("GetLaserOnTimer", "", "ii"),
    94: CommandLayout("ConvertDisplayCoordinates", "iddd", "ddd"),
    95: CommandLayout("GoBirdBath2", "i", ""),
    96: CommandLayout("SetTriggerSource", "i", ""),
    97: CommandLayout("GetTriggerSource", "", "i"),
    98: CommandLayout("GetFace", "", "i"),
    99: CommandLayout("GetCameras", "", "iiii" + _NAME + _COMMENT),
    100: CommandLayout("GetCamera", "", "ii"),
    101: CommandLayout("SetMeasurementCameraMode", "i", ""),
    102: CommandLayout("GetMeasurementCameraMode", "", "i"),
    103: CommandLayout("GetProbes", "", "iiiii" + _NAME + _COMMENT),
    104: CommandLayout("GetProbe", "", "i"),
    105: CommandLayout("GetTipAdapters", "", "iiiiii" + "dd" + _NAME + _COMMENT),
    106: CommandLayout("GetTipAdapter", "", "ii"),
    107: CommandLayout("GetTCamToTrackerCompensations", "", "iiiiii" + _NAME + _COMMENT),
    108: CommandLayout("GetTCamToTrackerCompensation", "", "i"),
    109: CommandLayout("SetTCamToTrackerCompensation", "i", ""),
    110: CommandLayout("GetProbeCompensations", "", "iiiiiii" + _NAME + _COMMENT),
    111: CommandLayout("GetProbeCompensation", "", "i"),
    112: CommandLayout("SetProbeCompensation", "i", ""),
    113: CommandLayout("GetTipToProbeCompensations", "", "iiiiii" + _NAME + _COMMENT),
    114: CommandLayout("GetTipToProbeCompensation", "", "i"),
    115: CommandLayout("SetExternTriggerParams", "iiii", ""),  # ExternTriggerParamsT
    116: CommandLayout("GetExternTriggerParams", "", "iiii"),
    117: CommandLayout("GetErrorEllipsoid", "9d", "6d"),
    118: CommandLayout("GetMeasurementCameraInfo", "", "iiii" + _NAME + "iiiii" + "dd" + "ii" + "dd" + "i"),
    119: CommandLayout("GetMeasurementProbeInfo", "", "14i"),
    120: CommandLayout("SetLongSystemParameter", "ii", ""),  # SetLongSystemParamCT
    121: CommandLayout("GetLongSystemParameter", "i", "ii"),
    122: CommandLayout("GetMeasurementStatusInfo", "", "ii"),
    123: CommandLayout("GetCompensations2", "", "ii" + _NAME + _COMMENT + _NAME + _COMMENT + "ii"),
    124: CommandLayout("GetCurrentPrismPosition", "", "ddd"),
    125: CommandLayout("SetDoubleSystemParameter", "id", ""),
    126: CommandLayout("GetDoubleSystemParameter", "i", "id"),
    127: CommandLayout("GetObjectTemperature", "", "d"),
    128: CommandLayout("GetTriggerBoardInfo", "", "iiii"),
    129: CommandLayout("GetOverviewCameraInfo", "", "i" + _NAME + "i" + "ddd" + "ii"),
    130: CommandLayout("ClearCommandQueue", "i", ""),
    131: CommandLayout("GetADMInfo2", "", "i" + _NAME + "iii" + "dd" + "i" + "d"),
    132: CommandLayout("GetTrackerInfo", "", "i" + _NAME + "iiiii" + "ddd" + "ii" + "dd" + "iii"),
    133: CommandLayout("GetNivelInfo2", "", "i" + _NAME + "iii" + "ddd"),
    134: CommandLayout("RestoreStartupConditions", "", ""),
    135: CommandLayout("GoAndMeasure", "ddd", ""),
    136: CommandLayout("GetTipToProbeCompensations2", "", "7i" + _NAME + _COMMENT + _NAME),
    137: CommandLayout("SetTipAdapter", "i", ""),
    138: CommandLayout("GetATRInfo", "", "i" + _NAME + "6i" + "4d"),
    139: CommandLayout("GetMeteoStationInfo", "", "i" + _NAME + "ii"),
    140: CommandLayout("GetAT4xxInfo", "", "i" + _NAME + "13i" + "6d"),
    142: CommandLayout("GetSystemSoftwareVersion", "", _NAME),
}
