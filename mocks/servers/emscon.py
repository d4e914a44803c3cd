"""Mock Leica emScon TPI server (AT901-like) on a real loopback TCP socket, framing with drivers.emscon.framing
(the client's PacketReader) and speaking drivers.emscon.messages.

    server = MockEmscon(measure_fn, VirtualClock()).start()
    host, port = server.address
    server.inject(EmsconFault.BEAM_BREAK)      # one-shot faults, in order of injection
    server.silent = True                       # persistent: never answer
    server.stop()

`measure_fn(expected_xyz_mm_or_None) -> (x, y, z, sx, sy, sz)` in mm gives every measured value (the digital
twin plugs in here); `expected` is the last GoPosition target in mm (None after GoBirdBath or before any).
The stationary measurement takes `meas_time_ms` of simulated time on the injected clock; Initialize,
GoPosition, FindReflector and GoBirdBath take `motion_time_s` (VirtualClock in tests: instant).

Behaviour (what a real server answers is assumed where the public headers do not say; see drivers/emscon/client.py):
- a refused command is answered with its own *RT and a non-OK ES_ResultStatus: StartMeasurement, GoPosition,
  FindReflector, GoBirdBath before Initialize -> ES_RS_TrackerNotInitialized (39); StartMeasurement without a
  locked reflector -> ES_RS_MeasurementStatusNotReady (10004); FindReflector when no reflector is there
  (`reflector_present = False`) -> ES_RS_MeasurementStatusNotReady (10004) after the search time-out;
- a beam break during a measurement: the acknowledgement, then a SystemStatusChange
  ES_SSC_MeasStatus_NotReady, then an ErrorResponseT {StartMeasurement, ES_RS_NoStationaryResult (10009)};
  the lock is lost;
- every accepted setting is followed by the matching SystemStatusChange (ES_SSC_UnitsChanged, ...), sent after
  the answer, so clients always meet status changes between answers;
- units and coordinate system types: the server starts in metres (an assumption) and converts every length,
  angle, temperature and pressure it reads or sends for every unit of SetUnits and every ES_CoordinateSystemType
  (mocks/servers/emscon_units.py; the conventions of the non-rectangular types are assumed there);
- statistic mode: ES_SM_Standard stationary results are SingleMeasResultT (type 2), ES_SM_Extended ones
  SingleMeasResult2T (type 9, 204 bytes); the system settings are kept, and bTryMeasurementMode marks every
  result as a try-mode result; the Get* commands of these settings read them back;
- identity (#39): GetTrackerInfo and GetSystemSoftwareVersion answer `identity` (mocks/servers/emscon_identity.py:
  the twin's tracker), lengths and angles in the units set; GetSystemStatus carries its serial number;
- only the stationary measurement mode is implemented: SetMeasurementMode of another is ES_RS_NotImplemented;
- a command the mock does not implement is answered, and the connection kept, with ES_RS_NotImplemented (2) in
  that command's *RT, full size, zeroed payload (drivers/emscon/messages.encode_refusal: the layouts of every
  ES_Command in drivers/emscon/layouts.py); a request it implements but cannot read (a wrong size, a value
  outside its enum) with ES_RS_WrongParameter (3) the same way; a packet that is no command, or an id that is
  no ES_Command, with a bare BasicCommandRT carrying the id it had (ES_C_Unknown, 64, if it had none) and
  ES_RS_NotImplemented. [H] gives the layouts and the status values, not this behaviour: assumed;
- only a size field out of range (below the 8-byte header or above MAX_PACKET_BYTES) closes that connection,
  since no reader can find the next packet after it; the server keeps accepting.
"""

from __future__ import annotations

import collections
import contextlib
import enum
import math
import socket
import threading
from collections.abc import Callable

from trackcal.drivers.emscon.enums import (
    ADMStatus,
    CoordinateSystemType,
    DataType,
    LaserProcessorStatus,
    LengthUnit,
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
    encode,
    packet_ids,
)
from trackcal.drivers.emscon.messages import (
    REQUEST_TYPES,
    CommandAnswer,
    ErrorResponse,
    FindReflector,
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
    Message,
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
    StartMeasurement,
    StatusChange,
    SystemStatusAnswer,
    TrackerStatusAnswer,
    encode_refusal,
)
from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.interfaces import Environment, RealClock
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers import emscon_units as units
from trackcal.mocks.servers.emscon_identity import DEFAULT_IDENTITY, TrackerIdentity

