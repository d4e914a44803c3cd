"""Leica AT901 laser tracker over emScon TPI (binary C variant, TCP port 700): implements interfaces.Tracker.

Wire format and enum values: drivers/emscon/enums.py, messages.py and framing.py (sources cited there: the Leica
emScon TPI V3.6 headers ES_C_API_Def.h / Enum.h in beckjac/emscon_ros and MuffinSpawn/Leica, and the CESAPI Python
client).

Conversation (one command at a time, under a lock):
- every command is answered by a packet of type ES_DT_Command with the same command id and an ES_ResultStatus
  (a *RT struct); StartMeasurement is answered twice: the acknowledgement, then a separate SingleMeasResultT
  (SingleMeasResult2T, type 9, if the tracker is in the extended statistic mode: both are read);
- error packets (ErrorResponseT) and system-status-change packets (SystemStatusChangeT) may arrive at any
  time, between or before answers. An error naming the pending command raises DeviceFault(code=status);
  an error naming another command is kept in `async_errors`; status changes are kept in `status_changes` and
  `last_status_change`; unsolicited reflector positions in `last_reflector_position`.
- a failure can come either as the command's own answer with a non-OK status or as an ErrorResponseT: both
  raise DeviceFault with the ES_ResultStatus as `code` and a message saying what it means and what was
  being done.

Every socket read runs against a deadline (DeviceTimeout names host:port and the action). After a timeout, a
connection loss or bytes that do not parse, the connection is closed: its byte stream can no longer be trusted
(a late answer would be taken for the next one). Call connect() again to resume.

`configure()` (on every connect(), and again whenever the campaign asks: at every station set-up and before
every point block) sets everything a measurement depends on, whatever a previous session or another client
left on the tracker, then reads each one back (Get*) and raises DeviceFault if the tracker reports something
else: the units (mm, degrees, Celsius, hPa, %RH), the Cartesian right-handed coordinate system type (ES_CS_RHR),
the stationary measurement mode, the standard statistic mode, the stationary measurement time once
set_stationary_averaging chose one, and the system settings: no user transformation and no station
orientation applied (results in the tracker's own frame), no try mode, unsolicited errors on, no reflector
position stream, the beam kept where it was when it is broken, the weather monitor as `weather_monitor` says,
bHasNivel / bHasVideoCamera left as the tracker reports them (they describe its hardware). A result still in
try mode or in another measurement mode is refused.

Not confirmed against a real AT901 (see also drivers/emscon/messages.py's docstring):
- the unit of StationaryModeDataT.lMeasTime is not written in the header; it is taken as milliseconds, the
  unit the same header gives for SearchParamsDataT.lTimeOut. `set_stationary_averaging(n)` asks for
  n / samples_per_second seconds (samples_per_second defaults to 1000, an assumption, not a datasheet value).
- whether a refusal comes as the *RT with a non-OK status or as an ErrorResponseT: both are handled.
- weather monitor: with ES_WMS_NotConnected (the default) the tracker is taken to compute refraction from the
  environment trackcal sets (SetEnvironmentParams, from its own meteo sensor); without one, configure
  ES_WMS_ReadAndCalculateRefractions. The header names the modes, not what each does with SetEnvironmentParams.
"""

from __future__ import annotations

import collections
import contextlib
import math
import socket
import threading
import time

from trackcal.drivers.emscon.enums import (
    CoordinateSystemType,
    MeasMode,
    MeasurementStatusInfo,
    ResultStatus,
    StatisticMode,
    SystemStatusChange,
    TrackerProcessorStatus,
    TrackerStatus,
    WeatherMonitorStatus,
)
from trackcal.drivers.emscon.framing import (
    Direction,
    PacketReader,
    decode_packet,
)
from trackcal.drivers.emscon.messages import (
    ANSWER_TYPES,
    Answer,
    ErrorResponse,
    FindReflector,
    FromTracker,
    GetCoordinateSystemType,
    GetMeasurementMode,
    GetMeasurementStatusInfo,
    GetStationaryModeParams,
    GetStatisticMode,
    GetSystemSettings,
    GetSystemSoftwareVersion,
    GetSystemStatus,
    GetTrackerInfo,
    GetTrackerStatus,
    GetUnits,
    GoBirdBath,
    GoPosition,
    Initialize,
    MeasurementStatusInfoAnswer,
    ReflectorPosResult,
    Request,
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
    SoftwareVersionAnswer,
    StartMeasurement,
    StatusChange,
    SystemStatusAnswer,
    TrackerInfoAnswer,
    TrackerStatusAnswer,
    encode_command,
)
from trackcal.drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout, ProtocolError, TargetNotVisible
from trackcal.drivers.interfaces import DeviceIdentity, Environment, TrackerMeasurement
from trackcal.drivers.interfaces import TrackerStatus as InterfaceTrackerStatus
from trackcal.drivers.transport import receive, require_positive

