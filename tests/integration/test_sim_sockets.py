"""Campaigns against the simulated cell over real sockets (emScon, KR C2 EKI + RSI, Modbus PLC, serial meteo on a
pty), with faults injected in the mocks mid-campaign.

The reference is the same campaign run on the in-process doubles of mocks.inproc (test_engine.py): both draw
every measurement from the same twin (noise a pure function of seed and step identity), so the tables must be
identical value for value. The protocols may add nothing and lose nothing: float64 in emScon, joint angles at
the controller's 4 decimals in EKI/RSI, the same as the plan's targets.

Every test also checks the safety invariant from the outside: the robot (the mock controller's joints) never
moves while the mock PLC reports the cell door open.
"""

import contextlib
import itertools
import logging
import re
import socket
import threading
import time

import numpy as np
import pytest

from tests.helpers import assert_stopped, before_call, feasible_plan, inproc_live
from trackcal.campaign.cells.sim import SimCell, TwinMocks
from trackcal.campaign.jobs.campaign import new_session, run_stored
from trackcal.campaign.session.session import export_table
from trackcal.drivers.emscon.enums import LengthUnit
from trackcal.drivers.emscon.framing import PacketReader
from trackcal.drivers.emscon.messages import SetUnits, encode_command
from trackcal.drivers.kuka.rsi_codec import RobFrame, encode_rob
from trackcal.mocks.servers.emscon import EmsconFault

SEED = 3


@pytest.fixture(scope="module")
def plan(kr270):
    return feasible_plan(kr270, 4, seed=5, repeat=1)


@pytest.fixture(scope="module")
def reference(kr270, plan, tmp_path_factory):
    store, _ = new_session(tmp_path_factory.mktemp("ref") / "s", "kr270", plan, "sim", SEED)
    run_stored(store, inproc_live(kr270, SEED)[1])
    return export_table(store)


def watched(sim: SimCell) -> list[tuple[float, ...]]:
    """Joint values the controller reached while the PLC said the door was open (must stay empty)."""
    violations: list[tuple[float, ...]] = []
    report = sim.controller.on_joints

    def on_joints(q):
        if not sim.plc.door_closed:
            violations.append(q)
        report(q)

    sim.controller.on_joints = on_joints
    return violations


def same_table(a, b) -> None:
    assert a.pose == b.pose and a.point == b.point and a.station == b.station
    np.testing.assert_array_equal(a.q_deg, b.q_deg)
    np.testing.assert_array_equal(a.xyz, b.xyz)


def test_campaign_over_sockets_gives_the_in_process_table(tmp_path, kr270, plan, reference):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    moved_with_door_open = watched(sim)
    run_stored(store, sim.live)
    assert store.events("campaign_done") and not moved_with_door_open
    same_table(export_table(store), reference)
    # the operator was asked through the PLC and did each thing once: 2 stations, 3 points per station
    kinds = [k for k, _, _ in sim.human.log]
    assert kinds.count("change_station") == 2 and kinds.count("move_reflector") == 6
    assert sim.controller.crashed is None and not sim.controller.errors


def test_beam_break_mid_campaign_is_looked_at_again_and_nothing_is_lost(tmp_path, kr270, plan, reference):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    # someone walks through the beam during the fifth measurement
    before_call(sim.live.tracker, "measure", 5, lambda: sim.tracker_mock.inject(EmsconFault.BEAM_BREAK))
    run_stored(store, sim.live)
    warnings = [e.data["message"] for e in store.events("warning")]
    assert len([w for w in warnings if w.endswith("looking again")]) == 1
    same_table(export_table(store), reference)


def test_controller_estop_stops_safely_and_resume_completes(tmp_path, kr270, plan, reference):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    # pressed while the fourth command travels: the controller refuses it
    before_call(sim.live.robot, "move", 4, sim.controller.estop)
    assert_stopped(run_stored(store, sim.live), "(?i)emergency stop")
    error = store.events("error")[-1].data
    assert error["type"] == "DeviceFault"
    stored = len(store.events("measurement"))
    assert 0 < stored < len(reference.pose) and not store.events("campaign_done")
    # a new process (new mocks, the fault reset) resumes the session: nothing lost, nothing measured twice
    run_stored(store, SimCell(kr270, SEED, store).live)
    assert store.events("campaign_done")
    same_table(export_table(store), reference)


