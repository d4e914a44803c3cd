"""The ABB client (drivers/abb/client.py) against the mock IRC5 in its own process (mocks/servers/abb): a move, the
motion guard's stop on the path, the controller's own stops latched until reset, 503 and a controller that
disappears, one campaign per arm."""

from __future__ import annotations

import threading
import time

import pytest

from tests.helpers import free_udp_port
from trackcal.drivers.abb.client import AbbRws
from trackcal.drivers.errors import ConnectionLost, DeviceFault, DeviceTimeout, MotionRefused
from trackcal.drivers.interfaces import READ_FROM_DEVICE, DeviceIdentity, StopCause
from trackcal.mocks.servers.abb.process import MockAbbProcess

LIMITS = ((-165, 165), (-110, 110), (-110, 70), (-160, 160), (-120, 120), (-400, 400))  # configs/robots/irb120.yaml


@pytest.fixture(scope="module")
def mock():
    with MockAbbProcess(seed=5) as m:
        yield m


@pytest.fixture
def robot(mock):
    mock.fault("release")
    r = AbbRws(*mock.address, joint_limits_deg=LIMITS, io_timeout_s=3.0)
    r.connect()
    r.reset_faults()
    yield r
    r.close()


def test_connect_reads_the_identity_and_a_move_ends_standing_at_its_target(robot, mock):
    ident = robot.controller_identity
    assert ident is not None and ident.serial and ident.robotware.startswith("6.")
    # the interface's form (drivers.interfaces.DeviceIdentity): ctrl/identity's ctrl-id, rw/system's name and
    # rwversion (Robot Web Services manual, "Get Controller Identity", "Get RobotWare System Information")
    assert robot.identity() == DeviceIdentity(
        ident.serial, f"IRC5 system {ident.system}", f"RobotWare {ident.robotware}", READ_FROM_DEVICE
    )
    target = (12.3456, -10.0, 20.0, 5.0, 45.0, -30.0)
    robot.move(target, 100)
    assert robot.joints() == target
    assert robot.wait_settled(1e-3, 0.1, 5.0) == target
    assert mock.state()["pers"]["trackcal_done"] == mock.state()["pers"]["trackcal_move"]
    assert robot.state().moving is False and robot.state().fault == ""


def test_targets_outside_the_limits_are_refused_before_anything_is_sent(robot, mock):
    before = mock.state()["pers"]["trackcal_move"]
    with pytest.raises(MotionRefused) as err:
        robot.move((0, 0, 80, 0, 30, 0), 50)  # axis 3 above its 70 deg
    assert err.value.code == "joint_limits"
    assert mock.state()["pers"]["trackcal_move"] == before


def test_the_guard_stops_the_arm_on_its_path_with_the_causes_code(robot, mock):
    start = robot.joints()
    door = threading.Event()
    robot.motion_guard = lambda: StopCause("the door opened", "door_open") if door.is_set() else None
    threading.Timer(0.15, door.set).start()
    target = (start[0] + 120 if start[0] < 0 else start[0] - 120, *start[1:])
    with pytest.raises(DeviceFault) as err:
        robot.move(target, 10)  # 120 deg at 25 deg/s: ~5 s, stopped after ~0.15 s
    assert err.value.code == "door_open"
    stood = robot.joints()
    assert stood != target and min(start[0], target[0]) < stood[0] < max(start[0], target[0])
    time.sleep(0.3)
    assert robot.joints() == stood  # it stands: braked, not resumed
    assert mock.state()["execution"] == "stopped"
    robot.motion_guard = None
    robot.reset_faults()  # RAPID from main again, the stopped move dropped
    time.sleep(0.3)
    assert robot.joints() == stood
    robot.move(start, 100)
    assert robot.joints() == start