DEFAULT_PORT = 700  # the TCP port of emScon TPI's binary C variant
_RECV_BYTES = 65536

# What the ES_ResultStatus codes a campaign meets mean, in the operator's words. Names from
# ES_C_API_Def.h (see drivers/emscon/enums.py); the explanations are ours.
_FAULT_MESSAGES: dict[ResultStatus, str] = {
    ResultStatus.SERVER_BUSY: "tracker busy: another command is still pending",
    ResultStatus.NOT_IMPLEMENTED: "command not implemented by this tracker/server",
    ResultStatus.WRONG_PARAMETER: "wrong parameter",
    ResultStatus.WRONG_CURRENT_REFLECTOR: "wrong current reflector for this operation",
    ResultStatus.NO_DISTANCE_SET: "no distance set: the beam was broken, find the reflector again",
    ResultStatus.NO_TRACKER_CONNECTED: "no tracker (sensor) connected to the emScon server",
    ResultStatus.TRACKER_NOT_INITIALIZED: "tracker not initialised: run initialize() first",
    ResultStatus.MODULE_TIMED_OUT: "timed out inside the tracker",
    ResultStatus.METEO_DATA_OUT_OF_RANGE: "meteo data (temperature/pressure/humidity) out of range",
    ResultStatus.MEASUREMENT_STATUS_NOT_READY: "not ready to measure: no reflector locked "
    "(beam broken or reflector not found)",
    ResultStatus.NO_STATIONARY_RESULT: "no stationary result: the beam was broken during the measurement",
    ResultStatus.SENSOR_NOT_STABLE: "sensor not stable",
    ResultStatus.SENSOR_NOT_WARMED_UP: "sensor not warmed up",
    ResultStatus.SYSTEM_NOT_READY_FOR_MEASUREMENT: "system not ready for measurement",
    ResultStatus.COMMUNICATION_WITH_SENSOR_FAILED: "controller-sensor communication failed",
    ResultStatus.ADM_HARDWARE_PROBLEM: "ADM hardware problem",
    ResultStatus.ATR_HARDWARE_PROBLEM: "ATR hardware problem",
}
# "Parameter n out of range, OK" statuses: the tracker accepted the command (kept in `warnings`).
_ACCEPTED = frozenset(
    {ResultStatus.ALL_OK}
    | {s for s in ResultStatus if s.name.startswith("PARAMETER") and s.name.endswith("OUT_OF_RANGE_OK")}
)


# Each setting configure() makes and the Get* command that reads it back (their payloads are the same struct).
_READ_BACK: dict[type[Request], type[Request]] = {
    SetUnits: GetUnits,
    SetCoordinateSystemType: GetCoordinateSystemType,
    SetMeasurementMode: GetMeasurementMode,
    SetStatisticMode: GetStatisticMode,
    SetSystemSettings: GetSystemSettings,
    SetStationaryModeParams: GetStationaryModeParams,
}

# the statuses that mean "the reflector cannot be seen from here" (a campaign measures it from elsewhere)
_NOT_VISIBLE = frozenset(
    {ResultStatus.MEASUREMENT_STATUS_NOT_READY, ResultStatus.NO_STATIONARY_RESULT, ResultStatus.NO_DISTANCE_SET}
)


def fault_message(status: ResultStatus) -> str:
    """A clear sentence for an ES_ResultStatus code."""
    return _FAULT_MESSAGES.get(status, f"tracker reports {status.name}")


def fault(status: ResultStatus, what: str, device: str) -> DeviceFault:
    cls = TargetNotVisible if status in _NOT_VISIBLE else DeviceFault
    return cls(f"{fault_message(status)} while {what}", code=int(status), device=device)


