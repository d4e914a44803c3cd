"""The mock UR e-Series controller (mocks/servers/ur) against third-party clients, each mock in its own process on
its own loopback address (127.0.0.121..): the unmodified ur_rtde 1.6.5 (PyPI ur-rtde: RTDEReceiveInterface,
RTDEControlInterface, DashboardClient) and Universal Robots' own pure-Python RTDE client (vendored under
tests/thirdparty/rtde, BSD-3). Then the framing byte for byte against that client's serializer, fuzzed, and the
motion and safety rules on the controller alone (no sockets), tick by tick.
"""

from __future__ import annotations

import contextlib
import math
import random
import socket
import struct
import subprocess
import sys
import threading
import time

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from tests.helpers import ROOT
from trackcal.mocks.servers.ur import rtde_codec as rc
from trackcal.mocks.servers.ur.controller import (
    MOVEJ,
    MOVEL,
    NORMAL,
    PAUSED,
    PLAYING,
    PROTECTIVE_STOP,
    SAFEGUARD_STOP,
    STOPJ,
    UrController,
)
from trackcal.mocks.servers.ur.follow import JointFollower
from trackcal.mocks.servers.ur.kinematics import NOMINAL_A, NOMINAL_D, factory_calibration, tcp_pose
from trackcal.mocks.servers.ur.motion import TICK_S, UR10_VMAX_RAD_S, Motion
from trackcal.mocks.servers.ur.primary import (
    KINEMATICS_INFO,
    ROBOT_MESSAGE,
    ROBOT_STATE,
    kinematics_info,
    parse_kinematics_info,
)
from trackcal.mocks.servers.ur.process import MockUrProcess
from trackcal.mocks.servers.ur.server import (
    DASHBOARD_PORT,
    PRIMARY_PORT,
    REALTIME_PORT,
    RTDE_PORT,
    SECONDARY_PORT,
    RtdeSession,
)

sys.path.insert(0, str(ROOT / "tests" / "thirdparty"))
from rtde import rtde as ur_rtde_py  # noqa: E402  (UR's client, vendored: tests/thirdparty/rtde/VENDORED.md)
from rtde import serialize as ur_serialize  # noqa: E402

rtde_receive = pytest.importorskip("rtde_receive")
rtde_control = pytest.importorskip("rtde_control")
dashboard_client = pytest.importorskip("dashboard_client")

HOME = [0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0]


