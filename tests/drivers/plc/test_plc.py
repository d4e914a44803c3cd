"""Cell PLC: ModbusCellIO against the pymodbus MockPlc over real TCP sockets on 127.0.0.1."""

from __future__ import annotations

import contextlib
import random
import socket
import threading
import time
from io import StringIO

import pytest
from rich.console import Console

from trackcal.campaign.cells.checks import motion_guard
from trackcal.campaign.cells.operator import PlcOperator
from trackcal.drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout, ProtocolError
from trackcal.drivers.interfaces import CellIO
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.drivers.plc.codec import (
    REQUEST_REGISTERS,
    REQUEST_TARGET_CHARS,
    OperatorRequest,
    PlcRegisterMap,
    decode_request,
    encode_request,
)
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.plc import MockPlc, PlcFault

TIMEOUT_S = 0.25


@pytest.fixture(scope="module")
def plc():
    mock = MockPlc(clock=VirtualClock()).start()
    yield mock
    mock.stop()


@pytest.fixture
def cell(plc):
    plc.clear_fault()
    plc.open_door()
    plc.release_acknowledge()
    plc.set_estop(False)
    io = ModbusCellIO(*plc.address, unit_id=1, timeout_s=TIMEOUT_S)
    io.connect()
    yield io
    io.close()
    plc.clear_fault()


def test_implements_cellio(cell):
    assert isinstance(cell, CellIO)


def test_door_follows_the_plc(plc, cell):
    assert cell.door_closed() is False  # the mock cell starts with its door open
    plc.close_door()
    assert cell.door_closed() is True
    plc.open_door()
    assert cell.door_closed() is False


def test_acknowledge_button(plc, cell):
    assert cell.acknowledge_pressed() is False
    plc.press_acknowledge()
    assert cell.acknowledge_pressed() is True
    plc.release_acknowledge()
    assert cell.acknowledge_pressed() is False


def test_request_lamp(plc, cell):
    cell.set_request_lamp(True)
    assert plc.lamp is True
    cell.set_request_lamp(False)
    assert plc.lamp is False


def test_door_and_ack_are_independent_bits(plc, cell):
    plc.press_acknowledge()
    assert cell.door_closed() is False
    plc.release_acknowledge()
    plc.close_door()
    assert cell.acknowledge_pressed() is False


def test_heartbeat_and_watchdog(plc, cell):
    assert cell.heartbeat() == plc.heartbeat
    status = cell.read_status()
    assert status.running and status.estop_ok and not status.watchdog_expired
    plc.clock.advance(plc.watchdog_s + 0.1)  # heartbeat now stale in PLC time
    assert cell.read_status().watchdog_expired
    cell.heartbeat()
    assert not cell.read_status().watchdog_expired
    plc.set_estop(True)
    assert not cell.read_status().estop_ok


def test_remapped_plc_program():
    # Every signal moved except MAP_VERSION, which stays at IR 1 in every map version (cell-plc-registers.md).
    remap = PlcRegisterMap(
        door_closed_di=17,
        acknowledge_di=3,
        request_lamp_coil=5,
        heartbeat_hr=10,
        request_hr=20,
        status_ir=4,
        map_version=0x0201,
    )
    with MockPlc(register_map=remap) as mock:
        with ModbusCellIO(*mock.address, timeout_s=TIMEOUT_S, register_map=remap) as io:
            mock.close_door()
            assert io.door_closed() is True and io.acknowledge_pressed() is False
            io.set_request_lamp(True)
            assert mock.lamp is True
            io.show_request("move_reflector", "P2")
            assert mock.operator_request == OperatorRequest("move_reflector", 1, "P2")
        # a client that expects the default map refuses this PLC program at connect
        with pytest.raises(ProtocolError, match="0x0201"):
            ModbusCellIO(*mock.address, timeout_s=TIMEOUT_S).connect()


def test_request_map_must_not_overlap_the_heartbeat():
    with pytest.raises(ValueError, match="heartbeat HR 5 inside the operator request block HR 1..10"):
        PlcRegisterMap(heartbeat_hr=5)