MeasureFn = Callable[[tuple[float, float, float] | None], tuple[float, float, float, float, float, float]]

_COMMANDS_READ = frozenset(int(c) for c in REQUEST_TYPES)  # the commands whose requests the mock decodes
_UNKNOWN_COMMAND = 64  # ES_C_Unknown [H]
# ESVersionNumberT reported: the TPI version of the headers the codec follows (V3.6)
_VERSION = (3, 6, 0)
_POLL_S = 0.05  # how often blocked threads look at the stop flag
# ISO 2533 standard atmosphere at sea level (20 degC is the ISO 1 reference temperature), 50 %RH mid-range
STANDARD_ENVIRONMENT = Environment(20.0, 1013.25, 50.0)


class EmsconFault(enum.Enum):
    BEAM_BREAK = "beam_break"  # next StartMeasurement: ack, status change, ErrorResponseT NoStationaryResult
    DROP_CONNECTION = "drop"  # next request: the connection is closed without an answer
    MALFORMED_PACKET = "malformed"  # next request: answered by a packet whose lPacketSize is absurd
    STATUS_CHANGE = "status_change"  # next request: an unsolicited SystemStatusChange before the answer
    ASYNC_ERROR = "async_error"  # next request: an ErrorResponseT for another command before the answer


class MockEmscon:
    def __init__(
        self,
        measure_fn: MeasureFn,
        clock: VirtualClock | RealClock,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        environment: Environment = STANDARD_ENVIRONMENT,
        reflector_present: bool | Callable[[], bool] = True,
        motion_time_s: float = 2.0,
        identity: TrackerIdentity = DEFAULT_IDENTITY,
        dribble: bool = False,
        coalesce: bool = False,
    ) -> None:
        self.measure_fn = measure_fn
        self.clock = clock
        self._bind = (host, port)
        self.reflector_present = reflector_present
        self.motion_time_s = motion_time_s
        self.identity = identity  # GetTrackerInfo, GetSystemSoftwareVersion, GetSystemStatus's serial number
        self.dribble = dribble  # send every byte in its own segment
        self.coalesce = coalesce  # send everything a request causes in a single segment
        self.silent = False  # read requests, never answer
        self.environment = environment
        # tracker state (shared by all connections: there is one tracker)
        self.initialized = False
        self.locked = False
        self.units = SetUnits(LengthUnit.METER)
        self.coordinate_system = CoordinateSystemType.RHR
        self.meas_mode = MeasMode.STATIONARY
        self.statistic = SetStatisticMode(StatisticMode.STANDARD, StatisticMode.STANDARD)
        # a plausible power-on state (an assumption): no weather monitor, raw station frame, errors reported
        self.system_settings = SetSystemSettings(
            WeatherMonitorStatus.NOT_CONNECTED, False, False, True, True, False, False, False, False
        )
        self.meas_time_ms = 1000
        self.reflector_id = 0
        self.search_radius = 0.0
        self.search_timeout_ms = 10000
        self.expected_mm: tuple[float, float, float] | None = None
        self.last_result_status = ResultStatus.ALL_OK
        # observation hooks for tests
        self.received: list[Request] = []
        self.refused: list[tuple[int, ResultStatus]] = []  # (command id, status) of packets it could not read
        self.connections_accepted = 0
        self.connections_dropped_on_garbage = 0
        self._faults: collections.deque[EmsconFault] = collections.deque()
        self._state_lock = threading.RLock()
        self._stop = threading.Event()
        self._listener: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._conns: set[socket.socket] = set()

    # -------------------- lifecycle
    @property
    def address(self) -> tuple[str, int]:
        if self._listener is None:
            raise RuntimeError("server not started")
        host, port = self._listener.getsockname()[:2]
        return host, port

    def start(self) -> MockEmscon:
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(self._bind)
        listener.listen(8)
        listener.settimeout(_POLL_S)
        self._listener = listener
        self._spawn(self._accept_loop, "emscon-mock-accept")
        return self

    def stop(self) -> None:
        self._stop.set()
        with self._state_lock:
            conns = list(self._conns)
        for conn in conns:
            _close(conn)
        for thread in self._threads:
            thread.join(timeout=2.0)
        if self._listener is not None:
            _close(self._listener)

    def __enter__(self) -> MockEmscon:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    # -------------------- test hooks
    def inject(self, fault: EmsconFault) -> None:
        """Arm a one-shot fault; several are consumed in the order they were injected."""
        with self._state_lock:
            self._faults.append(fault)

    def set_environment(self, env: Environment) -> None:
        with self._state_lock:
            self.environment = env

    def _take_fault(self, *kinds: EmsconFault) -> EmsconFault | None:
        with self._state_lock:
            if self._faults and self._faults[0] in kinds:
                return self._faults.popleft()
        return None

    # -------------------- threads
    def _spawn(self, target, name: str, *args) -> None:
        thread = threading.Thread(target=target, args=args, name=name, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _accept_loop(self) -> None:
        assert self._listener is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(_POLL_S)
            with self._state_lock:
                self._conns.add(conn)
                self.connections_accepted += 1
            self._spawn(self._serve, f"emscon-mock-conn-{self.connections_accepted}", conn)

    def _serve(self, conn: socket.socket) -> None:
        reader = PacketReader()
        try:
            while not self._stop.is_set():
                try:
                    data = conn.recv(65536)
                except TimeoutError:
                    continue
                if not data:
                    return
                try:
                    packets = reader.feed(data)
                except ProtocolError:  # a size field out of range: the stream cannot be framed any more
                    with self._state_lock:
                        self.connections_dropped_on_garbage += 1
                    return
                for packet in packets:
                    try:
                        request = decode_packet(packet, Direction.TO_TRACKER)
                    except ProtocolError:
                        self._refuse(conn, packet)
                        continue
                    assert isinstance(request, Request)
                    if not self._handle(conn, request):
                        return
        except OSError:
            return
        finally:
            with self._state_lock:
                self._conns.discard(conn)
            _close(conn)

    # -------------------- protocol
    def _refuse(self, conn: socket.socket, packet: bytes) -> None:
        """Answer a framed packet the codec cannot read (see the module docstring) and keep the connection."""
        data_type, command_id = packet_ids(packet)
        if command_id is None:
            command_id = _UNKNOWN_COMMAND
        is_read = data_type == DataType.COMMAND and command_id in _COMMANDS_READ
        status = ResultStatus.WRONG_PARAMETER if is_read else ResultStatus.NOT_IMPLEMENTED
        with self._state_lock:
            self.refused.append((command_id, status))
            self.last_result_status = status
        if not self.silent:
            self._send(conn, [encode_refusal(command_id, status)])

    def _handle(self, conn: socket.socket, request: Request) -> bool:
        """Answer one request. Returns False when the connection is to be closed."""
        with self._state_lock:
            self.received.append(request)
        if self.silent:
            return True
        if self._take_fault(EmsconFault.DROP_CONNECTION):
            return False
        out: list[bytes] = []
        if self._take_fault(EmsconFault.MALFORMED_PACKET):
            # lPacketSize = 3 is below the header size: no client can frame past it
            self._send(conn, [(3).to_bytes(4, "little") + bytes(12)])
            return True
        if self._take_fault(EmsconFault.STATUS_CHANGE):
            out.append(encode(StatusChange(SystemStatusChange.MEAS_STATUS_BUSY)))
        if self._take_fault(EmsconFault.ASYNC_ERROR):
            out.append(encode(ErrorResponse(GetSystemStatus.COMMAND, ResultStatus.UNKNOWN)))
        for message in self._respond(request, conn, out):
            out.append(encode(message))
        self._send(conn, out)
        return True

    def _respond(self, request: Request, conn: socket.socket, out: list[bytes]) -> list[Message]:
        """The packets answering `request` (its handler of _HANDLERS). Long operations advance the clock;
        StartMeasurement flushes its acknowledgement before the measurement time passes (unless coalescing)."""
        needs_init = (StartMeasurement, GoPosition, FindReflector, GoBirdBath)
        if isinstance(request, needs_init) and not self.initialized:
            return self._answer(request, ResultStatus.TRACKER_NOT_INITIALIZED)
        if isinstance(request, StartMeasurement):
            return self._measure(conn, out)
        readback = self._readback(request)
        if readback is not None:
            return [SettingAnswer(request.COMMAND, ResultStatus.ALL_OK, readback)]
        handler = next((_HANDLERS[t] for t in type(request).__mro__ if t in _HANDLERS), None)
        assert handler is not None, f"no answer for {request}"
        return handler(self, request)

    def _answer(self, request: Request, status: ResultStatus, *after: Message) -> list[Message]:
        """The request's CommandAnswer with `status` (remembered as the last result), then `after`."""
        self.last_result_status = status
        return [CommandAnswer(request.COMMAND, status), *after]

    def _changed(self, request: Request, change: SystemStatusChange) -> list[Message]:
        return self._answer(request, ResultStatus.ALL_OK, StatusChange(change))

    def _initialize(self, request: Initialize) -> list[Message]:
        self.clock.sleep(self.motion_time_s)
        with self._state_lock:
            self.initialized, self.locked = True, False
        return self._changed(request, SystemStatusChange.INITIALIZATION_STATUS_CHANGED)

    def _system_status(self, request: GetSystemStatus) -> list[Message]:
        processor = TrackerProcessorStatus.INITIALIZED if self.initialized else TrackerProcessorStatus.COMPENSATION_SET
        return [
            SystemStatusAnswer(
                ResultStatus.ALL_OK,
                self.last_result_status,
                processor,
                LaserProcessorStatus.LASER_READY,
                ADMStatus.ADM_READY,
                _VERSION,
                self.system_settings.weather_monitor,
                0,
                self.identity.serial_number,
            )
        ]

    def _tracker_info(self, request: GetTrackerInfo) -> list[Message]:
        return [self.identity.tracker_info(self.units)]

    def _software_version(self, request: GetSystemSoftwareVersion) -> list[Message]:
        return [self.identity.software_version()]

    def _tracker_status(self, request: GetTrackerStatus) -> list[Message]:
        state = TrackerStatus.READY if self.initialized else TrackerStatus.NOT_READY
        return [TrackerStatusAnswer(ResultStatus.ALL_OK, state)]

    def _measurement_status(self, request: GetMeasurementStatusInfo) -> list[Message]:
        flags = (
            MeasurementStatusInfo.TRACKER_FOUND
            | MeasurementStatusInfo.TRACKER_COMPENSATION_FOUND
            | MeasurementStatusInfo.ADM_FOUND
            | MeasurementStatusInfo.ADM_COMPENSATION_FOUND
        )
        if self.locked:
            flags |= MeasurementStatusInfo.REFLECTOR_FOUND
        if self.initialized:
            flags |= MeasurementStatusInfo.INITIALIZED
        return [MeasurementStatusInfoAnswer(ResultStatus.ALL_OK, self.last_result_status, int(flags))]

    def _set_units(self, request: SetUnits) -> list[Message]:
        with self._state_lock:
            self.units = request
        return self._changed(request, SystemStatusChange.UNITS_CHANGED)

    def _set_coordinate_system(self, request: SetCoordinateSystemType) -> list[Message]:
        with self._state_lock:
            self.coordinate_system = request.coordinate_system
        return self._changed(request, SystemStatusChange.COORDINATE_SYSTEM_TYPE_CHANGED)

    def _set_measurement_mode(self, request: SetMeasurementMode) -> list[Message]:
        if request.mode != MeasMode.STATIONARY:
            return self._answer(request, ResultStatus.NOT_IMPLEMENTED)
        self.meas_mode = request.mode
        return self._changed(request, SystemStatusChange.MEASUREMENT_MODE_CHANGED)

    def _set_statistic_mode(self, request: SetStatisticMode) -> list[Message]:
        with self._state_lock:
            self.statistic = request
        return self._changed(request, SystemStatusChange.STATISTIC_MODE_CHANGED)

    def _set_system_settings(self, request: SetSystemSettings) -> list[Message]:
        with self._state_lock:
            self.system_settings = request
        return self._changed(request, SystemStatusChange.SYSTEM_SETTINGS_CHANGED)

    def _set_stationary_params(self, request: SetStationaryModeParams) -> list[Message]:
        if request.meas_time_ms <= 0:
            return self._answer(request, ResultStatus.PARAMETER1_OUT_OF_RANGE_NOK)
        self.meas_time_ms = request.meas_time_ms
        return self._changed(request, SystemStatusChange.STATIONARY_MODE_PARAMS_CHANGED)

    def _set_environment(self, request: SetEnvironmentParams) -> list[Message]:
        u = self.units
        t, p = units.temperature_from_units(u, request.temperature), units.pressure_from_units(u, request.pressure)
        self.set_environment(Environment(t, p, request.humidity))
        return self._changed(request, SystemStatusChange.ENVIRONMENT_PARAMS_CHANGED)

    def _set_reflector(self, request: SetReflector) -> list[Message]:
        if request.reflector_id < 0:
            return self._answer(request, ResultStatus.WRONG_PARAMETER1)
        self.reflector_id = request.reflector_id
        return self._changed(request, SystemStatusChange.REFLECTOR_CHANGED)

    def _set_search_params(self, request: SetSearchParams) -> list[Message]:
        if request.search_radius <= 0 or request.timeout_ms <= 0:
            return self._answer(request, ResultStatus.WRONG_PARAMETER)
        self.search_radius = request.search_radius * units.MM_PER_LENGTH[self.units.length]
        self.search_timeout_ms = request.timeout_ms
        return self._changed(request, SystemStatusChange.SEARCH_PARAMS_CHANGED)

    def _go_position(self, request: GoPosition) -> list[Message]:
        self.clock.sleep(self.motion_time_s)
        values = units.from_units(self.units, self.coordinate_system, (request.x, request.y, request.z))
        with self._state_lock:
            self.expected_mm = units.from_type(self.coordinate_system, values)
            self.locked = self._present() and request.use_adm
        return self._answer(request, ResultStatus.ALL_OK)

    def _find_reflector(self, request: FindReflector) -> list[Message]:
        if not self._present():
            self.clock.sleep(self.search_timeout_ms / 1000.0)
            return self._answer(request, ResultStatus.MEASUREMENT_STATUS_NOT_READY)
        self.clock.sleep(self.motion_time_s)
        with self._state_lock:
            self.locked = True
        return self._answer(request, ResultStatus.ALL_OK)

    def _go_bird_bath(self, request: GoBirdBath) -> list[Message]:
        self.clock.sleep(self.motion_time_s)
        with self._state_lock:
            self.expected_mm, self.locked = None, self._present()
        return self._answer(request, ResultStatus.ALL_OK)

    def _readback(self, request: Request) -> Request | None:
        """The current setting a Get* request asks for, as the Set* request that would set it (or None)."""
        if isinstance(request, GetUnits):
            return self.units
        if isinstance(request, GetCoordinateSystemType):
            return SetCoordinateSystemType(self.coordinate_system)
        if isinstance(request, GetMeasurementMode):
            return SetMeasurementMode(self.meas_mode)
        if isinstance(request, GetStationaryModeParams):
            return SetStationaryModeParams(self.meas_time_ms, False)
        if isinstance(request, GetStatisticMode):
            return self.statistic
        if isinstance(request, GetSystemSettings):
            return self.system_settings
        return None

    def _present(self) -> bool:
        """A reflector the tracker can see: a fixed flag, or asked of the simulated world each time."""
        return bool(self.reflector_present() if callable(self.reflector_present) else self.reflector_present)

    def _measure(self, conn: socket.socket, out: list[bytes]) -> list[Message]:
        cmd = StartMeasurement.COMMAND
        if not self.locked:
            self.last_result_status = ResultStatus.MEASUREMENT_STATUS_NOT_READY
            return [CommandAnswer(cmd, ResultStatus.MEASUREMENT_STATUS_NOT_READY)]
        out.append(encode(CommandAnswer(cmd, ResultStatus.ALL_OK)))
        if not self.coalesce:  # the acknowledgement goes out before the measurement time passes
            self._send(conn, list(out))
            out.clear()
        self.clock.sleep(self.meas_time_ms / 1000.0)
        if self._take_fault(EmsconFault.BEAM_BREAK) or not self._present():  # injected, or the world hides it
            with self._state_lock:
                self.locked = False
                self.last_result_status = ResultStatus.NO_STATIONARY_RESULT
            return [
                StatusChange(SystemStatusChange.MEAS_STATUS_NOT_READY),
                ErrorResponse(cmd, ResultStatus.NO_STATIONARY_RESULT),
            ]
        x, y, z, sx, sy, sz = (float(v) for v in self.measure_fn(self.expected_mm))
        self.last_result_status = ResultStatus.ALL_OK
        with self._state_lock:  # the settings as they are when the result is sent
            u, cs, extended = self.units, self.coordinate_system, self.statistic.stationary
            try_mode = self.system_settings.try_mode
            env = self.environment
        v1, v2, v3 = units.to_units(u, cs, units.to_type(cs, (x, y, z)))
        s1, s2, s3 = units.stds_to_units(u, cs, (sx, sy, sz), math.sqrt(x * x + y * y + z * z))
        total = math.sqrt(sx * sx + sy * sy + sz * sz) / units.MM_PER_LENGTH[u.length]
        head = (ResultStatus.ALL_OK, MeasMode.STATIONARY, try_mode, v1, v2, v3, s1, s2, s3, total)
        meteo = (
            units.temperature_to_units(u, env.temperature_c),
            units.pressure_to_units(u, env.pressure_hpa),
            env.humidity_pct,
        )
        if extended == StatisticMode.EXTENDED:  # uncorrelated coordinates, no pointing error (an ideal tracker)
            return [SingleMeasResult2(*head, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, s1, s2, s3, total, 0.0, 0.0, 0.0, *meteo)]
        return [SingleMeasResult(*head, 0.0, 0.0, 0.0, s1, s2, s3, total, *meteo)]

    def _send(self, conn: socket.socket, chunks: list[bytes]) -> None:
        if not chunks:
            return
        data = b"".join(chunks)
        try:
            if self.dribble:
                for i in range(len(data)):
                    conn.sendall(data[i : i + 1])
            elif self.coalesce:
                conn.sendall(data)
            else:
                for chunk in chunks:
                    conn.sendall(chunk)
        except OSError:
            pass  # the client went away; the serve loop notices on its next read


# request type -> MockEmscon's handler (StartMeasurement and the Get* readbacks are answered in _respond itself)
_HANDLERS: dict[type, Callable[[MockEmscon, Request], list[Message]]] = {
    Initialize: MockEmscon._initialize,
    GetSystemStatus: MockEmscon._system_status,
    GetTrackerStatus: MockEmscon._tracker_status,
    GetTrackerInfo: MockEmscon._tracker_info,
    GetSystemSoftwareVersion: MockEmscon._software_version,
    GetMeasurementStatusInfo: MockEmscon._measurement_status,
    SetUnits: MockEmscon._set_units,
    SetCoordinateSystemType: MockEmscon._set_coordinate_system,
    SetMeasurementMode: MockEmscon._set_measurement_mode,
    SetStatisticMode: MockEmscon._set_statistic_mode,
    SetSystemSettings: MockEmscon._set_system_settings,
    SetStationaryModeParams: MockEmscon._set_stationary_params,
    SetEnvironmentParams: MockEmscon._set_environment,
    SetReflector: MockEmscon._set_reflector,
    SetSearchParams: MockEmscon._set_search_params,
    GoPosition: MockEmscon._go_position,
    FindReflector: MockEmscon._find_reflector,
    GoBirdBath: MockEmscon._go_bird_bath,
}


def _close(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        sock.close()
