"""EmsconTracker against MockEmscon over real loopback sockets: the campaign sequence, partial reads,
coalesced packets, time-outs and every injected fault.

Numbers:
- POINT: a plausible reflector position about 2.7 m from the tracker in a robot cell (mm);
- the mock's measured value is POINT + OFFSET with standard deviations STD: arbitrary deterministic values of
  the order of the AT901 accuracy (micrometres), chosen exactly representable in binary (2**-7 = 0.0078125,
  2**-6, 2**-8) so that equality checks are exact;
- ENV: 20 degC / 1013.25 hPa (ISO 2533 standard atmosphere, sea level) and 50 %RH (mid-range);
- MOTION_S = 2 s of simulated time per motion and 2000 samples at the client's 1000 samples/s = 2 s of
  simulated measurement: any values would do, these make the clock arithmetic obvious.
"""

from __future__ import annotations

import math
import random
import socket
import struct
import time

import pytest

from trackcal.drivers.emscon.client import EmsconTracker
from trackcal.drivers.emscon.enums import (
    AngleUnit,
    Command,
    CoordinateSystemType,
    LengthUnit,
    PressureUnit,
    ResultStatus,
    StatisticMode,
    SystemStatusChange,
    TemperatureUnit,
    WeatherMonitorStatus,
)
from trackcal.drivers.emscon.framing import PacketReader, decode_packet
from trackcal.drivers.emscon.messages import (
    ErrorResponse,
    FindReflector,
    GetUnits,
    GoPosition,
    Initialize,
    SetCoordinateSystemType,
    SetStatisticMode,
    SetSystemSettings,
    SetUnits,
    SingleMeasResult,
    StartMeasurement,
    StatusChange,
    encode_command,
)
from trackcal.drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout, ProtocolError
from trackcal.drivers.interfaces import Environment, Tracker
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.emscon import EmsconFault, MockEmscon

POINT = (2500.0, -400.0, 900.0)
OFFSET = (2**-7, -(2**-6), 2**-8)
STD = (2**-7, 2**-7, 2**-6)
ENV = Environment(20.0, 1013.25, 50.0)
MOTION_S = 2.0
N_SAMPLES = 2000


def measure_fn(expected):
    x, y, z = expected if expected is not None else (0.0, 0.0, 0.0)
    return (x + OFFSET[0], y + OFFSET[1], z + OFFSET[2], *STD)


@pytest.fixture
def clock():
    return VirtualClock()


@pytest.fixture
def server(clock):
    srv = MockEmscon(measure_fn, clock, motion_time_s=MOTION_S).start()
    yield srv
    srv.stop()


def client_for(server, **kw) -> EmsconTracker:
    host, port = server.address
    kw.setdefault("timeout_s", 2.0)
    kw.setdefault("measure_timeout_s", 2.0)
    kw.setdefault("motion_timeout_s", 2.0)
    kw.setdefault("search_timeout_s", 1.0)
    return EmsconTracker(host, port, **kw)


@pytest.fixture
def tracker(server):
    trk = client_for(server)
    yield trk
    trk.close()


def ready(tracker: EmsconTracker) -> None:
    tracker.connect()
    tracker.initialize()
    tracker.find_reflector(*POINT, search_radius_mm=5.0)


def expected_measurement():
    return tuple(p + o for p, o in zip(POINT, OFFSET, strict=True))


# -------------------- campaign sequence
def test_campaign_sequence(server, tracker, clock):
    assert isinstance(tracker, Tracker)
    tracker.connect()
    assert server.units.length == LengthUnit.MILLIMETER  # the mock starts in metres; connect() sets mm
    before = tracker.status()
    assert not before.initialized and not before.reflector_locked
    tracker.initialize()
    tracker.set_environment(ENV)
    tracker.set_reflector(1)
    tracker.set_stationary_averaging(N_SAMPLES)
    assert server.meas_time_ms == 2000
    tracker.find_reflector(*POINT, search_radius_mm=5.0)
    t0 = clock.now()
    m = tracker.measure()
    assert clock.now() - t0 == 2.0  # the stationary measurement time passed on the mock's clock
    assert (m.x_mm, m.y_mm, m.z_mm) == expected_measurement()
    assert (m.std_x_mm, m.std_y_mm, m.std_z_mm) == STD
    assert m.environment == ENV
    st = tracker.status()
    assert st.initialized and st.reflector_locked and not st.busy
    tracker.go_birdbath()
    # Initialize, GoPosition, FindReflector, GoBirdBath: 4 motions; plus 2 s of measurement
    assert clock.now() == 4 * MOTION_S + 2.0
    commands = [type(r).__name__ for r in server.received]
    settings = ["SetUnits", "SetCoordinateSystemType", "SetMeasurementMode", "SetStatisticMode", "SetSystemSettings"]
    assert commands[: len(settings) + 1] == ["GetSystemSettings", *settings]
    assert commands[len(settings) + 1 : 2 * len(settings) + 1] == [f"Get{c[3:]}" for c in settings]
    assert commands[-1] == "GoBirdBath"
    assert server.received[commands.index("GoPosition")] == GoPosition(*POINT, use_adm=True)
    # every setting was followed by a status-change packet between answers: all recorded, none mistaken
    assert SystemStatusChange.ENVIRONMENT_PARAMS_CHANGED in tracker.status_changes
    assert tracker.last_status_change is not None
    tracker.close()


