"""Issue 27, finding 7: name the cause that is true. An open door, a PLC that does not answer and an RSI stream that
went silent are three different stops of a move or a settle, each with its own code and message; the campaign's
session records the code and the advice printed with the stop fits it. Over real sockets: the KR C2 client against
the mock controller (UDP, passive: the shipped RSI), its motion guard reading the mock cell PLC over Modbus TCP, the
faults injected in the mocks (mocks/servers/plc.py, mocks/servers/kuka/controller.py)."""

from __future__ import annotations

import threading
import time

import pytest

from tests.helpers import assert_stopped, before_call, feasible_plan, inproc_live
from trackcal.campaign.cells.checks import DOOR_OPEN, PLC_SILENT, motion_guard
from trackcal.campaign.cells.sim import SimCell
from trackcal.campaign.cli.campaign import stopped_safely
from trackcal.campaign.errors import CampaignError
from trackcal.campaign.jobs.campaign import new_session, run_stored
from trackcal.campaign.session.session import export_table
from trackcal.drivers.errors import DeviceFault
from trackcal.drivers.interfaces import RealClock
from trackcal.drivers.kuka.client import RSI_STALE, KukaKrc2
from trackcal.drivers.kuka.eki_codec import ERR_STOPPED
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.mocks.clock import VirtualClock
from trackcal.mocks.servers.kuka.controller import MockKrc2
from trackcal.mocks.servers.plc import MockPlc, PlcFault

HOME = (0.0, -90.0, 90.0, 0.0, 90.0, 0.0)  # kuka_experimental KR_C2/ros_rsi.src HOME
TARGET = (10.0, -80.0, 85.0, 5.0, 80.0, -15.0)
STALE_S = 0.5  # rsi_stale_s of these tests: 40 cycles of 12 ms without a frame
PLC_TIMEOUT_S = 0.3


def inject_door(plc, mock):
    plc.open_door()


def inject_silent_plc(plc, mock):
    plc.inject(PlcFault.SILENT)


def inject_lost_rsi(plc, mock):
    mock.lose_rsi()


NAMES = ("door opened", "PLC does not answer", "RSI stream went stale")  # the three causes' words
CAUSES = [  # (injection, the stop's code, its message, the other causes' words, which it must not use)
    (inject_door, DOOR_OPEN, "the cell door opened", NAMES[1:]),
    (inject_silent_plc, PLC_SILENT, "the cell PLC (does not answer|cannot be read)", NAMES[::2]),  # door or status
    (inject_lost_rsi, RSI_STALE, r"the RSI stream went stale: no frame for \d", NAMES[:2]),
]


@pytest.fixture
def rig():
    """The mock PLC (door closed) read by the client's guard, and the mock KR C2 on the real clock (the stream's
    silence is judged in wall time, as on a real cell)."""
    plc = MockPlc(clock=VirtualClock()).start()
    plc.close_door()
    cellio = ModbusCellIO(*plc.address, timeout_s=PLC_TIMEOUT_S)
    cellio.connect()
    client = KukaKrc2(
        "127.0.0.1",
        0,
        "127.0.0.1",
        0,
        rsi_protocol="udp",
        rsi_passive=True,
        controller_host="127.0.0.1",
        motion_guard=motion_guard(cellio),
        connect_timeout_s=5.0,
        move_timeout_s=60.0,
        rsi_stale_s=STALE_S,
    )
    client.listen()
    mock = MockKrc2(
        client.eki.address,
        client.rsi.address,
        RealClock(),
        HOME,
        joint_speed_deg_s=100.0,
        settle_s=0.3,
        rsi_protocol="udp",
        rsi_passive=True,
    ).start()
    client.connect()
    yield plc, mock, client
    client.close()
    mock.stop()
    cellio.close()
    plc.stop()
    assert mock.crashed is None


def after(condition, action) -> threading.Thread:
    def run():
        deadline = time.monotonic() + 10.0
        while not condition() and time.monotonic() < deadline:
            time.sleep(0.002)
        action()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize(("inject", "code", "message", "not_said"), CAUSES, ids=["door", "plc", "rsi"])
def test_each_cause_stops_a_move_with_its_own_code_and_message(rig, inject, code, message, not_said):
    plc, mock, client = rig
    after(lambda: mock.moving, lambda: inject(plc, mock))
    with pytest.raises(DeviceFault, match=f"stopped: {message}") as exc:
        client.move(TARGET, 1)  # 1 % of 100 deg/s: 28 s of motion, stopped long before
    assert exc.value.code == code
    assert not any(words in str(exc.value) for words in not_said)
    assert len(mock.stops) == 1  # the stop request went out and the controller braked


@pytest.mark.parametrize(("inject", "code", "message", "not_said"), CAUSES, ids=["door", "plc", "rsi"])
def test_each_cause_ends_settling_with_its_own_code_and_message(rig, inject, code, message, not_said):
    plc, mock, client = rig
    started = threading.Event()
    after(started.is_set, lambda: inject(plc, mock))
    started.set()
    with pytest.raises(DeviceFault, match=f"settling stopped: {message}") as exc:
        client.wait_settled(0.0005, 30.0, 60.0)  # a window far longer than any of the three needs to be noticed
    assert exc.value.code == code and not any(words in str(exc.value) for words in not_said)


def test_the_three_codes_are_distinct_and_none_is_the_controllers_brake_code():
    codes = [code for _, code, _, _ in CAUSES]
    assert len(set(codes)) == 3 and ERR_STOPPED not in codes


# --- a campaign: the session records the cause, the advice fits it --------------------------------------------


@pytest.fixture(scope="module")
def plan(kr270):
    return feasible_plan(kr270, 4, seed=5, repeat=1)


# slow: the code and message of a silent PLC are checked by default on a move and a settle (above); this is the whole
# campaign with its resume, 12 s
@pytest.mark.slow
def test_a_silent_plc_mid_campaign_is_recorded_as_such_and_resume_completes(tmp_path, kr270, plan):
    """The PLC falls silent as the third move starts: the robot client's guard names it (not "the door opened"),
    the session's error event carries its code, the stop's line says to check the PLC, and once the PLC answers
    again `resume` completes the campaign with the table of an uninterrupted run."""
    reference_store, _ = new_session(tmp_path / "ref", "kr270", plan, "sim", 3)
    run_stored(reference_store, inproc_live(kr270, 3)[1])
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    sim = SimCell(kr270, 3, store)
    before_call(sim.live.robot, "move", 3, lambda: sim.plc.inject(PlcFault.SILENT))
    result = run_stored(store, sim.live)
    assert_stopped(result, "the cell PLC does not answer")
    assert result.code == PLC_SILENT and "door opened" not in result.message
    assert store.events("error")[-1].data["code"] == PLC_SILENT
    with pytest.raises(CampaignError, match=r"Check the cell PLC's power .*: trackcal resume "):
        stopped_safely(store, result)
    run_stored(store, SimCell(kr270, 3, store).live)
    assert store.events("campaign_done")
    a, b = export_table(store), export_table(reference_store)
    assert a.pose == b.pose and (a.q_deg == b.q_deg).all() and (a.xyz == b.xyz).all()
