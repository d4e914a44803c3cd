"""`trackcal mock` as a third-party client meets it (issue 42): by default the cell runs in real time, so a move and a
tracker motion take the wall-clock time the device takes. One `trackcal mock --cell ur10` (its UR controller and its
emScon tracker) driven by the unmodified ur_rtde 1.6.5 and by a CESAPI client's bytes (tests/test_emscon_third_party).

Durations that are the very thing checked are wall-clock lower bounds only: a loaded machine can make the mock
slower, never faster, so none of these can fail for load (before this change the mock ran the UR ten times faster
than the wall clock and the tracker flat out: the bounds failed by 10x and more)."""

from __future__ import annotations

import socket
import struct
import time

import pytest

from tests.drivers.emscon.test_emscon_third_party import CommandSync
from tests.helpers import mock_process
from tests.mocks.servers.test_ur_mock import returns_within, wait_until
from trackcal.campaign.cells.hardware import load_hardware
from trackcal.mocks.servers.ur.motion import TICK_S

rtde_receive = pytest.importorskip("rtde_receive")
rtde_control = pytest.importorskip("rtde_control")

# emScon (Leica ES_C_API_Def.h): ES_C_Initialize, ES_C_SetSearchParams, ES_C_FindReflector; ES_RS_AllOK and
# ES_RS_MeasurementStatusNotReady (10004)
INITIALIZE, SET_SEARCH_PARAMS, FIND_REFLECTOR = 7, 43, 63
ALL_OK, NOT_READY = 0, 10004


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """`trackcal mock --cell ur10` with no --sim-speed: its hardware file's robot and tracker sections."""
    hw = tmp_path_factory.mktemp("mock") / "H.yaml"
    with mock_process("ur10", 3, hw, timeout_s=60.0):
        hardware = load_hardware(hw)
        yield hardware.robot, hardware.tracker


def test_ur_rtde_moves_trackcal_mock_at_the_requested_speed_and_stopj_stops_it(cell):
    """moveJ(q, v = 0.1 rad/s, a = 0.1 rad/s^2) over d = 0.1 rad of the base: URScript movej's trapezoid ("v: joint
    speed of leading axis, a: joint acceleration of leading axis", UR Script Manual) reaches v after v/a = 1 s and
    0.05 rad, so d = v^2/a leaves no cruise: 2 s, d/v + v/a (the controller's RTDE timestamp counts them; the wall
    clock at least as many). Then stopJ(D = 0.6 rad/s^2) once the base cruises at 0.3 rad/s: it brakes v/D = 0.5 s
    over v^2/2D = 0.075 rad past where the stop was sent, and stands short of the target."""
    host = cell[0]["host"]
    r = rtde_receive.RTDEReceiveInterface(host)
    c = rtde_control.RTDEControlInterface(host)
    try:
        q0 = r.getActualQ()
        d, v, a = 0.1, 0.1, 0.1
        target = [q0[0] + d, *q0[1:]]
        ts0, t0 = r.getTimestamp(), time.monotonic()
        assert c.moveJ(target, v, a, True)
        assert wait_until(lambda: r.getActualQ() == pytest.approx(target, abs=1e-9), 60.0)
        wall, controller = time.monotonic() - t0, r.getTimestamp() - ts0
        assert controller >= d / v + v / a - 2 * TICK_S
        assert wall >= d / v + v / a - 2 * TICK_S  # was 0.2 s: the mock ran ten times faster than the wall clock

        far = [target[0] + 1.0, *target[1:]]
        v, a, decel = 0.3, 0.6, 0.6
        assert c.moveJ(far, v, a, True)
        assert wait_until(lambda: r.getActualQd()[0] >= v * (1 - 1e-9), 30.0)
        q_sent, t_sent = r.getActualQ()[0], time.monotonic()
        assert returns_within(10.0, lambda: c.stopJ(decel, False))  # blocking stopj: returns when the arm stands
        braking = time.monotonic() - t_sent
        assert wait_until(lambda: r.getActualQd() == [0.0] * 6, 5.0)
        q_stop = r.getActualQ()[0]
        assert q_stop >= q_sent + v * v / (2 * decel) - 1e-6 and q_stop < far[0] - 0.1
        assert braking >= 0.9 * v / decel  # 0.5 s of braking (less the frames the reading trails by)
    finally:
        c.stopScript()
        c.disconnect()
        r.disconnect()


def test_the_trackers_motions_take_their_time(cell):
    """Initialize moves the tracker's head (the mock's motion time: 2 s, MockEmscon's motion_time_s); FindReflector
    with nothing to find searches for the whole time-out the client set (SetSearchParams' lTimeOut, 1500 ms) before
    ES_RS_MeasurementStatusNotReady. Both were answered at once (the twin's tracker ran flat out)."""
    tracker = cell[1]
    with socket.create_connection((tracker["host"], tracker["port"]), timeout=30.0) as sock:
        client = CommandSync(sock)
        t0 = time.monotonic()
        answer, _ = client.execute(INITIALIZE, "", ())
        assert struct.unpack_from("<i", answer, 12)[0] == ALL_OK
        assert time.monotonic() - t0 >= 2.0
        answer, _ = client.execute(SET_SEARCH_PARAMS, "di", (50.0, 1500))
        assert struct.unpack_from("<i", answer, 12)[0] == ALL_OK
        t0 = time.monotonic()
        answer, _ = client.execute(FIND_REFLECTOR, "d", (2000.0,))
        assert struct.unpack_from("<i", answer, 12)[0] == NOT_READY  # the twin's reflector is on no nest yet
        assert time.monotonic() - t0 >= 1.5