def wait_until(cond, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def returns_within(seconds: float, call) -> bool:
    """Run a blocking client call in a thread (ur_rtde releases the interpreter lock while it waits); False if it
    has not returned after `seconds` of wall time (the thread is left to the client's own timeout)."""
    worker = threading.Thread(target=call, daemon=True)
    worker.start()
    worker.join(seconds)
    return not worker.is_alive()


# ----------------------------------------------------------------------------------------------- ur_rtde
def test_ur_rtde_reads_moves_and_stops():
    host = "127.0.0.121"
    with MockUrProcess(host, seed=3, args=["--q0-deg", "0,0,0,0,0,0"]) as ur:
        r = rtde_receive.RTDEReceiveInterface(host)
        c = rtde_control.RTDEControlInterface(host)
        d = dashboard_client.DashboardClient(host)
        d.connect()
        seen: list[tuple[float, ...]] = []
        follower = JointFollower(host, seen.append).start()  # the twin's side: joints in degrees
        try:
            assert follower.fresh(5.0) and follower.q_deg == (0.0,) * 6
            assert r.getActualQ() == [0.0] * 6
            # UR's published UR10 DH at q = 0: the flange at (a2 + a3, -(d4 + d6), d1 - d5); the mock's factory
            # calibration moves it by a few tenths of a millimetre
            x, y, z = r.getActualTCPPose()[:3]
            expected = (NOMINAL_A[1] + NOMINAL_A[2], -(NOMINAL_D[3] + NOMINAL_D[5]), NOMINAL_D[0] - NOMINAL_D[4])
            assert expected == pytest.approx((-1.1843, -0.256141, 0.0116), abs=1e-9)
            assert (x, y, z) == pytest.approx(expected, abs=2e-3)
            assert r.getRobotMode() == 7 and r.getSafetyMode() == NORMAL  # RUNNING, NORMAL (RTDE guide)
            assert "5.11.1" in d.polyscopeVersion() and d.isInRemoteControl()
            assert d.robotmode() == "Robotmode: RUNNING" and d.safetystatus() == "Safetystatus: NORMAL"

            target = [0.3, -1.2, 1.1, -1.0, -1.4, 0.5]
            assert c.moveJ(target, 1.05, 1.4)
            # the receive interface's frames trail the control interface's by a cycle or two
            assert wait_until(lambda: r.getActualQ() == pytest.approx(target, abs=1e-4), 1.0)
            assert ur.state()["q"] == target  # the controller ends the profile on the target exactly
            assert follower.fresh() and follower.q_deg == pytest.approx([math.degrees(v) for v in target], abs=1e-9)

            far = [1.3, -1.2, 1.1, -1.0, -1.4, 0.5]  # 1 rad on the base at 0.5 rad/s: 2+ s
            assert c.moveJ(far, 0.5, 1.0, True)
            assert wait_until(lambda: r.getActualQ()[0] > 0.45)
            c.stopJ(2.0)
            state = ur.state()  # stopJ returns when the arm stands (the script's blocking stopj)
            assert not state["moving"]
            stopped = state["q"]
            assert 0.45 < stopped[0] < far[0] - 0.2  # it stopped before the target: braking at 2 rad/s^2 from
            assert wait_until(lambda: r.getActualQ() == stopped, 1.0)  # at most 0.5 rad/s takes 0.0625 rad
            time.sleep(0.1)
            assert r.getActualQ() == stopped  # and stands
            assert ur.state()["commands"] == [MOVEJ, MOVEJ, STOPJ]
            assert ur.state()["out_int_upper"][0] == 0  # the lower range in use
            assert len(seen) == follower.frames and seen[-1] == follower.q_deg

            # a client on the upper range registers (24..): its script says so, the mock answers there
            c.stopScript()
            c.disconnect()
            flags = rtde_control.RTDEControlInterface.FLAG_UPPER_RANGE_REGISTERS
            c = rtde_control.RTDEControlInterface(
                host, -1.0, flags | rtde_control.RTDEControlInterface.FLAG_UPLOAD_SCRIPT
            )
            assert c.moveJ(target, 1.05, 1.4)
            state = ur.state()
            # the answer went out on output_int_register_24 (2 done, then 1 ready once the client cleared)
            assert state["reg_offset"] == [24, 24] and state["out_int_upper"][0] in (1, 2)
            assert state["commands"] == [MOVEJ, MOVEJ, STOPJ, 255, MOVEJ]  # 255: stopScript
        finally:
            follower.stop()
            c.stopScript()
            for client in (c, r, d):
                client.disconnect()


def test_ur_rtde_moves_at_the_requested_speed_and_stopj_stops_it_short():
    """Issue 42: ur_rtde's moveJ(q, 0.1, 0.1) over 0.1 rad of the base takes d/v + v/a = 2 s (URScript movej: "v:
    joint speed of leading axis, a: joint acceleration of leading axis"; at v^2/a = d the trapezoid has no cruise), on
    the controller's clock (RTDE timestamp) and so at least that on the wall clock (the mock at --speed 1 never runs
    ahead of it; a loaded machine only makes it slower, so these are lower bounds); no reported speed above v. Then
    a two-joint move: the other joint scaled to the leading one (its speed half the base's in every frame), and a
    stopJ once the base cruises stops it short of the target, at least v^2 / 2D past where the stop was sent."""
    host = "127.0.0.126"
    with MockUrProcess(host, seed=5, args=["--q0-deg", "0,0,0,0,0,0"]):
        r = rtde_receive.RTDEReceiveInterface(host)
        c = rtde_control.RTDEControlInterface(host)
        try:
            d, v, a = 0.1, 0.1, 0.1
            target = [d, 0.0, 0.0, 0.0, 0.0, 0.0]
            ts0, t0 = r.getTimestamp(), time.monotonic()
            assert c.moveJ(target, v, a, True)
            peak = 0.0
            while r.getActualQ() != target and time.monotonic() - t0 < 60:
                peak = max(peak, abs(r.getActualQd()[0]))
                time.sleep(0.002)
            wall, controller = time.monotonic() - t0, r.getTimestamp() - ts0
            assert r.getActualQ() == target
            assert controller >= d / v + v / a - 2 * TICK_S and wall >= d / v + v / a - 2 * TICK_S
            assert 0.5 * v < peak <= v * (1 + 1e-9)

            far = [1.2, 0.6, 0.0, 0.0, 0.0, 0.0]  # from `target`: the base leads (1.1 rad), the shoulder 0.6 rad
            v, a, decel = 0.3, 0.6, 0.6
            assert c.moveJ(far, v, a, True)
            ratio = 0.6 / 1.1
            t0 = time.monotonic()
            while True:
                qd = r.getActualQd()
                assert qd[1] == pytest.approx(ratio * qd[0], abs=1e-9)  # one frame's speeds: synchronised
                if qd[0] >= v * (1 - 1e-9) or time.monotonic() - t0 > 60:
                    break
                time.sleep(0.002)
            q_sent = r.getActualQ()[0]
            assert returns_within(10.0, lambda: c.stopJ(decel, False))  # returns when the arm stands (blocking stopj)
            assert wait_until(lambda: r.getActualQd() == [0.0] * 6, 5.0)
            q_stop = r.getActualQ()
            assert q_stop[0] >= q_sent + v * v / (2 * decel) - 1e-6  # braking from v at D: v^2 / 2D
            assert q_stop[0] < far[0] - 0.1  # short of the target
            assert q_stop[1] - target[1] == pytest.approx(ratio * (q_stop[0] - target[0]), abs=1e-9)  # on the path
        finally:
            c.stopScript()
            c.disconnect()
            r.disconnect()


def _off_line(p, a, b) -> float:
    """Distance of point p from the line through a and b (m)."""
    u = [y - x for x, y in zip(a, b, strict=True)]
    n = math.sqrt(sum(x * x for x in u))
    w = [y - x for x, y in zip(a, p, strict=True)]
    along = sum(x * y for x, y in zip(w, u, strict=True)) / n
    return math.sqrt(max(0.0, sum(x * x for x in w) - along * along))


def test_ur_rtde_movel_keeps_the_tcp_on_the_line_at_the_tool_speed():
    """Issue 42: URScript movel(pose, a, v), "linear in tool-space", a and v of the tool (UR Script Manual, movel);
    the mock ended the script on it ("not emulated"). 0.1 m along x at v = 0.05 m/s, a = 0.1 m/s^2 takes d/v + v/a
    = 2.5 s (a trapezoid: v^2/a = 0.025 m < d) on the controller's clock, so at least that on the wall clock; every
    TCP pose read is on the line (10 um: the joints are linear between inverse-kinematics waypoints 1 mm apart here,
    mocks/servers/ur/linear.py), no TCP speed above v (0.1 %: RTDE's TCP speed is a difference over one tick), the
    orientation kept, the target reached to a micrometre. Then stopL mid-move stops the tool short of the target, on
    the line, at least v^2 / 2D past where the stop was sent."""
    host = "127.0.0.127"
    with MockUrProcess(host, seed=6, args=["--q0-deg", "0,-60,80,-110,-90,0"]) as ur:
        r = rtde_receive.RTDEReceiveInterface(host)
        c = rtde_control.RTDEControlInterface(host)
        try:
            start = r.getActualTCPPose()
            d, v, a = 0.1, 0.05, 0.1
            target = [start[0] + d, *start[1:]]
            ts0, t0 = r.getTimestamp(), time.monotonic()
            assert c.moveL(target, v, a, True)
            off = fastest = 0.0
            while time.monotonic() - t0 < 60:
                pose, speed = r.getActualTCPPose(), r.getActualTCPSpeed()
                off = max(off, _off_line(pose[:3], start[:3], target[:3]))
                fastest = max(fastest, math.sqrt(sum(x * x for x in speed[:3])))
                if pose[:3] == pytest.approx(target[:3], abs=1e-6):
                    break
                time.sleep(0.002)
            wall, controller = time.monotonic() - t0, r.getTimestamp() - ts0
            assert r.getActualTCPPose()[:3] == pytest.approx(target[:3], abs=1e-6), ur.state()["log"]
            assert controller >= d / v + v / a - 2 * TICK_S and wall >= d / v + v / a - 2 * TICK_S
            assert off < 1e-5 and 0.5 * v < fastest <= v * 1.001
            assert r.getActualTCPPose()[3:] == pytest.approx(start[3:], abs=1e-6)

            back = [start[0] - 0.1, *start[1:]]  # 0.2 m back at 0.1 m/s: cruising from 0.025 m to 0.175 m
            v, a, decel = 0.1, 0.2, 0.5
            assert c.moveL(back, v, a, True)
            t0 = time.monotonic()
            while math.sqrt(sum(x * x for x in r.getActualTCPSpeed()[:3])) < 0.99 * v and time.monotonic() - t0 < 60:
                time.sleep(0.002)
            x_sent = r.getActualTCPPose()[0]
            # returns when the tool stands: well within 10 s (braking takes v / D = 0.2 s); it once never returned
            # (test_every_stop_ends_once_braked), so a hang fails here instead of holding the suite
            assert returns_within(10.0, lambda: c.stopL(decel, False)), ur.state()
            assert wait_until(lambda: r.getActualQd() == [0.0] * 6, 5.0)
            stop = r.getActualTCPPose()
            assert x_sent - stop[0] >= 0.99 * v * v / (2 * decel)  # braking from (at least 99 % of) v at D
            assert stop[0] > back[0] + 0.01 and _off_line(stop[:3], target[:3], back[:3]) < 1e-5
            assert ur.state()["commands"] == [3, 3, 33]  # movel, movel, stopl (ur_rtde's command ids)
        finally:
            c.stopScript()
            c.disconnect()
            r.disconnect()


def test_ur_rtde_protective_stop_then_recovery():
    host = "127.0.0.122"
    args = ["--protective-stop-on-move", "1", "--unlock-delay-s", "0.5"]
    with MockUrProcess(host, seed=4, args=args) as ur:
        r = rtde_receive.RTDEReceiveInterface(host)
        c = rtde_control.RTDEControlInterface(host)
        d = dashboard_client.DashboardClient(host)
        d.connect()
        try:
            target = [0.8, -1.2, 1.1, -1.0, -1.4, 0.5]
            assert not c.moveJ(target, 1.05, 1.4)  # protective stop halfway: the move fails
            assert wait_until(r.isProtectiveStopped, 2.0)  # the receive interface's next frame
            assert r.getSafetyStatusBits() & 4 and r.getSafetyMode() == PROTECTIVE_STOP
            assert wait_until(lambda: ur.state()["moving"] is False)
            assert abs(r.getActualQ()[0] - target[0]) > 0.1
            assert d.safetystatus() == "Safetystatus: PROTECTIVE_STOP"
            assert not c.isProgramRunning()
            assert not c.moveJ(target, 1.05, 1.4)  # still stopped: refused

            time.sleep(0.6)  # the mock's unlock delay (the real controller's is 5 s), counted in controller time,
            assert wait_until(lambda: _unlock(d), 5.0)  # which a loaded machine may run slower than the wall clock
            d.closeSafetyPopup()
            assert d.safetystatus() == "Safetystatus: NORMAL"
            assert wait_until(lambda: not r.isProtectiveStopped(), 2.0)  # the next RTDE frames say so too
            assert c.reuploadScript()
            assert wait_until(c.isProgramRunning, 5.0)
            assert c.moveJ(target, 1.05, 1.4)
            assert wait_until(lambda: r.getActualQ() == pytest.approx(target, abs=1e-4), 1.0)

            # a safeguard stop (a door) pauses the move and the program; its reset resumes both
            back = [0.45, *target[1:]]
            assert c.moveJ(back, 0.1, 1.0, True)  # 3.5 s of travel: the stop lands mid-move even on a loaded machine
            assert wait_until(lambda: r.getActualQ()[0] < 0.75)
            ur.inject("safeguard_stop")
            assert wait_until(lambda: r.getSafetyMode() == SAFEGUARD_STOP and r.getSafetyStatusBits() & (1 << 4), 2.0)
            assert wait_until(lambda: not ur.state()["moving"], 2.0) and ur.state()["runtime_state"] == PAUSED
            held = r.getActualQ()[0]
            assert 0.45 < held < 0.75
            ur.inject("safeguard_reset")
            assert wait_until(lambda: r.getActualQ() == pytest.approx(back, abs=1e-4), 20.0)
            assert c.isProgramRunning()
        finally:
            c.stopScript()
            for client in (c, r, d):
                client.disconnect()


def _connects(host: str, port: int) -> bool:
    try:
        socket.create_connection((host, port), timeout=1.0).close()
    except OSError:
        return False
    return True


def _unlock(d) -> bool:
    try:
        d.unlockProtectiveStop()  # raises unless "Protective stop releasing"
    except RuntimeError as exc:
        assert "Cannot unlock protective stop until 5s after occurrence" in str(exc)
        return False
    return True


def test_ur_rtde_refuses_a_robot_in_local_control():
    host = "127.0.0.125"
    with MockUrProcess(host, seed=7, args=["--local"]) as ur:
        with pytest.raises(RuntimeError, match="remote control"):  # ur_rtde asks `is in remote control` (5.6+)
            rtde_control.RTDEControlInterface(host)
        assert ur.state()["scripts"] == []


# ----------------------------------------------------------------------------------------------- UR's client
def test_urs_python_client_reads_its_own_recipe():
    host = "127.0.0.123"
    with MockUrProcess(host, seed=5) as ur:
        con = ur_rtde_py.RTDE(host, RTDE_PORT)
        con.connect()
        try:
            assert con.get_controller_version() == (5, 11, 1, 108318)
            names = ["timestamp", "actual_q", "robot_mode", "safety_status_bits"]
            types = ["DOUBLE", "VECTOR6D", "INT32", "UINT32"]  # RTDE guide
            assert con.send_output_setup(names, types, frequency=125)
            t0 = time.monotonic()  # before the start: frames that wait in the socket count in the span
            assert con.send_start()
            frames = [con.receive()]
            # frames that waited in the socket before the first one returned are skipped before it, outside the
            # stamps' span (a loaded machine: the client keeps the newest of a burst, rtde.py's __recv)
            skipped_before = con.skipped_package_count
            frames += [con.receive() for _ in range(199)]
            wall = time.monotonic() - t0
            stamps = [f.timestamp for f in frames]
            gaps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
            steps = [round(g / 0.008) for g in gaps]
            # every frame 1/125 s of controller time after the previous one; frames it skipped (it keeps the newest
            # of a burst) are counted by the client
            assert all(s >= 1 for s in steps)
            assert all(abs(g - s * 0.008) < 1e-6 for g, s in zip(gaps, steps, strict=True))
            assert sum(steps) == len(frames) - 1 + con.skipped_package_count - skipped_before
            assert (len(frames) + con.skipped_package_count) / wall < 125 * 1.5  # not faster than real time
            assert all(
                f.actual_q == pytest.approx(HOME) and f.robot_mode == 7 and f.safety_status_bits == 1 for f in frames
            )

            assert con.send_pause()  # 'P': answered, and no frame after the answer
            time.sleep(0.2)
            assert not con.has_data()
            assert con.send_start()
            assert con.receive() is not None

            ur.inject("stale")  # frames stop, the connection stays
            assert any(con.receive() is None for _ in range(100))  # after those on their way: the 1 s timeout
            assert con.receive() is None
            ur.inject("stale off")
            assert con.receive() is not None
            ur.inject("drop")
            with pytest.raises(ur_rtde_py.RTDEException):
                for _ in range(1000):
                    con.receive()
        finally:
            con.disconnect()

        ur.inject("unreachable 1.5")  # gone from the network: refused, then back
        with pytest.raises(OSError):
            socket.create_connection((host, RTDE_PORT), timeout=1.0).close()
        assert wait_until(lambda: _connects(host, RTDE_PORT), 10.0)

        # NOT_FOUND and IN_USE, as the client's serializer reads them
        a, b = ur_rtde_py.RTDE(host, RTDE_PORT), ur_rtde_py.RTDE(host, RTDE_PORT)
        a.connect()
        b.connect()
        try:
            with pytest.raises(ValueError, match="NOT_FOUND"):
                a.send_output_setup(["actual_q", "no_such_variable"])
            assert a.send_input_setup(["input_int_register_5"], ["INT32"]) is not None
            with pytest.raises(ValueError, match="already in use"):
                b.send_input_setup(["input_int_register_5"])
        finally:
            a.disconnect()
            b.disconnect()


def test_garbage_closes_the_connection_and_the_mock_serves_on():
    host = "127.0.0.124"
    with MockUrProcess(host, seed=6) as ur:
        with socket.create_connection((host, RTDE_PORT), timeout=5) as s:
            s.sendall(b"\x00\x05\xffgarbage that is no RTDE")
            assert s.recv(100) == b""  # closed
        with socket.create_connection((host, RTDE_PORT), timeout=5) as s:
            s.sendall(struct.pack(">HBH", 5, rc.REQUEST_PROTOCOL_VERSION, 2))
            assert s.recv(100) == struct.pack(">HBB", 4, rc.REQUEST_PROTOCOL_VERSION, 1)  # accepted
        r = rtde_receive.RTDEReceiveInterface(host)
        assert r.getActualQ() == pytest.approx(HOME)
        r.disconnect()
        assert any("RTDE" in e for e in ur.state()["errors"])

        # the primary interface: the version message, then robot state with the arm's calibrated DH
        with socket.create_connection((host, PRIMARY_PORT), timeout=5) as s:
            version = _primary_message(s)
            assert version[0] == ROBOT_MESSAGE and version[1][9] == 3  # VERSION
            name_len = version[1][10]
            assert version[1][11 : 11 + name_len] == b"URControl"
            assert struct.unpack_from(">BBii", version[1], 11 + name_len) == (5, 11, 1, 108318)
            state = _primary_message(s)
            assert state[0] == ROBOT_STATE and state[1][4] == KINEMATICS_INFO
            assert parse_kinematics_info(state[1]) == factory_calibration(6)

        # garbage on every other port: the mock answers what it can, closes what it cannot, and serves on
        noise = random.Random(6)
        for port in (DASHBOARD_PORT, PRIMARY_PORT, SECONDARY_PORT, REALTIME_PORT):
            with socket.create_connection((host, port), timeout=5) as s:
                s.sendall(bytes(noise.randrange(256) for _ in range(5000)) + b"\nrobotmode\n")
        d = dashboard_client.DashboardClient(host)
        d.connect()
        assert d.robotmode() == "Robotmode: RUNNING"
        d.disconnect()
        assert ur.state()["runtime_state"] != PLAYING  # no program came of it

        # the command line: a mistake is one line and exit 2, also an address in use
        for args in (["--q0-deg", "1,2"], ["--host", host]):
            done = subprocess.run(
                [sys.executable, "-m", "trackcal.mocks.servers.ur", *args], capture_output=True, text=True, timeout=60
            )
            assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr


def _primary_message(s: socket.socket) -> tuple[int, bytes]:
    """(type, body) of one primary-interface message: int32 length (header included), uint8 type."""

    def exactly(n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = s.recv(n - len(buf))
            assert chunk
            buf += chunk
        return buf

    length, kind = struct.unpack(">iB", exactly(5))
    return kind, exactly(length - 5)


# ----------------------------------------------------------------------------------------------- framing
OUT_NAMES = sorted(rc.OUTPUTS)


@given(st.lists(st.sampled_from(OUT_NAMES), min_size=1, max_size=12, unique=True), st.randoms(use_true_random=False))
def test_data_frames_read_back_by_urs_serializer(names, rnd):
    types = tuple(rc.output_type(n) for n in names)
    recipe = rc.Recipe(1, tuple(names), types, 125.0)
    config = ur_serialize.DataConfig.unpack_recipe(recipe.answer())  # the client parses the setup answer
    assert config.id == 1 and config.types == list(types)
    config.names = names
    values = {}
    for n, t in zip(names, types, strict=True):
        k = len(rc.TYPE_FORMAT[t])
        one = {
            "DOUBLE": lambda: rnd.uniform(-1e3, 1e3),
            "BOOL": lambda: rnd.random() < 0.5,
            "UINT8": lambda: rnd.randrange(256),
            "INT32": lambda: rnd.randrange(-(2**31), 2**31),
            "UINT32": lambda: rnd.randrange(2**32),
            "UINT64": lambda: rnd.randrange(2**64),
        }
        base = t.removeprefix("VECTOR6").removeprefix("VECTOR3")
        kind = {"D": "DOUBLE", "INT32": "INT32", "UINT32": "UINT32"}.get(base, base)
        values[n] = [one[kind]() for _ in range(k)] if k > 1 else one[kind]()
    frame = rc.pack_data(recipe, values)
    header = ur_serialize.ControlHeader.unpack(frame)
    assert (header.size, header.command) == (len(frame), 85)  # 'U'
    got = config.unpack(frame[3:])
    for n in names:
        assert getattr(got, n) == values[n]


@given(
    st.lists(
        st.sampled_from(
            [f"input_int_register_{i}" for i in range(48)] + [f"input_double_register_{i}" for i in range(48)]
        ),
        min_size=1,
        max_size=10,
        unique=True,
    ),
    st.randoms(use_true_random=False),
)
def test_input_frames_of_urs_client_are_read(names, rnd):
    recipe = rc.Recipe(7, tuple(names), tuple(rc.input_type(n) for n in names))
    config = ur_serialize.DataConfig.unpack_recipe(recipe.answer())
    config.names = names
    obj = ur_serialize.DataObject.create_empty(names, 7)
    for n in names:
        setattr(obj, n, rnd.randrange(-(2**31), 2**31) if "int" in n else rnd.uniform(-10, 10))
    payload = config.pack(obj)
    assert rc.unpack_data(recipe, payload) == {n: getattr(obj, n) for n in names}


def test_setup_answers_and_names():
    assert rc.output_type("actual_q") == "VECTOR6D" and rc.output_type("output_int_register_24") == "INT32"
    assert rc.output_type("input_double_register_47") == "DOUBLE"  # inputs can be read back
    assert rc.output_type("output_int_register_48") == rc.NOT_FOUND  # 0..47 (RTDE guide)
    assert rc.output_type("output_int_register_05") == rc.NOT_FOUND
    assert rc.input_type("output_int_register_0") == rc.NOT_FOUND  # outputs cannot be written
    assert rc.input_type("input_bit_register_64") == "BOOL" and rc.input_type("input_bit_register_63") == rc.NOT_FOUND
    freq, names = rc.parse_output_setup(struct.pack(">d", 500.0) + b"timestamp,actual_q,")  # ur_rtde's trailing comma
    assert freq == 500.0 and names == ("timestamp", "actual_q")


class _Sock:
    def __init__(self) -> None:
        self.out = b""

    def sendall(self, data: bytes) -> None:
        self.out += data


class _Server:
    def __init__(self) -> None:
        self.ctl = UrController()
        self.reserve_lock = threading.Lock()
        self.recipes: list = []

    def reserved_inputs(self, asking) -> set:
        return set()


@given(st.binary(max_size=300))
def test_garbage_never_escapes_as_anything_but_a_frame_error(data):
    """Whatever bytes arrive, the RTDE reader either answers or raises FrameError (it then closes the connection)."""
    sess = RtdeSession(_Server(), _Sock())  # type: ignore[arg-type]
    with contextlib.suppress(rc.FrameError):  # the one error allowed: the session then closes the connection
        for command, payload in rc.Deframer().feed(data):
            sess.handle(command, payload)


@given(st.sampled_from(sorted(rc.COMMANDS)), st.binary(max_size=200))
def test_every_package_type_with_any_payload(command, payload):
    sess = RtdeSession(_Server(), _Sock())  # type: ignore[arg-type]
    try:
        sess.handle(command, payload)
    except rc.FrameError:
        return
    for cmd, _ in rc.Deframer().feed(sess.sock.out):  # what it answered is framed RTDE
        assert cmd in rc.COMMANDS


# ----------------------------------------------------------------------------------------------- controller
def _run_ticks(ctl: UrController, n: int) -> None:
    for _ in range(n):
        ctl.step()


def _command(ctl: UrController, cmd: int, floats=(), async_flag: int = 0) -> None:
    values = {f"input_double_register_{i}": v for i, v in enumerate(floats)}
    ctl.write_inputs(values | {"input_int_register_1": async_flag, "input_int_register_0": cmd})


def _started(seed: int = 0) -> UrController:
    ctl = UrController(seed=seed, unlock_delay_s=5.0)
    ctl.load_script("def rtde_control():\n    global reg_offset_float = 0\n    global reg_offset_int = 0\nend\n")
    ctl.step()
    assert ctl.runtime_state == PLAYING and ctl.out_int[0] == 1  # signal_ready
    return ctl


def _ticks_until_done(ctl) -> int:
    """Controller ticks until signal_done_with_cmd (output int 2) after a blocking move."""
    ticks = 0
    while ctl.out_int[0] != 2:
        ctl.step()
        ticks += 1
        assert ticks < 5000
    return ticks


def test_movej_follows_a_trapezoid_and_answers_done():
    ctl = _started()
    target = [HOME[0] + 1.0, *HOME[1:]]  # 1 rad on the base
    _command(ctl, MOVEJ, [*target, 1.0, 1.4])
    ticks = _ticks_until_done(ctl)
    # trapezoid: v/a accelerating + decelerating, D/v in total at cruise: T = v/a + D/v (physics of the profile)
    assert ticks * TICK_S == pytest.approx(1.0 / 1.4 + 1.0 / 1.0, abs=3 * TICK_S)
    assert list(ctl.motion.q) == target
    _command(ctl, 0)
    ctl.step()
    assert ctl.out_int[0] == 1  # ready again after the clear command


def test_movel_takes_its_trapezoid_on_the_controllers_clock_and_refuses_what_it_cannot_reach():
    """movel (ur_rtde's command 3) on the controller alone, tick by tick: 0.1 m along x at 0.05 m/s and 0.1 m/s^2
    takes d/v + v/a = 2.5 s of controller ticks and ends on the target; a target 3 m away, beyond a UR10's 1300 mm
    reach (UR10 datasheet), ends the program with a runtime error before the arm moves."""
    ctl = _started()
    start = tcp_pose(ctl.motion.q, ctl.calibration, ctl.tcp)
    target = [start[0] + 0.1, *start[1:]]
    _command(ctl, MOVEL, [*target, 0.05, 0.1])
    ticks = _ticks_until_done(ctl)
    assert ticks * TICK_S == pytest.approx(0.1 / 0.05 + 0.05 / 0.1, abs=3 * TICK_S)
    assert tcp_pose(ctl.motion.q, ctl.calibration, ctl.tcp)[:3] == pytest.approx(target[:3], abs=1e-9)
    _command(ctl, 0)
    ctl.step()
    q = ctl.motion.q
    _command(ctl, MOVEL, [start[0] + 3.0, *start[1:], 0.05, 0.1])
    ctl.step()
    assert ctl.runtime_state != PLAYING and ctl.motion.q == q
    assert any("inverse kinematics failed" in line for line in ctl.log)


def test_rated_speed_caps_the_leading_joint():
    m = Motion([0.0] * 6)
    m.move([2.0, 0, 0, 0, 0, 0], speed=3.0, acc=40.0)  # asks 3 rad/s of the base, rated 120 deg/s (UR10e datasheet)
    v = UR10_VMAX_RAD_S[0]
    assert v == pytest.approx(math.radians(120))
    assert m.path is not None and m.path.total == pytest.approx(v / 40.0 + 2.0 / v)
    peak = 0.0
    while m.moving:
        m.step()
        peak = max(peak, abs(m.qd[0]))
    assert peak == pytest.approx(v, rel=1e-9)


def test_stopj_brakes_within_the_physical_distance():
    m = Motion([0.0] * 6)
    m.move([3.0, 0, 0, 0, 0, 0], speed=1.0, acc=1.4)
    while m.qd[0] < 1.0 - 1e-12:
        m.step()
    q_at = m.q[0]
    m.stop(2.0)
    while m.moving:
        m.step()
    assert m.q[0] - q_at == pytest.approx(1.0**2 / (2 * 2.0), abs=1.0 * TICK_S)  # v^2 / 2a


@example(decel=1.323, ticks=122)  # one stop that never ended before the fix (found by a search, kept as a witness)
@given(decel=st.floats(0.05, 40.0), ticks=st.integers(1, 1200))
def test_every_stop_ends_once_braked(decel, ticks):
    """A stop ends the move within v / D of controller time (constant deceleration D from speed v, UR Script Manual
    stopj: "a: joint acceleration"), plus the tick it lands in. The brake used to end on the speed reaching exactly
    zero; for about one stop in twenty sd0 - D * (sd0 / D) is a rounding residue above zero, the arm stood but the
    move never ended, and ur_rtde's blocking stopJ / stopL waited for a 'done' that never came (the moveL / stopL
    judge's hang)."""
    m = Motion([0.0] * 6)
    m.move([3.0, 0, 0, 0, 0, 0], speed=1.0, acc=1.4)
    for _ in range(ticks):
        m.step()
    v = m.qd[0]
    m.stop(decel)
    n = 0
    while m.moving and n <= v / decel / TICK_S + 2:
        m.step()
        n += 1
    assert not m.moving and m.qd == (0.0,) * 6


def test_protective_stop_unlock_waits_five_seconds():
    ctl = _started()
    _command(ctl, MOVEJ, [HOME[0] + 0.5, *HOME[1:], 1.0, 1.4])
    _run_ticks(ctl, 100)
    ctl.protective_stop()
    assert ctl.safety_status_bits & 4 and ctl.runtime_state != PLAYING
    _run_ticks(ctl, round(4.9 / TICK_S))
    assert not ctl.unlock_protective_stop()  # Dashboard Server manual: not before 5 s
    _run_ticks(ctl, round(0.2 / TICK_S))
    assert ctl.unlock_protective_stop() and ctl.safety_mode == NORMAL


def test_same_seed_same_joints_and_identity():
    def run(seed):
        ctl = _started(seed)
        _command(ctl, MOVEJ, [0.4, -1.0, 1.2, -1.3, -1.2, 0.3, 0.8, 1.2], async_flag=1)
        rows = []
        for i in range(400):
            ctl.step()
            if i == 150:
                _command(ctl, 0)
            if i == 200:
                ctl.write_inputs({"input_double_register_0": 3.0})
                _command(ctl, STOPJ, [3.0])
            rows.append(ctl.values(["timestamp", "actual_q", "actual_TCP_pose", "output_int_register_2"]))
        return ctl.serial, ctl.calibration, rows

    a, b, c = run(1), run(1), run(2)
    assert a == b
    assert a[0] != c[0] and a[1] != c[1]
    assert [r["actual_q"] for r in a[2]] == [r["actual_q"] for r in c[2]]  # motion does not depend on the seed


def test_kinematics_info_round_trip():
    cal = factory_calibration(9)
    data = kinematics_info(cal)
    assert len(data) == 5 + 6 * 4 + 4 * 6 * 8 + 4  # Client Interface: header, 6 uint32, 4 x 6 double, uint32
    assert parse_kinematics_info(data) == cal


def test_safeguard_stop_pauses_and_reset_resumes_the_move():
    ctl = _started()
    target = [HOME[0] + 0.6, *HOME[1:]]
    _command(ctl, MOVEJ, [*target, 1.0, 1.4])
    _run_ticks(ctl, 150)
    ctl.safeguard_stop()
    assert ctl.safety_mode == SAFEGUARD_STOP and ctl.safety_status_bits & (1 << 4) and ctl.runtime_state == PAUSED
    _run_ticks(ctl, 500)
    held = ctl.motion.q
    assert not ctl.motion.moving and ctl.out_int[0] == 1  # braked on the path, the movej not done
    assert held[0] < target[0]
    ctl.safeguard_reset()
    while ctl.out_int[0] != 2:
        ctl.step()
    assert list(ctl.motion.q) == target and ctl.safety_mode == NORMAL and ctl.runtime_state == PLAYING


def test_faults_scheduled_halfway_through_a_move():
    ctl = _started()
    ctl.fault_on_move[1] = "stale"
    ctl.protective_stop_on_move = 2
    _command(ctl, MOVEJ, [HOME[0] + 0.5, *HOME[1:], 1.0, 1.4])
    ctl.step()  # the script reads the command
    assert ctl.motion.path is not None
    _run_ticks(ctl, round(ctl.motion.path.total / 2 / TICK_S) - 2)
    assert ctl.events == []
    _run_ticks(ctl, 4)
    assert ctl.events == ["stale"]  # for the server: frames stop
    while ctl.out_int[0] != 2:
        ctl.step()
    _command(ctl, 0)
    ctl.step()
    _command(ctl, MOVEJ, [HOME[0], *HOME[1:], 1.0, 1.4])
    _run_ticks(ctl, 2000)
    assert ctl.safety_mode == PROTECTIVE_STOP and ctl.motion.q[0] != HOME[0]


def test_a_protective_stop_armed_on_a_move_to_where_the_arm_stands_comes_with_the_command():
    # a campaign moves to its pose again before every measurement (mocks/servers/ur/controller.py: no path to halve):
    # the stop armed on such a move ends the program with the command, and the arm does not move
    ctl = _started()
    ctl.protective_stop_on_move = 1
    _command(ctl, MOVEJ, [*HOME, 1.0, 1.4])
    ctl.step()
    assert ctl.safety_mode == PROTECTIVE_STOP and ctl.runtime_state != PLAYING and list(ctl.motion.q) == list(HOME)


def test_async_stopj_answers_at_once_and_reports_progress():
    ctl = _started()
    _command(ctl, MOVEJ, [HOME[0] + 1.0, *HOME[1:], 1.0, 1.4], async_flag=1)
    ctl.step()
    assert ctl.out_int[0] == 2 and ctl.out_int[2] & 32768  # done at once; bit 15: an async operation runs
    _command(ctl, 0)
    _run_ticks(ctl, 300)
    _command(ctl, STOPJ, [0.5], async_flag=1)  # exec_stopl_stopj with async = 1: a stop thread
    ctl.step()
    assert ctl.out_int[0] == 2 and ctl.out_int[2] & 32768 and ctl.motion.moving
    _command(ctl, 0)
    while ctl.motion.moving:
        ctl.step()
    ctl.step()
    assert not ctl.out_int[2] & 32768  # finished once the arm stands
    assert ctl.motion.q[0] < HOME[0] + 1.0


def test_tcp_speed_of_a_base_rotation_is_omega_cross_r():
    ctl = UrController()
    ctl.motion.move([HOME[0] + 1.0, *HOME[1:]], 1.0, 1.4)
    _run_ticks(ctl, 800)  # cruising
    qd = ctl.motion.qd[0]
    v = ctl.value("actual_TCP_speed")
    x, y, _ = ctl.value("actual_TCP_pose")[:3]
    # rigid rotation about the base z axis: w = (0, 0, qd), v = w x r
    assert v[3:] == pytest.approx((0.0, 0.0, qd), abs=1e-9)
    assert v[:3] == pytest.approx((-qd * y, qd * x, 0.0), rel=1e-3, abs=1e-6)