class EmsconTracker:
    """A Leica AT901 (or any emScon TPI tracker) on `host:port`. Units: mm, degrees, Celsius, hPa, %RH."""

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        timeout_s: float = 5.0,
        measure_timeout_s: float = 60.0,
        motion_timeout_s: float = 120.0,
        search_timeout_s: float = 10.0,
        samples_per_second: float = 1000.0,
        weather_monitor: str = "not_connected",
    ) -> None:
        require_positive(
            timeout_s=timeout_s,
            measure_timeout_s=measure_timeout_s,
            motion_timeout_s=motion_timeout_s,
            search_timeout_s=search_timeout_s,
            samples_per_second=samples_per_second,
        )
        try:
            self.weather_monitor = WeatherMonitorStatus[weather_monitor.upper()]
        except KeyError:
            names = ", ".join(m.name.lower() for m in WeatherMonitorStatus)
            raise ValueError(f"weather_monitor must be one of {names}, got {weather_monitor!r}") from None
        self.host = host
        self.port = port
        self.timeout_s = timeout_s
        self.measure_timeout_s = measure_timeout_s
        self.motion_timeout_s = motion_timeout_s
        self.search_timeout_s = search_timeout_s
        self.samples_per_second = samples_per_second
        self.device = f"tracker {host}:{port}"
        self.last_status_change: SystemStatusChange | None = None
        self.status_changes: collections.deque[SystemStatusChange] = collections.deque(maxlen=256)
        self.async_errors: collections.deque[ErrorResponse] = collections.deque(maxlen=256)
        self.warnings: collections.deque[tuple[str, ResultStatus]] = collections.deque(maxlen=256)
        self.last_reflector_position: tuple[float, float, float] | None = None
        self.meas_time_ms: int | None = None  # the stationary measurement time chosen, re-set by configure()
        self._sock: socket.socket | None = None
        self._reader = PacketReader()
        self._inbox: collections.deque[FromTracker] = collections.deque()
        self._lock = threading.RLock()

    # -------------------- Tracker protocol
    def connect(self) -> None:
        with self._lock:
            if self._sock is not None:
                return
            try:
                sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
            except OSError as exc:  # refused, unreachable, timed out
                raise ConnectionLost(
                    f"cannot connect to {self.host} port {self.port} while connecting: {exc}",
                    device=self.device,
                ) from exc
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._sock = sock
            self._reader = PacketReader()
            self._inbox.clear()
            self.configure()

    def configure(self) -> None:
        """Set everything a measurement depends on and read it back (see the module docstring)."""
        with self._lock:
            hardware = self._read_setting(GetSystemSettings(), "reading the system settings")
            assert isinstance(hardware, SetSystemSettings)
            wanted: list[tuple[Request, str]] = [
                (SetUnits(), "the units (mm, deg, Celsius, hPa, %RH)"),
                (SetCoordinateSystemType(CoordinateSystemType.RHR), "the Cartesian coordinate system (RHR)"),
                (SetMeasurementMode(MeasMode.STATIONARY), "the stationary measurement mode"),
                (SetStatisticMode(StatisticMode.STANDARD, StatisticMode.STANDARD), "the standard statistic mode"),
                (
                    SetSystemSettings(
                        self.weather_monitor,
                        False,
                        False,
                        True,
                        True,
                        False,
                        False,
                        hardware.has_nivel,
                        hardware.has_video_camera,
                    ),
                    f"the system settings (weather monitor {self.weather_monitor.name}, no transformation, "
                    "no station orientation, no try mode)",
                ),
            ]
            if self.meas_time_ms is not None:
                wanted.append(
                    (
                        SetStationaryModeParams(self.meas_time_ms, use_adm=False),
                        f"the stationary measurement time ({self.meas_time_ms} ms)",
                    )
                )
            for request, what in wanted:
                self._command(request, f"setting {what}")
            for request, what in wanted:
                setting = self._read_setting(_READ_BACK[type(request)](), f"reading back {what}")
                if setting != request:
                    raise DeviceFault(
                        f"the tracker reports {setting} after setting {what} ({request})",
                        code="readback",
                        device=self.device,
                    )

    def _read_setting(self, request: Request, what: str) -> Request:
        """A Get* of a setting: the setting, as the Set* request that would set it."""
        answer = self._command(request, what)
        if not isinstance(answer, SettingAnswer):  # an accepted status without the payload
            self._fail(ProtocolError(f"answer to {request.COMMAND.name} without its setting while {what}"))
        return answer.setting

    def initialize(self) -> None:
        self._command(Initialize(), "initialising the tracker", self.motion_timeout_s)

    def set_environment(self, env: Environment) -> None:
        values = (env.temperature_c, env.pressure_hpa, env.humidity_pct)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"environment values must be finite: {env}")
        self._command(SetEnvironmentParams(*values), "setting the environment parameters")

    def set_reflector(self, reflector_id: int) -> None:
        self._command(SetReflector(int(reflector_id)), f"selecting reflector {reflector_id}")

    def set_stationary_averaging(self, n_samples: int) -> None:
        if n_samples < 1:
            raise ValueError("n_samples must be at least 1")
        meas_time_ms = max(1, round(n_samples * 1000.0 / self.samples_per_second))
        self._command(
            SetStationaryModeParams(meas_time_ms, use_adm=False),
            f"setting the stationary measurement time to {meas_time_ms} ms",
        )
        self.meas_time_ms = meas_time_ms

    def find_reflector(self, x_mm: float, y_mm: float, z_mm: float, search_radius_mm: float) -> None:
        """Point the beam at the expected reflector position (GoPosition, with ADM) and search around it."""
        if not all(math.isfinite(v) for v in (x_mm, y_mm, z_mm, search_radius_mm)) or search_radius_mm <= 0:
            raise ValueError("find_reflector needs a finite point and a positive search radius")
        self._command(
            SetSearchParams(search_radius_mm, round(self.search_timeout_s * 1000)),
            f"setting the search radius to {search_radius_mm} mm",
        )
        where = f"({x_mm:.3f}, {y_mm:.3f}, {z_mm:.3f}) mm"
        self._command(GoPosition(x_mm, y_mm, z_mm, use_adm=True), f"pointing at {where}", self.motion_timeout_s)
        distance = math.sqrt(x_mm * x_mm + y_mm * y_mm + z_mm * z_mm)
        self._command(
            FindReflector(distance),
            f"searching the reflector near {where}",
            self.motion_timeout_s + self.search_timeout_s,
        )

    def measure(self) -> TrackerMeasurement:
        what = "measuring (stationary)"
        with self._lock:
            self._transact(StartMeasurement(), what, self.timeout_s)  # the acknowledgement
            result = self._wait_for(
                StartMeasurement.COMMAND,
                (SingleMeasResult, SingleMeasResult2),
                time.monotonic() + self.measure_timeout_s,
                what,
                self.measure_timeout_s,
            )
        assert isinstance(result, SingleMeasResult | SingleMeasResult2)
        if result.status not in _ACCEPTED:
            raise fault(result.status, what, self.device)
        if result.status != ResultStatus.ALL_OK:
            self.warnings.append((what, result.status))
        if result.meas_mode != MeasMode.STATIONARY:
            self._fail(ProtocolError(f"measurement result in mode {result.meas_mode.name}, expected STATIONARY"))
        if result.is_try_mode:
            raise DeviceFault(
                "the tracker sent a try-mode result (bTryMeasurementMode set by another client?) while measuring",
                code="try_mode",
                device=self.device,
            )
        return TrackerMeasurement(
            result.val1,
            result.val2,
            result.val3,
            result.std1,
            result.std2,
            result.std3,
            Environment(result.temperature, result.pressure, result.humidity),
        )

    def status(self) -> InterfaceTrackerStatus:
        with self._lock:
            system = self._command(GetSystemStatus(), "reading the system status")
            tracker = self._command(GetTrackerStatus(), "reading the tracker status")
            info = self._command(GetMeasurementStatusInfo(), "reading the measurement status")
        assert isinstance(system, SystemStatusAnswer)
        assert isinstance(tracker, TrackerStatusAnswer)
        assert isinstance(info, MeasurementStatusInfoAnswer)
        initialized = system.tracker_processor_status == TrackerProcessorStatus.INITIALIZED
        locked = bool(info.info & MeasurementStatusInfo.REFLECTOR_FOUND)
        detail = (
            f"processor={system.tracker_processor_status.name} laser={system.laser_status.name} "
            f"adm={system.adm_status.name} tracker={tracker.tracker_status.name} "
            f"last_result={system.last_result_status.name} serial={system.tracker_serial_number}"
        )
        if self.last_status_change is not None:
            detail += f" last_status_change={self.last_status_change.name}"
        return InterfaceTrackerStatus(initialized, locked, tracker.tracker_status == TrackerStatus.BUSY, detail)

    def go_birdbath(self) -> None:
        self._command(GoBirdBath(), "driving to the bird bath", self.motion_timeout_s)

    def identity(self) -> DeviceIdentity:
        """Who the tracker says it is (for the certificate, #39): GetTrackerInfo's type, name, serial number and LCP
        firmware, and GetSystemSoftwareVersion's server software, which servers before TPI V3.6 do not know (their
        ES_RS_NotImplemented leaves it out)."""
        with self._lock:
            info = self._command(GetTrackerInfo(), "reading the tracker's identity (GetTrackerInfo)")
            try:
                sw = self._command(GetSystemSoftwareVersion(), "reading the emScon server's software version")
            except DeviceFault as exc:
                if exc.code != ResultStatus.NOT_IMPLEMENTED:
                    raise
                sw = None
        assert isinstance(info, TrackerInfoAnswer) and (sw is None or isinstance(sw, SoftwareVersionAnswer))
        model = info.tracker_name or info.tracker_type.name
        software = "LCP firmware {}.{}".format(*info.lcp_firmware) + (f", emScon {sw.version}" if sw else "")
        return DeviceIdentity(str(info.serial_number), f"{model} (ES_LTSensorType {int(info.tracker_type)})", software)

    def close(self) -> None:
        with self._lock:
            sock, self._sock = self._sock, None
            self._inbox.clear()
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.close()

    def __enter__(self) -> EmsconTracker:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -------------------- internals
    def _command(self, request: Request, what: str, timeout_s: float | None = None) -> Answer:
        with self._lock:
            return self._transact(request, what, self.timeout_s if timeout_s is None else timeout_s)

    def _transact(self, request: Request, what: str, timeout_s: float) -> Answer:
        """Send `request`, return its accepted answer or raise; packets arriving meanwhile are recorded."""
        sock = self._require(what)
        try:
            sock.sendall(encode_command(request))
        except OSError as exc:
            self.close()
            raise ConnectionLost(f"send failed while {what}: {exc}", device=self.device) from exc
        answer = self._wait_for(
            request.COMMAND,
            ANSWER_TYPES,
            time.monotonic() + timeout_s,
            what,
            timeout_s,
        )
        if answer.command != request.COMMAND:
            self._fail(ProtocolError(f"answer to {answer.command.name} while {what} (expected {request.COMMAND.name})"))
        if answer.status not in _ACCEPTED:
            raise fault(answer.status, what, self.device)
        if answer.status != ResultStatus.ALL_OK:
            self.warnings.append((what, answer.status))
        return answer  # type: ignore[return-value]

    def _wait_for(self, pending, wanted: tuple[type, ...], deadline: float, what: str, timeout_s: float):
        while True:
            msg = self._next_message(deadline, what, timeout_s)
            if isinstance(msg, StatusChange):
                self.last_status_change = msg.change
                self.status_changes.append(msg.change)
            elif isinstance(msg, ReflectorPosResult):
                self.last_reflector_position = (msg.val1, msg.val2, msg.val3)
            elif isinstance(msg, ErrorResponse):
                if msg.command == pending:
                    raise fault(msg.status, what, self.device)
                self.async_errors.append(msg)
            elif isinstance(msg, wanted):
                return msg
            else:
                self._fail(ProtocolError(f"unexpected {type(msg).__name__} while {what}"))

    def _next_message(self, deadline: float, what: str, timeout_s: float) -> FromTracker:
        while not self._inbox:
            data = receive(
                self._require(what),
                _RECV_BYTES,
                deadline - time.monotonic(),
                device=self.device,
                failed=f"receive failed while {what}",
                closed=f"the tracker closed the connection while {what}",
                drop=self.close,
            )
            if data is None:
                self.close()
                raise DeviceTimeout(f"no answer within {timeout_s} s while {what}", device=self.device)
            try:
                for packet in self._reader.feed(data):
                    self._inbox.append(decode_packet(packet, Direction.FROM_TRACKER))  # type: ignore[arg-type]
            except ProtocolError as exc:
                self._fail(ProtocolError(f"{exc} while {what}"))
        return self._inbox.popleft()

    def _require(self, what: str) -> socket.socket:
        if self._sock is None:
            raise ConnectionLost(f"not connected (call connect()) while {what}", device=self.device)
        return self._sock

    def _fail(self, exc: ProtocolError):
        self.close()
        raise ProtocolError(str(exc), device=self.device)
