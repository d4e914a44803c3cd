"""Safety of the UR over sockets: the cell door (the mock Modbus PLC, read by campaign/cells/checks.motion_guard)
opened 20 ms into a move brakes the mock UR (its own process) through trackcal's UR client: stopJ is sent, every
joint stays within its braking distance from where the stop was sent, and the arm then stands. A second ur_rtde
receive client in this process watches the arm independently of trackcal's."""

import math
import threading
import time

import pytest

from trackcal.campaign.cells.checks import motion_guard
from trackcal.drivers.errors import DeviceFault
from trackcal.drivers.interfaces import RealClock
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.drivers.ur.client import UrRtde
from trackcal.mocks.servers.plc import MockPlc
from trackcal.mocks.servers.ur.follow import JointFollower
from trackcal.mocks.servers.ur.process import MockUrProcess

HOST = "127.0.0.29"
CYCLE_S = 0.002  # RTDE at 500 Hz (e-Series; RTDE guide)


class Watcher(JointFollower):
    """Every frame of the controller's stream, in order (a reader of its own: mocks/servers/ur/follow.py), as
    (controller time s, q rad)."""

    def __init__(self, host: str) -> None:
        super().__init__(host, lambda q: None)
        self.seen: list[tuple[float, tuple[float, ...]]] = []
        self.start()

    def _frame(self, recipe, body) -> None:
        super()._frame(recipe, body)
        self.seen.append((self.timestamp, tuple(math.radians(v) for v in self.q_deg)))

    def close(self) -> None:
        self.stop()


@pytest.fixture
def cell():
    plc = MockPlc(clock=RealClock()).start()
    plc.close_door()
    cellio = ModbusCellIO(*plc.address, timeout_s=2.0)
    cellio.connect()
    with MockUrProcess(HOST, seed=7) as ur:
        robot = UrRtde(HOST, motion_guard=motion_guard(cellio), connect_timeout_s=10.0)
        robot.connect()
        watcher = Watcher(HOST)
        try:
            yield plc, ur, robot, watcher
        finally:
            watcher.close()
            robot.close()
            cellio.close()
            plc.stop()


def test_door_opened_20_ms_into_a_move_brakes_within_the_braking_distance_then_still(cell):
    plc, ur, robot, watcher = cell
    target = (90.0, -40.0, 40.0, -40.0, -40.0, 90.0)
    started = threading.Event()
    opened_at: list[float] = []

    def open_the_door_20_ms_in():
        started.wait(10)
        while not ur.state()["moving"]:
            time.sleep(0.001)
        time.sleep(0.020)
        opened_at.append(time.monotonic())
        plc.open_door()

    threading.Thread(target=open_the_door_20_ms_in, daemon=True).start()
    started.set()
    with pytest.raises(DeviceFault, match="the cell door opened") as exc:
        robot.move(target, 100)
    # the guard's cause names its code (campaign/cells/checks.motion_guard: door_open); ur_rtde's STOPJ reached
    # the script
    assert exc.value.code == "door_open" and 34 in ur.state()["commands"]
    time.sleep(0.3)
    frames = list(watcher.seen)
    sent = robot.stop_sent_at
    assert sent is not None and opened_at and sent >= opened_at[0]
    # joint speeds from consecutive frames (every frame of the stream, in order)
    speeds = [
        tuple((b - a) / (t1 - t0) for a, b in zip(q0, q1, strict=True))
        for (t0, q0), (t1, q1) in zip(frames, frames[1:], strict=False)
        if t1 > t0
    ]
    # braking starts at the frame of the highest speed (stopJ reached the controller's cycle there): from it the
    # joints decelerate together to rest in the time the leading one needs at stopJ's deceleration, each travelling
    # |v| t / 2; allowed on top: two RTDE cycles at that speed (the frame seen, the command's cycle) and the
    # 0.0001 deg step
    k = max(range(len(speeds)), key=lambda i: max(abs(v) for v in speeds[i]))
    v_stop, q_stop = speeds[k], frames[k + 1][1]
    assert max(abs(v) for v in v_stop) > 0  # it was moving when it braked
    t_stop = max(abs(v) for v in v_stop) / math.radians(robot.stop_deceleration_deg_s2)
    rest = frames[-1][1]
    for q0, v, q1 in zip(q_stop, v_stop, rest, strict=True):
        assert abs(q1 - q0) <= abs(v) * t_stop / 2 + abs(v) * 2 * CYCLE_S + math.radians(1e-4)
    # then still: the last 50 frames (0.1 s) report the same joints, short of the target
    tail = [q for _, q in frames[-50:]]
    assert all(q == tail[0] for q in tail)
    assert max(abs(math.degrees(q) - t) for q, t in zip(tail[0], target, strict=True)) > 1.0
    print(f"door open -> stopJ sent: {1000 * (sent - opened_at[0]):.1f} ms (wall clock, loaded machine)")
