"""drivers.ur.client.UrRtde against the mock UR controller (mocks/servers/ur) in its own process, through the
unmodified ur_rtde: connect, read, move and check, stop on the guard, a protective stop and its recovery, a robot in
local control, lost and stale connections. Each mock runs on its own loopback address (the UR ports are fixed)."""

import math
import socket
import subprocess
import sys
import threading
import time

import pytest

from trackcal.drivers.errors import ConnectionLost, DeviceFault, MotionRefused
from trackcal.drivers.interfaces import READ_FROM_DEVICE, DeviceIdentity, Robot
from trackcal.drivers.ur import client
from trackcal.drivers.ur.client import UrRtde
from trackcal.mocks.servers.ur.process import MockUrProcess

HOME = (0.0, -90.0, 90.0, -90.0, -90.0, 0.0)  # the mock's initial joints (mocks/servers/ur/controller.py HOME_RAD)


@pytest.fixture(scope="module")
def ur():
    """One mock for the tests that leave it in a sound state; unlock allowed at once (the real one waits 5 s)."""
    with MockUrProcess("127.0.0.21", seed=1, args=["--unlock-delay-s", "0"]) as mock:
        robot = UrRtde("127.0.0.21", connect_timeout_s=10.0)
        robot.connect()
        yield mock, robot
        robot.close()


def test_is_a_robot_and_reads_joints_and_tcp(ur):
    mock, robot = ur
    assert isinstance(robot, Robot)
    robot.move(HOME, 100)
    assert robot.joints() == HOME
    x, y, z, *_ = robot.tcp_pose()
    # the controller's own model at HOME: the UR10 flange about 1.3 m from the base axis at most (its reach)
    assert 0 < math.hypot(x, y) < 1300 and abs(z) < 1300
    assert robot.robot_mode() == 7 and robot.safety_mode() == 1  # RTDE guide: RUNNING, NORMAL
    assert robot.state().fault == "" and not robot.protective_stopped()


def test_identity_is_the_dashboard_servers_answers(ur):
    """`get serial number` (PolyScope 5.6 and later), `get robot model` and `PolyscopeVersion` (Universal Robots,
    "Dashboard Server e-Series"), compared with the replies read by hand on port 29999: the mock is PolyScope 5.11."""
    _, robot = ur
    with socket.create_connection(("127.0.0.21", 29999), timeout=5.0) as raw:
        lines = raw.makefile("rw", newline="\n")
        lines.readline()  # the greeting
        replies = []
        for command in ("get serial number", "get robot model", "PolyscopeVersion"):
            lines.write(command + "\n")
            lines.flush()
            replies.append(lines.readline().strip())
    ident = robot.identity()
    version = replies[2].split()[1]  # "URSoftware 5.11.1.108318 (Jan 16 2024)": the version number
    assert ident == DeviceIdentity(
        replies[0], f"Universal Robots {replies[1]}", f"PolyScope {version}", READ_FROM_DEVICE
    )
    assert ident.serial.isdigit() and version.startswith("5.11.")


def test_before_polyscope_5_6_the_serial_is_not_asked():
    """`get serial number` came with PolyScope 5.6 (ur_rtde's getSerialNumber refuses to send it before): a 5.4
    controller's identity has no serial, and its version."""
    with MockUrProcess("127.0.0.27", seed=5, args=["--version", "5.4.0.0"]):
        robot = UrRtde("127.0.0.27", connect_timeout_s=10.0)
        try:
            robot.connect()
            ident = robot.identity()
            assert ident.serial == "" and ident.software == "PolyScope 5.4.0.0"
        finally:
            robot.close()


def test_move_ends_at_the_target_exactly(ur):
    _, robot = ur
    target = (12.3456, -80.5, 75.25, -95.0, -88.8888, 7.0)
    robot.move(target, 100)
    assert robot.joints() == target  # the trust rule: the joints reported equal the target (4 decimals)
    assert robot.wait_settled(0.001, 0.05, 5.0) == target
    robot.move(HOME, 100)