def test_door_left_open_at_resume_blocks_motion_until_closed(tmp_path, kr270, plan, reference):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    moved_with_door_open = watched(sim)
    close, closes = sim.plc.close_door, []

    def forgetful_close():
        closes.append(1)
        if len(closes) != 2:  # leaving the cell at the first resume (after the station prompt, his 2nd exit) he
            close()  # forgets to close the door, and still acknowledges

    sim.plc.close_door = forgetful_close
    run_stored(store, sim.live)
    assert any("door is open" in e.data["message"] for e in store.events("warning"))
    assert not moved_with_door_open
    same_table(export_table(store), reference)


def another_program_sets_micrometres(sim: SimCell) -> None:
    """A second emScon client on the tracker (another program, its own connection) switches it to micrometres."""
    with socket.create_connection(sim.tracker_mock.address, timeout=5.0) as raw:
        raw.sendall(encode_command(SetUnits(LengthUnit.MICRON)))
        reader, packets = PacketReader(), []
        while not packets:  # the SetUnitsRT comes first, its status change after it
            packets += reader.feed(raw.recv(4096))


def test_units_changed_by_another_client_mid_block_stop_the_campaign_and_nothing_wrong_is_stored(
    tmp_path, kr270, plan, reference
):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    before_call(sim.world, "measure", 6, lambda: another_program_sets_micrometres(sim))
    assert_stopped(run_stored(store, sim.live), "units")
    error = store.events("error")[-1].data
    assert error["type"] == "ImplausibleMeasurement"
    # the sixth measurement came 1000 times too large (1 mm = 1000 um) and was not stored
    assert np.linalg.norm(error["xyz_mm"]) == pytest.approx(1000 * np.linalg.norm(reference.xyz[5]), rel=1e-3)
    stored = np.array([e.data["xyz_mm"] for e in store.events("measurement")])
    assert len(stored) == 5
    np.testing.assert_array_equal(stored, reference.xyz[:5])
    # a new process resumes: the tracker is configured again, the sixth point measured again, nothing lost
    run_stored(store, SimCell(kr270, SEED, store).live)
    same_table(export_table(store), reference)


@pytest.mark.slow  # a whole campaign over sockets; the fast check is test_plan_check's in-process one
def test_units_changed_by_another_client_between_blocks_are_set_again_before_the_next(tmp_path, kr270, plan, reference):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    # after the first point block, while the operator is asked to move the reflector on (his fifth prompt)
    before_call(sim.live.operator, "ask", 5, lambda: another_program_sets_micrometres(sim))
    run_stored(store, sim.live)
    units = [r for r in sim.tracker_mock.received if isinstance(r, SetUnits)]
    assert SetUnits(LengthUnit.MICRON) in units and units[-1] == SetUnits()  # trackcal set mm again after it
    same_table(export_table(store), reference)


def test_a_fake_controller_connecting_first_is_refused_and_the_real_one_runs_the_campaign(
    tmp_path, kr270, plan, reference, monkeypatch
):
    """Someone on the cell network (127.0.0.2: loopback, but not the controller's address 127.0.0.1) connects to
    trackcal's EKI and RSI ports before the controller and feeds joints the robot never had."""
    fakes: list[socket.socket] = []
    serve = TwinMocks.serve_controller

    def fake_first(self, eki_addr, rsi_addr, *args, **kw):
        fakes.append(socket.create_connection(eki_addr, source_address=("127.0.0.2", 0)))
        invented = encode_rob(RobFrame(ipoc=1, aipos=(10.0, -80.0, 80.0, 0.0, 45.0, 0.0)), tcp=False)
        rsi = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the twin's RSI is the shipped UDP
        rsi.bind(("127.0.0.2", 0))
        rsi.sendto(invented, rsi_addr)
        fakes.append(rsi)
        serve(self, eki_addr, rsi_addr, *args, **kw)

    monkeypatch.setattr(TwinMocks, "serve_controller", fake_first)
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    try:
        robot = sim.live.robot
        assert [a for a, _ in robot.refused_peers] == ["127.0.0.2", "127.0.0.2"]
        fakes[0].settimeout(2.0)  # the EKI connection: closed by trackcal, never answered
        with contextlib.suppress(ConnectionResetError):
            assert fakes[0].recv(16) == b""
        run_stored(store, sim.live)
    finally:
        for fake in fakes:
            fake.close()
    same_table(export_table(store), reference)