def test_two_measurements_in_a_row_and_reconnect(server, tracker):
    ready(tracker)
    assert tracker.measure() == tracker.measure()
    tracker.close()
    tracker.connect()  # the tracker stays initialised and locked across connections
    assert (tracker.measure().x_mm) == expected_measurement()[0]


# -------------------- partial reads
def test_dribbled_bytes(server, tracker):
    server.dribble = True
    ready(tracker)
    m = tracker.measure()
    assert (m.x_mm, m.y_mm, m.z_mm) == expected_measurement()
    assert tracker.status().reflector_locked


def test_coalesced_packets(server, tracker):
    server.coalesce = True
    ready(tracker)
    server.inject(EmsconFault.STATUS_CHANGE)
    m = tracker.measure()  # status change + ack + result arrive in one segment
    assert (m.x_mm, m.y_mm, m.z_mm) == expected_measurement()
    assert SystemStatusChange.MEAS_STATUS_BUSY in tracker.status_changes


# -------------------- faults
def test_measure_before_initialize_fails_like_the_tracker(server, tracker):
    tracker.connect()
    with pytest.raises(DeviceFault, match="not initialised") as info:
        tracker.measure()
    assert info.value.code == ResultStatus.TRACKER_NOT_INITIALIZED == 39  # ES_RS_TrackerNotInitialized
    with pytest.raises(DeviceFault) as info:
        tracker.find_reflector(*POINT, search_radius_mm=5.0)
    assert info.value.code == 39
    tracker.initialize()  # the connection is still usable after a fault
    tracker.find_reflector(*POINT, search_radius_mm=5.0)
    tracker.measure()


def test_no_reflector(server, tracker):
    server.reflector_present = False
    tracker.connect()
    tracker.initialize()
    with pytest.raises(DeviceFault, match="no reflector") as info:
        tracker.find_reflector(*POINT, search_radius_mm=5.0)
    assert info.value.code == ResultStatus.MEASUREMENT_STATUS_NOT_READY == 10004  # ES_API_ERROR_OFFSET + 4
    with pytest.raises(DeviceFault) as info:
        tracker.measure()
    assert info.value.code == 10004
    assert not tracker.status().reflector_locked


def test_beam_break_during_measurement(server, tracker):
    ready(tracker)
    server.inject(EmsconFault.BEAM_BREAK)
    with pytest.raises(DeviceFault, match="beam was broken") as info:
        tracker.measure()
    assert info.value.code == ResultStatus.NO_STATIONARY_RESULT == 10009  # ES_API_ERROR_OFFSET + 9
    assert tracker.last_status_change == SystemStatusChange.MEAS_STATUS_NOT_READY
    with pytest.raises(DeviceFault) as info:  # the lock is lost until the reflector is found again
        tracker.measure()
    assert info.value.code == 10004
    tracker.find_reflector(*POINT, search_radius_mm=5.0)
    assert (tracker.measure().x_mm) == expected_measurement()[0]


def test_unsolicited_status_change_and_foreign_error_between_answers(server, tracker):
    ready(tracker)
    server.inject(EmsconFault.STATUS_CHANGE)
    server.inject(EmsconFault.ASYNC_ERROR)
    m = tracker.measure()
    assert (m.x_mm, m.y_mm, m.z_mm) == expected_measurement()
    assert SystemStatusChange.MEAS_STATUS_BUSY in tracker.status_changes
    assert list(tracker.async_errors) == [ErrorResponse(Command.GET_SYSTEM_STATUS, ResultStatus.UNKNOWN)]


def test_dropped_connection(server, tracker):
    ready(tracker)
    server.inject(EmsconFault.DROP_CONNECTION)
    host, port = server.address
    with pytest.raises(ConnectionLost, match=f"{host}:{port}.*closed the connection while measuring"):
        tracker.measure()
    tracker.connect()
    assert tracker.measure().y_mm == expected_measurement()[1]


def test_malformed_packet(server, tracker):
    ready(tracker)
    server.inject(EmsconFault.MALFORMED_PACKET)
    with pytest.raises(ProtocolError, match="lPacketSize 3"):
        tracker.measure()
    with pytest.raises(ConnectionLost, match="not connected"):  # the desynchronised stream was dropped
        tracker.measure()
    tracker.connect()
    tracker.measure()


