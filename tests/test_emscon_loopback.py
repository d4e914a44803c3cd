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

import random
import socket
import struct
import time

import pytest

from drivers.emscon.client import EmsconTracker
from drivers.emscon.codec import (
    Command,
    ErrorResponse,
    FindReflector,
    GoPosition,
    Initialize,
    LengthUnit,
    PacketReader,
    ResultStatus,
    SetUnits,
    SingleMeasResult,
    StartMeasurement,
    SystemStatusChange,
    decode_packet,
    encode_command,
)
from drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout, ProtocolError
from drivers.interfaces import Environment, Tracker
from mocks.clock import VirtualClock
from mocks.servers.emscon import EmsconFault, MockEmscon

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
    assert commands[:3] == ["SetUnits", "SetCoordinateSystemType", "SetMeasurementMode"]
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
    with pytest.raises(DeviceTimeout, match=f"{host}:{port}.*0.3 s while setting units"):
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


def test_units_the_mock_does_not_support_are_refused(server, tracker):
    tracker.connect()
    with pytest.raises(DeviceFault) as info:
        tracker._command(SetUnits(LengthUnit.INCH), "setting inches")
    assert info.value.code == ResultStatus.WRONG_PARAMETER


# -------------------- server robustness
def test_garbage_or_dropped_clients_do_not_take_the_server_down(server, tracker):
    host, port = server.address
    rng = random.Random(20240611)  # fixed seed: the same garbage every run
    garbage = [
        rng.randbytes(512),
        struct.pack("<ii", 2**31 - 1, 0),  # absurd size
        struct.pack("<iii", 12, 99, 49),  # unknown ES_DataType
        struct.pack("<iii", 12, 0, 50),  # ES_Command 50 does not exist in the header
        encode_command(StartMeasurement())[:7],  # half a packet, then the client vanishes
    ]
    for payload in garbage:
        with socket.create_connection((host, port), timeout=1.0) as raw:
            raw.sendall(payload)
    deadline = time.monotonic() + 2.0
    while server.connections_dropped_on_garbage < 4 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert server.connections_dropped_on_garbage == 4
    ready(tracker)
    assert (tracker.measure().z_mm) == expected_measurement()[2]


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