def test_targets_outside_the_limits_or_box_are_refused_before_anything_moves(ur):
    mock, robot = ur
    moves = mock.state()["moves"]
    with pytest.raises(MotionRefused, match="joint limits"):
        robot.move((0, 0, 0, 0, 0, 400), 100)
    boxed = UrRtde("127.0.0.21", cell_box_check=lambda q: "a point leaves the box")
    with pytest.raises(MotionRefused, match="cell box"):
        boxed.check_target(HOME)
    with pytest.raises(MotionRefused, match="speed"):
        robot.move(HOME, 0)
    assert mock.state()["moves"] == moves


def test_the_guard_stops_a_move_with_stopj_and_the_arm_stands(ur):
    mock, robot = ur
    door = threading.Event()
    robot.motion_guard = lambda: "the cell door opened" if door.is_set() else None
    try:
        timer = threading.Timer(0.1, door.set)
        timer.start()
        with pytest.raises(DeviceFault, match="door opened") as exc:
            robot.move((60.0, -60.0, 60.0, -60.0, -60.0, 60.0), 100)
        assert exc.value.code == "stopped"
        first = robot.joints()
        time.sleep(0.2)
        assert robot.joints() == first != (60.0, -60.0, 60.0, -60.0, -60.0, 60.0)  # stopped short, and still
        assert 34 in mock.state()["commands"]  # ur_rtde STOPJ
        with pytest.raises(DeviceFault, match="refused: the cell door opened"):
            robot.move(HOME, 100)  # no move starts while the guard names a reason
    finally:
        robot.motion_guard = None
    robot.move(HOME, 100)


def test_stop_from_another_thread_ends_the_move(ur):
    _, robot = ur
    threading.Timer(0.1, robot.stop).start()
    with pytest.raises(DeviceFault, match="stop requested"):
        robot.move((-60.0, -100.0, 100.0, -100.0, -100.0, -60.0), 100)
    assert not robot.state().moving
    robot.stop()  # no move: a no-op
    robot.move(HOME, 100)


def test_a_protective_stop_ends_the_move_latched_until_reset():
    with MockUrProcess("127.0.0.22", seed=2, args=["--protective-stop-on-move", "1", "--unlock-delay-s", "0.5"]) as m:
        robot = UrRtde("127.0.0.22", connect_timeout_s=10.0)
        robot.connect()
        try:
            with pytest.raises(DeviceFault, match="protective stop") as exc:
                robot.move((40.0, -70.0, 70.0, -90.0, -90.0, 30.0), 100)
            assert exc.value.code == "protective_stop"
            assert robot.state().fault == "protective stop" and robot.protective_stopped()
            with pytest.raises(DeviceFault, match="protective stop"):
                robot.move(HOME, 100)  # refused while the stop is active
            robot.reset_faults()  # unlock (retried past the controller's unlock delay), popup, script again
            assert robot.state().fault == "" and m.state()["safety_mode"] == "NORMAL"
            robot.move(HOME, 100)
            assert robot.joints() == HOME
        finally:
            robot.close()


def test_local_control_is_one_clear_line():
    with MockUrProcess("127.0.0.23", seed=3, args=["--local"]):
        robot = UrRtde("127.0.0.23", connect_timeout_s=5.0)
        with pytest.raises(DeviceFault, match="local control: switch the teach pendant to Remote Control"):
            robot.connect()


def test_nothing_there_is_connection_lost_within_the_timeout():
    robot = UrRtde("127.0.0.24", connect_timeout_s=1.0)
    t0 = time.monotonic()
    with pytest.raises(ConnectionLost, match="not reachable within 1 s") as exc:
        robot.connect()
    assert "\n" not in str(exc.value)
    assert time.monotonic() - t0 < 30  # bounded: the retries stop at the deadline (plus one attempt)


LOST = """
import sys
from trackcal.drivers.errors import DeviceError
from trackcal.drivers.ur.client import UrRtde
from trackcal.mocks.servers.ur.process import MockUrProcess
with MockUrProcess(sys.argv[1], seed=4, args=[sys.argv[2], "1"]):
    robot = UrRtde(sys.argv[1], connect_timeout_s=10.0, stale_s=float(sys.argv[3]), move_timeout_s=20.0)
    robot.connect()
    try:
        robot.move((30.0, -60.0, 60.0, -60.0, -60.0, 30.0), 100)
        print("NO ERROR", flush=True)
    except DeviceError as exc:
        print(f"ERROR {type(exc).__name__}: {exc}", flush=True)
    robot.close()
"""