def test_silent_tracker_times_out_in_bounded_time(server):
    server.silent = True
    trk = client_for(server, timeout_s=0.3)
    host, port = server.address
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match=f"{host}:{port}.*0.3 s while reading the system settings"):
        trk.connect()
    assert time.monotonic() - t0 < 2.0


def test_measurement_result_that_never_comes_times_out():
    # real_fraction=1: the mock's 1 s stationary measurement takes 1 s of wall time; the client allows 0.2 s
    clock = VirtualClock(real_fraction=1.0)
    srv = MockEmscon(measure_fn, clock, motion_time_s=0.0).start()
    try:
        trk = client_for(srv, measure_timeout_s=0.2)
        ready(trk)
        trk.set_stationary_averaging(1000)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match="measuring"):
            trk.measure()
        assert time.monotonic() - t0 < 0.9
    finally:
        srv.stop()


def test_connection_refused_names_host_port_and_action():
    with socket.socket() as probe:  # a port that was free a moment ago and has no listener now
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    trk = EmsconTracker("127.0.0.1", port, timeout_s=1.0)
    with pytest.raises(ConnectionLost, match=f"127.0.0.1 port {port} while connecting"):
        trk.connect()
    with pytest.raises(ConnectionLost, match="not connected"):
        trk.measure()


# -------------------- whatever a previous program left on the tracker
LEFT_BEHIND = [
    SetUnits(LengthUnit.INCH, AngleUnit.GON, TemperatureUnit.FAHRENHEIT, PressureUnit.PSI),
    SetCoordinateSystemType(CoordinateSystemType.SCW),
    SetStatisticMode(StatisticMode.EXTENDED, StatisticMode.EXTENDED),
    SetSystemSettings(WeatherMonitorStatus.READ_ONLY, True, True, False, False, True, True, False, False),
]


def send_as_another_client(server, *requests) -> list:
    """Another program on the tracker's network changes its settings (its own connection, raw packets)."""
    with socket.create_connection(server.address, timeout=2.0) as raw:
        raw.sendall(b"".join(encode_command(r) for r in requests))
        reader, answers = PacketReader(), []
        while len(answers) < len(requests):
            data = raw.recv(4096)
            assert data, "the mock closed the connection"
            answers += [m for m in map(decode_packet, reader.feed(data)) if not isinstance(m, StatusChange)]
    return answers


def test_configure_undoes_what_another_program_left(server, tracker):
    send_as_another_client(server, *LEFT_BEHIND)
    ready(tracker)  # connect() configures
    assert (server.units, server.coordinate_system) == (SetUnits(), CoordinateSystemType.RHR)
    assert server.statistic == SetStatisticMode(StatisticMode.STANDARD, StatisticMode.STANDARD)
    assert not server.system_settings.try_mode and not server.system_settings.apply_transformation
    assert tracker.measure().z_mm == expected_measurement()[2]


def test_settings_changed_mid_session_are_undone_by_configure(server, tracker):
    ready(tracker)
    send_as_another_client(server, SetUnits(LengthUnit.MICRON))
    # 1 mm is 1000 um: the same reflector now reads 1000 times larger
    assert tracker.measure().z_mm == pytest.approx(expected_measurement()[2] * 1000, rel=1e-12)
    tracker.configure()
    assert tracker.measure().z_mm == expected_measurement()[2]


def test_extended_statistic_mode_results_are_read(server, tracker):
    ready(tracker)
    send_as_another_client(server, SetStatisticMode(StatisticMode.EXTENDED, StatisticMode.STANDARD))
    m = tracker.measure()  # a SingleMeasResult2T (type 9, 204 bytes): the same position and deviations
    assert (m.x_mm, m.y_mm, m.z_mm) == expected_measurement()
    assert (m.std_x_mm, m.std_y_mm, m.std_z_mm) == STD


def test_try_mode_result_is_refused(server, tracker):
    ready(tracker)
    try_mode = SetSystemSettings(
        WeatherMonitorStatus.NOT_CONNECTED, False, False, True, True, False, True, False, False
    )
    send_as_another_client(server, try_mode)
    with pytest.raises(DeviceFault, match="try-mode"):
        tracker.measure()


def test_a_setting_that_does_not_read_back_is_a_fault(server, tracker, monkeypatch):
    tracker.connect()
    readback = server._readback
    monkeypatch.setattr(
        server, "_readback", lambda r: SetUnits(LengthUnit.MICRON) if isinstance(r, GetUnits) else readback(r)
    )
    with pytest.raises(DeviceFault, match="reports SetUnits") as info:
        tracker.configure()
    assert info.value.code == "readback"