def test_door_opened_during_a_move_brakes_the_robot_and_resume_completes(tmp_path, kr270, plan, reference):
    """Issue 11: a door opened 20 ms into a move. trackcal's robot client polls the door at 25 Hz, sends the stop
    request, the controller brakes (no motion beyond its braking distance after the stop), the campaign stops
    safely and a resume (door closed + acknowledge) gives the table of an uninterrupted run."""
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    ctl = sim.controller
    after_stop: list[tuple[float, ...]] = []
    report = ctl.on_joints

    def on_joints(q):
        if ctl.stops:  # recorded once the robot came to rest
            after_stop.append(q)
        report(q)

    ctl.on_joints = on_joints

    def open_the_door_20_ms_in():
        wait_until = time.monotonic() + 10.0
        while not ctl.moving and time.monotonic() < wait_until:
            time.sleep(0.001)
        time.sleep(0.020)
        sim.plc.open_door()

    def in_real_time():  # this move runs at the pace of the real clock, as trackcal's 25 Hz poll does
        sim.clock.real_fraction = 1.0
        threading.Thread(target=open_the_door_20_ms_in, daemon=True).start()

    before_call(sim.live.robot, "move", 5, in_real_time)
    assert_stopped(run_stored(store, sim.live), "stopped: the cell door opened")
    [(q_stop, v_stop, q_rest)] = ctl.stops
    t_stop = max(abs(v) for v in v_stop) / ctl.brake_deg_s2 + ctl.cycle_s
    for a, v, b in zip(q_stop, v_stop, q_rest, strict=True):
        # all axes decelerate uniformly to rest together, in the time the fastest needs at the braking deceleration
        # rounded up to whole cycles (< v_max / a + cycle): each travels v t / 2; plus the controller's 0.0001 deg
        assert abs(b - a) <= abs(v) * t_stop / 2 + 1e-4
    # and then it stands: no joint change after rest. The cycle that reaches rest records the stop before it reports
    # its joints, so the rest position itself may be the one report after it (when its last braking step shows in
    # the controller's 0.0001 deg: it did for the fifth move of the plan once each block opened on an extra pose)
    assert after_stop in ([], [q_rest]) and ctl.joints_deg == q_rest
    assert store.events("error")[-1].data["type"] == "DeviceFault"
    assert store.events("error")[-1].data["code"] == "door_open"  # issue 27, finding 7: the session records the cause
    stored = len(store.events("measurement"))
    assert 0 < stored < len(reference.pose) and not store.events("campaign_done")
    run_stored(store, SimCell(kr270, SEED, store).live)
    assert store.events("campaign_done")
    same_table(export_table(store), reference)


def test_a_spoofer_on_the_controllers_address_streaming_first_is_never_read(
    tmp_path, kr270, plan, reference, monkeypatch, caplog
):
    """Issue 27, finding 1: a sender on 127.0.0.1 (the controller's address), another port, streams in-limit joints
    before the controller's first RSI frame and all along. Only the peer the controller's session began with (its
    first frame, empty <IPOC/>) is read: no stored row carries the spoofer's joints, it is counted and logged once,
    and the campaign gives the table of a clean run."""
    fake = (10.0, -60.0, 90.0, 10.0, 60.0, 10.0)  # the joints
    stop, first_sent = threading.Event(), threading.Event()
    spoofer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    spoofer.bind(("127.0.0.1", 0))
    serve = TwinMocks.serve_controller

    def stream(rsi_addr):
        for ipoc in itertools.count(10**9, 12):  # IPOC: ms of controller time, 12 ms a KR C2 cycle
            with contextlib.suppress(OSError):
                spoofer.sendto(encode_rob(RobFrame(ipoc=ipoc, aipos=fake), tcp=False), rsi_addr)
            first_sent.set()
            if stop.wait(0.012):
                return

    def spoofer_first(self, eki_addr, rsi_addr, *args, **kw):
        threading.Thread(target=stream, args=(rsi_addr,), daemon=True).start()
        assert first_sent.wait(10.0)
        serve(self, eki_addr, rsi_addr, *args, **kw)

    monkeypatch.setattr(TwinMocks, "serve_controller", spoofer_first)
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    caplog.set_level(logging.WARNING, logger="trackcal.drivers.kuka.rsi_link")
    try:
        sim = SimCell(kr270, SEED, store)
        run_stored(store, sim.live)
        rsi = sim.live.robot.rsi
    finally:
        stop.set()
        spoofer.close()
    table = export_table(store)
    assert not any(np.allclose(q, fake) for q in table.q_deg)
    same_table(table, reference)
    assert rsi.frames_foreign > 0
    assert len([r for r in caplog.records if "ignored" in r.getMessage()]) == 1