# ---------------------------------------------------------------- HMI request (cell-plc-registers.md)
def test_request_encoding_is_the_documented_layout():
    # 'P2' = 0x50 0x32, first character in the high byte; move_reflector = kind 1; NUL padding to 16 characters
    assert encode_request("move_reflector", 7, "P2") == [1, 7, 0x5032] + [0] * 7
    assert encode_request("change_station", 1, "S1") == [2, 1, 0x5331] + [0] * 7
    assert encode_request("resume", 65536, "") == [3, 0] + [0] * 8  # the sequence number wraps mod 65536
    assert encode_request(None, 9) == [0, 9] + [0] * 8
    assert len(encode_request("resume", 0)) == REQUEST_REGISTERS
    with pytest.raises(ValueError, match="unknown operator request kind"):
        encode_request("dance", 1, "P1")


def test_request_target_round_trip_and_what_does_not_fit():
    for name in ("P1", "S2", "TMAC_X+", "E", "ABCDEFGHIJKLMNOP"):
        assert decode_request(encode_request("move_reflector", 3, name)).target == name
    long = "a-very-long-reference-point-name"
    assert decode_request(encode_request("move_reflector", 3, long)).target == long[:REQUEST_TARGET_CHARS]
    assert decode_request(encode_request("change_station", 3, "Süd")).target == "S?d"  # ASCII only
    with pytest.raises(ValueError, match="kind code 9"):
        decode_request([9, 1] + [0] * 8)
    with pytest.raises(ValueError, match="10 registers"):
        decode_request([1, 1, 0])


def test_show_and_clear_request_through_the_mock(plc, cell):
    before = plc.operator_request.seq
    seq = cell.show_request("change_station", "S2")
    assert seq == (before + 1) & 0xFFFF
    assert plc.operator_request == OperatorRequest("change_station", seq, "S2")
    assert cell.read_request() == plc.operator_request  # the same registers read back over the wire
    cell.clear_request()
    assert plc.operator_request == OperatorRequest(None, seq, "")  # cleared, the sequence number stays
    cell.show_request("move_reflector", "P1")
    assert plc.operator_request == OperatorRequest("move_reflector", seq + 1, "P1")


def test_a_new_client_continues_the_sequence(plc, cell):
    """A trackcal process restarted after a crash must publish a request the HMI tells from the last one, even
    when the lamp is still on from the crashed process: the sequence number comes from the PLC."""
    last = cell.show_request("move_reflector", "P3")
    with ModbusCellIO(*plc.address, timeout_s=TIMEOUT_S) as again:
        assert again.show_request("move_reflector", "P3") == last + 1
    assert plc.operator_request.seq == last + 1


def test_request_write_failures_are_device_errors(plc, cell):
    plc.inject(PlcFault.EXCEPTION, code=0x02)  # a PLC program without the request registers
    with pytest.raises(ProtocolError, match="request sequence.*map mismatch"):
        cell.show_request("resume")
    plc.inject(PlcFault.SILENT)
    with pytest.raises(DeviceTimeout, match="request"):
        cell.clear_request()
    plc.clear_fault()


def operator_at(mock: MockPlc, seen: list):
    """A `sleep` for PlcOperator: the person at the cell, who presses the button (for one poll) once the lamp
    is on and notes what the HMI showed him then."""
    state = {"pressed": False}

    def sleep(_s: float) -> None:
        req = mock.operator_request
        if mock.lamp and not state["pressed"]:
            seen.append((req.kind, req.target))
            state["pressed"] = True
            mock.press_acknowledge()
        else:
            mock.release_acknowledge()

    return sleep


def test_plc_operator_shows_the_request_while_the_lamp_is_on():
    with MockPlc(clock=VirtualClock()) as mock, ModbusCellIO(*mock.address, timeout_s=TIMEOUT_S) as io:
        seen: list = []
        op = PlcOperator(io, Console(file=StringIO()).print, poll_s=0.0, sleep=operator_at(mock, seen))
        assert op.ask("move_reflector", "P2", "put the reflector on P2") == "plc"
        assert seen == [("move_reflector", "P2")]  # written before the lamp lit
        assert mock.lamp is False and mock.operator_request.kind is None  # both off afterwards