# The dropped connection is told by ur_rtde's receive thread, the stale stream by trackcal's clock: on a loaded machine
# ur_rtde's thread may see the close later than 0.3 s, and the drop was then reported as a stale stream. The drop case
# gives the stream 10 s, so that what it checks (a drop is ConnectionLost) does not race the stale limit.
@pytest.mark.parametrize(
    ("host", "fault", "stale_s", "error"),
    [
        ("127.0.0.25", "--drop-on-move", "10.0", "ConnectionLost"),
        ("127.0.0.26", "--stale-on-move", "0.3", "DeviceTimeout"),
    ],
)
def test_lost_and_stale_streams_end_the_move_in_one_line(host, fault, stale_s, error):
    """In a process of its own: after a dropped connection ur_rtde 1.6.5 may crash the process when its interfaces
    are released at exit (drivers/ur/client.py close), after trackcal has said why it stopped."""
    out = subprocess.run(
        [sys.executable, "-c", LOST, host, fault, stale_s], capture_output=True, text=True, timeout=120
    )
    lines = [line for line in out.stdout.splitlines() if line.startswith(("ERROR", "NO ERROR"))]
    assert len(lines) == 1 and lines[0].startswith(f"ERROR {error}: UR {host}: "), out.stdout + out.stderr


class _Refusing:
    """ur_rtde's control interface as a protective stop leaves it: its script stopped, moveJ returns False."""

    def moveJ(self, *args):
        return False


class _Stream:
    """ur_rtde's receive interface showing safety_status_bits with bit 2 (protective stop) after `late` reads: the
    receive interface trails the control one by a frame or two."""

    def __init__(self, late: int):
        self.reads = 0
        self.late = late

    def isConnected(self):
        return True

    def getSafetyStatusBits(self):
        self.reads += 1
        return 1 << 2 if self.reads > self.late else 0


def test_a_move_refused_because_of_a_protective_stop_says_so():
    """A protective stop raised between two moves stops the script; the next moveJ is refused. The cause is the
    protective stop (code protective_stop, latched), not a script that refuses (seen in the whole-suite run)."""
    robot = UrRtde("127.0.0.98")
    robot.control, robot.receive = _Refusing(), _Stream(late=2)
    with pytest.raises(DeviceFault, match="protective stop") as exc:
        robot._move((0.0,) * 6, 1.0)
    assert exc.value.code == "protective_stop" and robot.state().fault == "protective stop"
    robot.receive = _Stream(late=10**9)  # no safety stop: the script refused for another reason
    with pytest.raises(DeviceFault, match="not accepted") as exc:
        robot._move((0.0,) * 6, 1.0)
    assert exc.value.code == "refused"


class _StuckControl:
    """A control interface whose stopScript never returns until released (ur_rtde 1.6.5 once a stop has ended the
    script: tests/test_ur_safety.py hung in its teardown)."""

    def __init__(self) -> None:
        self.release, self.disconnected = threading.Event(), False

    def isConnected(self) -> bool:  # noqa: N802 (ur_rtde's name)
        return True

    def stopScript(self) -> None:  # noqa: N802
        self.release.wait()

    def disconnect(self) -> None:
        self.disconnected = True


class _Interface(_StuckControl):
    def stopScript(self) -> None:  # noqa: N802
        raise AssertionError("only a control interface has a script to stop")


def test_close_gives_up_on_an_interface_whose_call_never_returns():
    robot = client.UrRtde("127.0.0.1", io_timeout_s=0.2)
    stuck, receive, dashboard = _StuckControl(), _Interface(), _Interface()
    robot.control, robot.receive, robot.dashboard = stuck, receive, dashboard
    robot.close()  # returns: it waited io_timeout_s for the stuck call, not forever
    try:
        assert receive.disconnected and dashboard.disconnected  # the others are closed as before
        assert stuck in client._LOST_LINKS and not stuck.disconnected  # kept, never touched again
        assert robot.control is None and robot.receive is None and robot.dashboard is None
    finally:
        stuck.release.set()
        client._LOST_LINKS.remove(stuck)