def test_a_spoofer_alone_before_the_controllers_opening_frame_is_caught_before_anything_is_stored(
    tmp_path, kr270, plan, reference, monkeypatch
):
    """Issue 27, finding 1, what the session rule alone cannot catch: a sender on 127.0.0.1 that opens an RSI
    session of its own (an empty <IPOC/> first, as the KR C2 does) before the controller's opening frame is the
    session followed, and it streams in-limit joints. After the first move the two channels disagree (EKI's answer:
    where the arm went; RSI: the spoofer's joints), so the campaign stops safely before any measurement is stored,
    with one line naming the channel, the joint and both values. Without the spoofer, `resume` completes the
    campaign with the table of a clean run."""
    fake = (10.0, -60.0, 90.0, 10.0, 60.0, 10.0)  # the joints
    stop, first_sent = threading.Event(), threading.Event()
    spoofer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    spoofer.bind(("127.0.0.1", 0))
    serve = TwinMocks.serve_controller

    def stream(rsi_addr):
        spoofer.sendto(encode_rob(RobFrame(ipoc=None), tcp=False), rsi_addr)  # the KR C2's opening frame
        for ipoc in itertools.count(10**9, 12):  # IPOC: ms of controller time, 12 ms a KR C2 cycle
            with contextlib.suppress(OSError):
                spoofer.sendto(encode_rob(RobFrame(ipoc=ipoc, aipos=fake), tcp=False), rsi_addr)
            first_sent.set()
            if stop.wait(0.012):
                return

    def spoofer_first(self, eki_addr, rsi_addr, *args, **kw):
        threading.Thread(target=stream, args=(rsi_addr,), daemon=True).start()
        assert first_sent.wait(10.0)
        serve(self, eki_addr, rsi_addr, *args, **kw)

    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    with monkeypatch.context() as patched:
        patched.setattr(TwinMocks, "serve_controller", spoofer_first)
        try:
            sim = SimCell(kr270, SEED, store)
            assert sim.live.robot.rsi.address  # the spoofer's session is the one followed
            result = run_stored(store, sim.live)
        finally:
            stop.set()
            spoofer.close()
    assert_stopped(result, r"the two channels disagree on A\d: RSI -?\d+\.\d{4} deg, EKI -?\d+\.\d{4} deg")
    assert result.code == "channels_disagree" and store.events("error")[-1].data["code"] == "channels_disagree"
    assert store.events("measurement") == []  # nothing stored, so no row with the spoofer's joints
    run_stored(store, SimCell(kr270, SEED, store).live)
    same_table(export_table(store), reference)


def test_channels_that_disagree_by_a_hundredth_of_a_degree_stop_before_the_pose_is_measured(
    tmp_path, kr270, plan, reference
):
    """Issue 27, finding 1: the mock KR C2 answers the third move on EKI with A2 0.01 deg off what its RSI frames
    say (a hundred counts of the controller's 0.0001 deg). The campaign stops safely at that pose's settle, nothing is
    measured at it, and once the controller is sound again `resume` gives the table of an uninterrupted run."""
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", SEED)
    sim = SimCell(kr270, SEED, store)
    moves: list[tuple[float, ...]] = []
    before_call(sim.live.robot, "move", 3, lambda: sim.controller.misreport("eki", 1, 0.01))
    original_move = sim.live.robot.move
    sim.live.robot.move = lambda q, speed: (moves.append(tuple(q)), original_move(q, speed))[1]
    result = run_stored(store, sim.live)
    assert_stopped(result, r"the two channels disagree on A2: RSI (-?\d+\.\d{4}) deg, EKI (-?\d+\.\d{4}) deg")
    rsi, eki = (float(v) for v in re.search(r"RSI (\S+) deg, EKI (\S+) deg", result.message).groups())
    assert round(eki - rsi, 4) == 0.01 and rsi == moves[-1][1]  # RSI shows the target, EKI the lie
    assert result.code == "channels_disagree"
    [stopped_at] = [e.data["step"] for e in store.events("step_started") if e.step == result.step]
    assert stopped_at["kind"] == "settle" and stopped_at["q_deg"] == list(moves[-1])
    assert store.events("measurement") and all(e.step < result.step for e in store.events("measurement"))
    run_stored(store, SimCell(kr270, SEED, store).live)
    same_table(export_table(store), reference)
