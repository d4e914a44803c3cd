"""The KR C4's motion guard in RSI cycles (issue 40: the door stops the robot within a cycle or two): the guard is
read once per RSI frame by its own thread, and the answer to the next frame carries <Stop>1</Stop>, which the
mock KR C4 brakes on in its next cycle. Counted in the mock's frames, never in wall time: the mock waits for the
answer to each frame, so the frame that carries the stop does not depend on the machine's pace once the guard's
read is in."""

from __future__ import annotations

import threading
import time

import pytest

from tests.helpers import free_udp_port
from trackcal.drivers.errors import DeviceFault, ProtocolError
from trackcal.drivers.interfaces import StopCause
from trackcal.drivers.krc4.client import KukaKrc4
from trackcal.drivers.krc4.configs import RSI
from trackcal.drivers.kuka.rsi_codec import SenFrame, encode_sen, parse_sen
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.krc4.controller import MockKrc4

HOME = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)
TARGET = (10.0, -80.0, 85.0, 5.0, 80.0, -15.0)
KR210_LIMITS = ((-185, 185), (-140, -5), (-120, 168), (-350, 350), (-125, 125), (-350, 350))  # configs/robots/kr210
CYCLE_S = 0.012  # the RSI context's 12 ms cycle (IPO, kuka_rsi_hw_interface KR_C4_RSI_4+ README): the slower one
DOOR_AT_FRAME = 10  # the door opens once the mock has sent this many frames of the move


def _cell(guard):
    port = free_udp_port()
    # braking from 5 deg/s at 50 deg/s^2 takes 0.1 s, 8 cycles: the move cannot end (and the stop flag fall) before
    # the answer that carries it, whichever of the RSI stop and the EKI stop request the mock served first
    mock = MockKrc4(
        ("127.0.0.1", 0),
        ("127.0.0.1", port),
        VirtualClock(real_fraction=1.0),
        HOME,
        cycle_s=CYCLE_S,
        joint_speed_deg_s=100.0,
        settle_s=0.1,
        seed=3,
        answer_budget_s=5.0,
        brake_deg_s2=50.0,
    ).start()
    client = KukaKrc4(
        mock.eki_addr[1],
        "127.0.0.1",
        port,
        controller_host="127.0.0.1",
        motion_guard=guard,
        rsi_cycle_s=CYCLE_S,
        joint_limits_deg=KR210_LIMITS,
        connect_timeout_s=5.0,
        move_timeout_s=20.0,
        io_timeout_s=2.0,
    )
    client.connect()
    return client, mock


def test_the_door_rides_on_the_next_rsi_answer_and_the_arm_stops_short_of_the_target():
    door = threading.Event()
    opened: list[int] = []  # the mock's frame count when the door opened
    seen: list[int] = []  # ... when the guard read it open
    mock = None

    def guard():
        if not door.is_set():
            return None
        seen.append(mock.frames_sent)
        return StopCause("the cell door opened", "door_open")

    client, mock = _cell(guard)
    try:

        def open_door():
            deadline = time.monotonic() + 10.0
            while not mock.moving and time.monotonic() < deadline:
                time.sleep(0.001)
            start = mock.frames_sent
            while mock.frames_sent < start + DOOR_AT_FRAME and time.monotonic() < deadline:
                time.sleep(0.001)
            opened.append(mock.frames_sent)
            door.set()

        threading.Thread(target=open_door, daemon=True).start()
        with pytest.raises(DeviceFault, match="the cell door opened") as exc:
            client.move(TARGET, 5)  # 5 % of 100 deg/s: seconds of motion, stopped on the way
        assert exc.value.code == "door_open"
        # the guard's read after the frame the door opened on (one read per frame), the answer to the next frame
        # after that read carries Stop; the frame count may step once between the read and the flag
        assert seen[0] - opened[0] <= 2
        # The EKI stop request is still sent as a fallback: on a loaded machine (the full suite on 2 cores) it can end
        # the move before the mock's thread runs its next RSI cycle, and the flag falls with the move, unanswered.
        # When the answer carried it, it was the next one.
        assert len(mock.rsi_stops) <= 1
        for raised in mock.rsi_stops:
            assert 0 <= raised - seen[0] <= 2
        [(_, _, q_rest)] = mock.stops  # braked once, before the target
        assert q_rest != pytest.approx(TARGET, abs=0.01)
    finally:
        client.close()
        mock.stop()
    assert mock.crashed is None, mock.errors


def test_the_plc_is_read_by_the_guard_thread_not_by_the_moving_thread():
    readers: list[str] = []

    def guard():
        readers.append(threading.current_thread().name)
        return None

    client, mock = _cell(guard)
    try:
        client.move(TARGET, 20)  # ~0.4 s of motion and the dwell: many cycles, many 40 ms slices of the KR C2's
        client.wait_settled(0.0005, 0.1, 5.0)
    finally:
        client.close()
        mock.stop()
    mine = threading.current_thread().name
    assert readers.count(mine) == 2  # one read when the move was armed, one when the settle was
    assert readers.count("krc4-guard") >= 10  # the rest: the guard thread, per RSI frame


def test_a_passive_kr_c4_keeps_the_moving_thread_s_guard():
    client = KukaKrc4(1, "127.0.0.1", 0, controller_host="127.0.0.1", rsi_passive=True, motion_guard=lambda: None)
    assert client.cycle_guard is None  # ONLYSEND TRUE: no answer to carry the stop


def test_the_stop_element_is_declared_and_written_only_when_set():
    assert RSI.flags == ("Stop",)  # configs/krc4/trackcal_rsi_ethernet.xml RECEIVE: TAG="Stop" TYPE="BOOL"
    plain = encode_sen(SenFrame(4208163))
    assert b"Stop" not in plain  # the KR C2's answer (and the KR C4's without a stop) is unchanged
    raised = encode_sen(SenFrame(4208163, stop=True))
    assert b"<Stop>1</Stop><IPOC>4208163</IPOC>" in raised
    assert parse_sen(raised).stop is True and parse_sen(plain).stop is False
    with pytest.raises(ProtocolError, match="Stop"):
        parse_sen(raised.replace(b"<Stop>1</Stop>", b"<Stop>yes</Stop>"))