@pytest.mark.parametrize(
    ("unit", "mm_per_unit"),  # exact by definition: international yard of 1959 (0.9144 m = 3 ft = 36 in)
    [
        (LengthUnit.METER, 1000.0),
        (LengthUnit.MICRON, 1e-3),
        (LengthUnit.FOOT, 304.8),
        (LengthUnit.INCH, 25.4),
        (LengthUnit.YARD, 914.4),
    ],
)
def test_mock_lengths_in_every_unit(server, tracker, unit, mm_per_unit):
    ready(tracker)
    send_as_another_client(server, SetUnits(unit))
    m = tracker.measure()
    assert m.z_mm * mm_per_unit == pytest.approx(expected_measurement()[2], rel=1e-12)


def test_mock_spherical_coordinates(server, tracker):
    ready(tracker)
    send_as_another_client(server, SetUnits(angle=AngleUnit.RADIAN), SetCoordinateSystemType(CoordinateSystemType.SCC))
    m = tracker.measure()  # (horizontal angle, zenith angle, distance): the conventions assumed in the mock
    x, y, z = expected_measurement()
    assert m.x_mm == pytest.approx(math.atan2(y, x), rel=1e-12)
    assert m.y_mm == pytest.approx(math.acos(z / math.dist((0, 0, 0), (x, y, z))), rel=1e-12)
    assert m.z_mm == pytest.approx(math.dist((0, 0, 0), (x, y, z)), rel=1e-12)


# -------------------- server robustness
def test_garbage_or_dropped_clients_do_not_take_the_server_down(server, tracker):
    host, port = server.address
    rng = random.Random(20240611)  # fixed seed: the same garbage every run
    garbage = [
        rng.randbytes(512),  # its size field is out of range (a random int32 almost surely is)
        struct.pack("<ii", 2**31 - 1, 0),  # absurd size
        encode_command(StartMeasurement())[:7],  # half a packet, then the client vanishes
    ]
    for payload in garbage:
        with socket.create_connection((host, port), timeout=1.0) as raw:
            raw.sendall(payload)
    deadline = time.monotonic() + 2.0
    while server.connections_dropped_on_garbage < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert server.connections_dropped_on_garbage == 2
    ready(tracker)
    assert (tracker.measure().z_mm) == expected_measurement()[2]


def test_packets_it_cannot_read_are_answered_and_the_connection_kept(server):
    # (packet, answer): ES_RS_NotImplemented 2, ES_RS_WrongParameter 3 (ES_C_API_Def.h ES_ResultStatus)
    cases = [
        (struct.pack("<iii", 12, 99, 49), struct.pack("<iiii", 16, 0, 49, 2)),  # unknown ES_DataType 99
        (struct.pack("<iii", 12, 0, 50), struct.pack("<iiii", 16, 0, 50, 2)),  # ES_Command 50 does not exist
        (struct.pack("<ii", 8, 0), struct.pack("<iiii", 16, 0, 64, 2)),  # no command at all: ES_C_Unknown 64
        # GetATRInfo (138) is not implemented: its whole GetATRInfoRT, zeroed: BasicCommandRT 16 + atrType 4 +
        # cATRName[32] 64 + 6 long 24 + 4 double 32 = 140 bytes
        (struct.pack("<iii", 12, 0, 138), struct.pack("<iiii", 140, 0, 138, 2) + bytes(124)),
        # SetUnits with ES_LengthUnit 9 (no such unit): SetUnitsRT (16 bytes) with ES_RS_WrongParameter
        (struct.pack("<iii5i", 32, 0, 5, 9, 1, 0, 1, 0), struct.pack("<iiii", 16, 0, 5, 3)),
    ]
    with socket.create_connection(server.address, timeout=2.0) as raw:
        for packet, answer in cases:
            raw.sendall(packet)
            got = b""
            while len(got) < len(answer):
                data = raw.recv(4096)
                assert data, "the mock closed the connection"
                got += data
            assert got == answer
    assert server.connections_dropped_on_garbage == 0


def test_same_requests_give_the_same_bytes():
    """Determinism: two mocks fed the same requests answer byte for byte the same (a whole session)."""
    requests = [SetUnits(), Initialize(), GoPosition(*POINT), FindReflector(2700.0), StartMeasurement()]

    def session() -> bytes:
        srv = MockEmscon(measure_fn, VirtualClock(), motion_time_s=MOTION_S).start()
        try:
            with socket.create_connection(srv.address, timeout=2.0) as raw:
                raw.sendall(b"".join(encode_command(r) for r in requests))
                reader, received, stream = PacketReader(), [], b""
                while not (received and isinstance(decode_packet(received[-1]), SingleMeasResult)):
                    data = raw.recv(4096)
                    assert data, "the mock closed the connection"
                    stream += data
                    received += reader.feed(data)
                return stream
        finally:
            srv.stop()

    first = session()
    assert first == session()
    assert len(first) > 156  # answers, status changes and the 156-byte SingleMeasResultT