def test_plc_operator_without_request_registers_keeps_lamp_and_button():
    """A PLC program without the request registers (here: the client looks for them where this PLC has none,
    so it answers ILLEGAL DATA ADDRESS): one warning, then lamp and acknowledge button as before."""

    with (
        MockPlc(clock=VirtualClock()) as mock,
        ModbusCellIO(*mock.address, timeout_s=TIMEOUT_S, register_map=PlcRegisterMap(request_hr=40)) as io,
    ):
        seen: list = []
        out = StringIO()
        op = PlcOperator(io, Console(file=out, width=200).print, poll_s=0.0, sleep=operator_at(mock, seen))
        assert op.ask("change_station", "S1", "move the tracker to station S1") == "plc"
        assert seen == [(None, "")] and mock.lamp is False
        assert "HMI shows no requests" in out.getvalue() and "ILLEGAL DATA ADDRESS" in out.getvalue()
        assert op.hmi is False


# ---------------------------------------------------------------- faults
def test_silent_plc_times_out_and_door_reads_open(plc, cell):
    plc.close_door()
    assert cell.door_closed() is True
    plc.inject(PlcFault.SILENT)
    t0 = time.monotonic()
    assert cell.door_closed() is False  # SAFETY: unreadable door is OPEN
    assert time.monotonic() - t0 < TIMEOUT_S + 0.5
    assert isinstance(cell.last_door_error, DeviceTimeout)
    with pytest.raises(DeviceTimeout, match=r"127\.0\.0\.1:\d+.*acknowledge"):
        cell.acknowledge_pressed()
    with pytest.raises(DeviceTimeout, match="request lamp"):
        cell.set_request_lamp(True)
    plc.clear_fault()
    assert cell.door_closed() is True  # reconnects by itself on the next call
    assert cell.last_door_error is None


def test_dropped_connection_is_connection_lost_and_door_reads_open(plc, cell):
    plc.close_door()
    plc.inject(PlcFault.DROP)
    assert cell.door_closed() is False
    assert isinstance(cell.last_door_error, ConnectionLost)
    with pytest.raises(ConnectionLost, match=rf"{plc.address[0]}:{plc.address[1]}.*acknowledge"):
        cell.acknowledge_pressed()
    plc.clear_fault()
    assert cell.door_closed() is True


def test_a_close_from_another_thread_waits_for_the_request_under_way(plc, cell):
    """The KR C4's motion guard reads the door from its own thread (drivers.krc4.cycle_guard) while the campaign's
    thread closes the client at the end: the close waits for the read under way (issue 37's slow KR C4 run: a close
    under the read left pymodbus' socket None, an AttributeError out of the guard's thread), and a read after the
    close reads the door as open."""
    plc.close_door()
    inside, release = threading.Event(), threading.Event()
    client = cell._client
    read = client.read_discrete_inputs

    def held_read(*args, **kw):  # the request is on the wire until the test releases it
        inside.set()
        release.wait(timeout=30)
        return read(*args, **kw)

    client.read_discrete_inputs = held_read
    said: list[bool] = []
    reader = threading.Thread(target=lambda: said.append(cell.door_closed()))
    reader.start()
    assert inside.wait(timeout=30)
    closer = threading.Thread(target=cell.close)
    closer.start()
    closer.join(timeout=0.5)  # an unguarded close is done by now (a slow machine only hides that, never fails this)
    closed_under_the_read = not closer.is_alive()
    release.set()
    reader.join(timeout=30)
    closer.join(timeout=30)
    assert not closed_under_the_read and said == [True]
    assert cell.door_closed() is False and isinstance(cell.last_door_error, ConnectionLost)