def test_stop_from_another_thread_returns_once_the_arm_stands(robot):
    start = robot.joints()
    target = (start[0] + 100 if start[0] < 0 else start[0] - 100, *start[1:])
    errors = []
    mover = threading.Thread(target=lambda: errors.append(pytest.raises(DeviceFault, robot.move, target, 10)))
    mover.start()
    time.sleep(0.2)
    robot.stop()
    mover.join(10)
    assert errors and errors[0].value.code == "stopped"
    q = robot.joints()
    time.sleep(0.2)
    assert robot.joints() == q
    robot.reset_faults()


def test_a_guard_stop_by_the_controller_ends_the_move_and_stays_latched_until_released(robot, mock):
    start = robot.joints()
    target = (start[0] + 100 if start[0] < 0 else start[0] - 100, *start[1:])
    threading.Timer(0.2, mock.fault, ("guardstop",)).start()
    with pytest.raises(DeviceFault) as err:
        robot.move(target, 10)
    assert err.value.code == "guard_stop"
    assert robot.state().fault == "guardstop"
    with pytest.raises(DeviceFault):
        robot.move(start, 10)  # latched: refused before anything is sent
    with pytest.raises(DeviceFault) as err:
        robot.reset_faults()  # the controller still holds it
    assert err.value.code == "guard_stop"
    mock.fault("release")
    robot.reset_faults()
    assert robot.state().fault == "" and mock.state()["ctrlstate"] == "motoron"
    robot.move(start, 100)


def test_motors_off_mid_move_ends_it(robot, mock):
    start = robot.joints()
    target = (start[0] + 90 if start[0] < 0 else start[0] - 90, *start[1:])
    threading.Timer(0.2, mock.fault, ("motoroff",)).start()
    with pytest.raises(DeviceFault) as err:
        robot.move(target, 10)
    assert err.value.code == "motors_off"
    robot.reset_faults()  # motors on again
    assert mock.state()["ctrlstate"] == "motoron"


def test_a_busy_controller_is_one_line_with_its_status(robot, mock):
    mock.busy(1)
    with pytest.raises(DeviceFault) as err:
        robot.joints()
    assert "HTTP 503" in str(err.value) and "\n" not in str(err.value)
    assert len(robot.joints()) == 6


def test_one_campaign_per_arm_on_this_pc(mock):
    a, b = AbbRws(*mock.address), AbbRws(*mock.address)
    a.claim()
    try:
        with pytest.raises(ConnectionLost):
            b.claim()
    finally:
        a.close()
    b.claim()
    b.close()


def test_a_controller_that_disappears_mid_move_is_connection_lost_or_timeout():
    with MockAbbProcess(seed=6) as gone:
        r = AbbRws(*gone.address, io_timeout_s=1.0)
        r.connect()
        threading.Timer(0.2, gone.kill).start()
        t0 = time.monotonic()
        with pytest.raises((ConnectionLost, DeviceTimeout)):
            r.move((100, 0, 0, 0, 30, 0), 5)
        assert time.monotonic() - t0 < 5.0  # within a few io timeouts, not the move timeout
        r.close()


def test_with_egm_a_settle_counts_frames_and_a_silent_stream_stops_the_move():
    port = free_udp_port()
    with MockAbbProcess(seed=8, args=["--egm", f"127.0.0.1:{port}"]) as m:
        r = AbbRws(*m.address, egm=("127.0.0.1", port), egm_stale_s=0.3, io_timeout_s=3.0)
        r.connect()
        try:
            target = (5.0, 5.0, 5.0, 5.0, 35.0, 5.0)
            r.move(target, 100)
            t0 = time.monotonic()
            assert r.wait_settled(1e-3, 0.2, 5.0) == target  # 0.2 s of controller time: 50 EGM frames of 4 ms
            assert time.monotonic() - t0 < 5.0
            assert m.control("egm off") == "ok"
            with pytest.raises(DeviceFault) as err:
                r.move((-60.0, 5.0, 5.0, 5.0, 35.0, 5.0), 10)
            assert err.value.code == "egm_stale"
            assert m.control("egm on") == "ok"
            time.sleep(0.1)
            r.reset_faults()
            r.move(target, 100)
            assert r.joints() == target
        finally:
            r.close()
