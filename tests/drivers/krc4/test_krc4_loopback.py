"""drivers.krc4.client.KukaKrc4 against mocks.servers.krc4.controller.MockKrc4 over real loopback sockets: trackcal
connects to the controller's EKI server and answers its 4 ms RSI stream (UDP, with the frame's IPOC and zero AK
corrections); the motion guard brakes a move; a peer that is not the controller is not read; a controller that
disappears ends the next request with a device error, never a hang."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from tests.helpers import free_udp_port
from trackcal.drivers.errors import ConnectionLost, DeviceError, DeviceFault
from trackcal.drivers.interfaces import StopCause
from trackcal.drivers.krc4.client import KRC4_CYCLE_S, KukaKrc4
from trackcal.drivers.kuka.client import GUARD_S
from trackcal.drivers.kuka.eki_codec import ERR_DRIVES_OFF, ERROR_TEXT
from trackcal.drivers.kuka.rsi_codec import RobFrame, encode_rob
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.krc4.controller import ETHERNET_TIMEOUT, MockKrc4

HOME = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)
TARGET = (10.0, -80.0, 85.0, 5.0, 80.0, -15.0)
# KR 210 R2700-2 axis limits (configs/robots/kr210.yaml, from kuka_quantec_support's kr210_r2700_2_macro.xacro)
KR210_LIMITS = ((-185, 185), (-140, -5), (-120, 168), (-350, 350), (-125, 125), (-350, 350))


def open_cell(guard=None, **mock_kw):
    port = free_udp_port()
    seen: list = []
    mock_kw.setdefault("answer_budget_s", 5.0)
    mock = MockKrc4(
        ("127.0.0.1", 0),
        ("127.0.0.1", port),
        VirtualClock(),
        HOME,
        joint_speed_deg_s=100.0,
        settle_s=0.3,
        on_joints=seen.append,
        seed=2,
        **mock_kw,
    ).start()
    client = KukaKrc4(
        mock.eki_addr[1],
        "127.0.0.1",
        port,
        controller_host="127.0.0.1",
        motion_guard=guard,
        joint_limits_deg=KR210_LIMITS,
        connect_timeout_s=5.0,
        move_timeout_s=10.0,
        io_timeout_s=2.0,
    )
    client.connect()
    return client, mock, seen


def test_move_settle_and_the_two_channels_agree():
    client, mock, seen = open_cell()
    try:
        assert client.rsi.cycle_s == KRC4_CYCLE_S and not client.rsi.passive and client.rsi.protocol == "udp"
        client.move(TARGET, 50)
        assert client.wait_settled(0.0005, 0.1, 5.0) == TARGET  # RSI's joints; EKI's agree (else a DeviceFault)
        assert client.joints() == TARGET and seen[-1] == TARGET
        assert client.rsi.frames_answered > 0 and mock.late_packets == 0
        assert client.device.startswith("KR C4 127.0.0.1 eki ")
    finally:
        client.close()
        mock.stop()
    assert mock.crashed is None, mock.errors


def test_the_guard_brakes_the_move_and_the_arm_stands():
    door = threading.Event()
    client, mock, _ = open_cell(
        guard=lambda: StopCause("the cell door opened", "door_open") if door.is_set() else None, brake_deg_s2=50.0
    )
    try:

        def open_door_when_moving():
            deadline = time.monotonic() + 5.0
            while not mock.moving and time.monotonic() < deadline:
                time.sleep(0.001)
            door.set()

        threading.Thread(target=open_door_when_moving, daemon=True).start()
        with pytest.raises(DeviceFault, match="the cell door opened") as exc:
            client.move(TARGET, 2)  # 2 % of 100 deg/s: long enough to be stopped on the way
        assert exc.value.code == "door_open"
        [(_, _, q_rest)] = mock.stops  # the controller braked once (interrupt 18's BRAKE on the RSI Stop)
        assert q_rest != pytest.approx(TARGET, abs=0.01)
        assert len(mock.rsi_stops) == 1  # one rising edge of Stop in the RSI answers
        # the move, then the EKI stop request for it if the moving thread looked before the arm stood
        assert [cmd.kind for cmd in mock.commands] in ([1], [1, 2])
        door.clear()
        assert client.wait_settled(0.0005, 0.1, 2.0) == pytest.approx(q_rest, abs=1e-4)
    finally:
        client.close()
        mock.stop()
    assert GUARD_S <= 1 / 20  # the door is read at 20 Hz or faster during the move (issue 11)


def test_frames_from_another_address_are_not_read():
    client, mock, _ = open_cell()
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as spoof:
            spoof.bind(("127.0.0.2", 0))  # loopback, but not the controller's address
            spoof.sendto(encode_rob(RobFrame(ipoc=10**12, aipos=TARGET), tcp=False), client.rsi.address)
            deadline = time.monotonic() + 2.0
            while not client.refused_peers and time.monotonic() < deadline:
                time.sleep(0.01)
        assert client.refused_peers and client.refused_peers[0][0] == "127.0.0.2"
        assert client.joints() == HOME
    finally:
        client.close()
        mock.stop()


def test_a_controller_that_disappears_ends_the_next_move_with_a_device_error():
    client, mock, _ = open_cell()
    try:
        mock.stop()  # switched off: EKI server and RSI stream gone
        t0 = time.monotonic()
        with pytest.raises(DeviceError):
            client.move(TARGET, 50)
        assert time.monotonic() - t0 < 10.0
    finally:
        client.close()


def test_a_second_client_for_the_same_rsi_port_is_refused_until_the_first_closes():
    """One campaign per arm: the claim is the RSI port, which a second client on this PC cannot take (a UDP port
    alone could be bound twice with SO_REUSEADDR)."""
    port = free_udp_port()
    first = KukaKrc4(54600, "127.0.0.1", port, controller_host="127.0.0.1")
    second = KukaKrc4(54600, "127.0.0.1", port, controller_host="127.0.0.1")
    try:
        first.listen()
        with pytest.raises(ConnectionLost, match=f"cannot listen for the claim of this robot .* on 127.0.0.1:{port}"):
            second.listen()
        first.close()
        second.listen()  # released
    finally:
        first.close()
        second.close()


def test_drives_off_mid_move_ends_the_move_with_the_controllers_code():
    client, mock, _ = open_cell()
    try:
        threading.Thread(target=lambda: wait_moving(mock) and mock.drives_off(), daemon=True).start()
        with pytest.raises(DeviceFault) as exc:
            client.move(TARGET, 2)
        assert exc.value.code == ERR_DRIVES_OFF  # configs/krc4/trackcal_eki.src FaultCode: 2 = drives not ready
        assert client.state().fault == ERROR_TEXT[ERR_DRIVES_OFF]
        client.reset_faults()  # drives on again (the mock's drives come back with the reset)
        client.move(TARGET, 100)
    finally:
        client.close()
        mock.stop()
    assert mock.crashed is None, mock.errors


def test_late_rsi_answers_stop_the_robot_after_the_ethernet_timeout():
    client, mock, _ = open_cell(answer_budget_s=1e-9)  # every answer misses the budget
    try:
        with pytest.raises((DeviceFault, DeviceError)):
            client.move(TARGET, 20)
        # more than the ETHERNET object's Timeout (100 late packets, KR_C4_RSI_4+/README.md) in a row
        assert mock.rsi_stopped and mock.consecutive_late == ETHERNET_TIMEOUT + 1
    finally:
        client.close()
        mock.stop()
    assert mock.crashed is None


def wait_moving(mock, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not mock.moving and time.monotonic() < deadline:
        time.sleep(0.001)
    return mock.moving