@pytest.mark.parametrize("code", [0x04, 0x06, 0x0B])
def test_plc_refusal_is_device_fault_with_code(plc, cell, code):
    plc.close_door()
    plc.inject(PlcFault.EXCEPTION, code=code)
    assert cell.door_closed() is False
    assert isinstance(cell.last_door_error, DeviceFault) and cell.last_door_error.code == code
    with pytest.raises(DeviceFault) as info:
        cell.set_request_lamp(True)
    assert info.value.code == code
    plc.clear_fault()
    assert cell.door_closed() is True


@pytest.mark.parametrize("code", [0x01, 0x02, 0x03])
def test_request_mismatch_exception_is_protocol_error(plc, cell, code):
    plc.close_door()
    plc.inject(PlcFault.EXCEPTION, code=code)
    assert cell.door_closed() is False
    assert isinstance(cell.last_door_error, ProtocolError)
    with pytest.raises(ProtocolError, match=f"0x{code:02X}"):
        cell.acknowledge_pressed()


def test_unmapped_address_is_protocol_error(plc):
    # The client believes the lamp is coil 40; the PLC program has no such coil: ILLEGAL DATA ADDRESS (02).
    wrong = PlcRegisterMap(request_lamp_coil=40)
    with (
        ModbusCellIO(*plc.address, timeout_s=TIMEOUT_S, register_map=wrong) as io,
        pytest.raises(ProtocolError, match="0x02"),
    ):
        io.set_request_lamp(True)


def test_no_server_connection_lost_and_door_open():
    with socket.socket() as s:  # a port that was free a moment ago: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    io = ModbusCellIO("127.0.0.1", port, timeout_s=TIMEOUT_S)
    with pytest.raises(ConnectionLost, match=rf"127\.0\.0\.1:{port}.*connect"):
        io.connect()
    assert io.door_closed() is False
    assert isinstance(io.last_door_error, ConnectionLost)
    with pytest.raises(ConnectionLost, match="acknowledge"):
        io.acknowledge_pressed()


def test_not_connected_door_reads_open():
    io = ModbusCellIO("127.0.0.1", 1, timeout_s=TIMEOUT_S)
    assert io.door_closed() is False
    with pytest.raises(ConnectionLost, match="not connected"):
        io.set_request_lamp(True)


def test_stopped_plc_door_reads_open():
    mock = MockPlc().start()
    mock.close_door()
    io = ModbusCellIO(*mock.address, timeout_s=TIMEOUT_S)
    io.connect()
    assert io.door_closed() is True
    mock.stop()
    assert io.door_closed() is False
    assert isinstance(io.last_door_error, ConnectionLost | DeviceTimeout)
    io.close()


def test_garbage_connections_never_take_the_server_down(plc, cell):
    rng = random.Random(20240611)  # fixed seed: the same garbage every run
    for i in range(40):
        with socket.create_connection(plc.address, timeout=1.0) as raw:
            if i % 2:
                raw.sendall(bytes(rng.randrange(256) for _ in range(rng.randint(1, 700))))
            else:
                # a valid MBAP header (protocol id 0) around a random PDU: unknown function codes, bad lengths
                pdu = bytes(rng.randrange(256) for _ in range(rng.randint(1, 20)))
                raw.sendall(
                    rng.randrange(65536).to_bytes(2, "big")
                    + b"\x00\x00"
                    + (len(pdu) + 1).to_bytes(2, "big")
                    + b"\x01"
                    + pdu
                )
            if i % 5 == 0:
                raw.settimeout(0.05)
                with contextlib.suppress(OSError):
                    raw.recv(260)
    plc.close_door()
    assert cell.door_closed() is True
    cell.set_request_lamp(True)
    assert plc.lamp is True


def test_the_motion_guard_names_a_silent_plc_and_an_open_door_apart(plc, cell):
    """Issue 27, finding 7: a frozen cell (the PLC silent) stops the robot as a PLC that does not answer, not as
    "the cell door opened"; both stop it."""
    guard = motion_guard(cell)
    plc.close_door()
    assert guard() is None
    plc.open_door()
    assert guard() == "the cell door opened"
    plc.close_door()
    plc.inject(PlcFault.SILENT)
    reason = guard()
    assert reason is not None and reason.startswith("the cell PLC does not answer (") and "door opened" not in reason
