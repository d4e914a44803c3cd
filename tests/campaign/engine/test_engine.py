"""The campaign engine on the simulated world (in-process devices): order, safety, crash, resume, replay."""

import dataclasses

import numpy as np
import pytest

from tests.helpers import assert_stopped, before_call, feasible_plan, inproc_live
from trackcal.calib.identify.solver import identify
from trackcal.calib.model.params import irreducible_params
from trackcal.campaign.engine import steps as steps_module
from trackcal.campaign.engine.engine import Live, Progress
from trackcal.campaign.engine.recording import ReplayDivergence
from trackcal.campaign.engine.steps import PROMPTS, PlanError, StepKind, campaign_steps, next_prompts, plan_steps
from trackcal.campaign.jobs.campaign import new_session, replay, run_stored, stored_campaign
from trackcal.campaign.jobs.completeness import completeness
from trackcal.campaign.session.session import APPROACHED, export_table, write_export
from trackcal.campaign.session.store import SessionStore
from trackcal.mocks.cell import World
from trackcal.mocks.inproc import InprocCellIO, InprocRobot, InprocTracker, SimOperator
from trackcal.mocks.twin import Twin


@pytest.fixture(scope="module")
def cell(kr270):
    return kr270


@pytest.fixture(scope="module")
def plan(cell):
    return feasible_plan(cell, 10, seed=11, repeat=2)


live = inproc_live


def test_step_order_groups_operator_actions(cell, plan):
    steps = list(campaign_steps(cell, np.array(plan["poses_deg"]), plan["repeat"]))
    prompts = [s for s in steps if s.kind in ("change_station", "move_reflector")]
    # one tracker move per station, one reflector move per (station, point) that has visible poses
    assert [s.kind for s in prompts].count("change_station") == 2
    assert len(prompts) <= 2 + 2 * 3
    # every prompt is followed by an explicit resume before any motion
    for i, s in enumerate(steps):
        if s.kind in ("change_station", "move_reflector"):
            assert steps[i + 1].kind == "resume"
    # passes alternate: the second pass visits the poses in reverse order (between the block's drift revisits)
    block = [s for s in steps if s.kind == "measure" and s.station == "S1" and s.point == "P1"]
    revisits = [i for i, s in enumerate(block) if s.drift]
    block = [s.pose for s in block[revisits[0] + 1 : revisits[-1]]]
    half = len(block) // 2
    assert block[:half] == block[half:][::-1]
    # drift checks at the start and end of each point block
    drift = [s for s in steps if s.kind == "measure" and s.drift]
    assert len(drift) >= 2 and len(drift) % 2 == 0


def test_a_point_no_station_sees_is_refused_before_the_start(cell, plan):
    blind = dataclasses.replace(
        cell,
        tool_normals={k: -np.array([0.0, 0.0, 1.0]) * 0 + np.array([-1.0, 0, 0]) for k in cell.tool_normals},
        acceptance_deg=1.0,
    )
    with pytest.raises(PlanError, match="not visible from any station"):
        list(campaign_steps(blind, np.array(plan["poses_deg"]), 1))


def test_the_progress_names_the_next_prompt_of_every_step(cell, plan):
    # one pass from the end gives what a scan of the steps after each step gave (issue 41: the scan was quadratic)
    steps = plan_steps(cell, plan)
    brute = [next((s.label for s in steps[i + 1 :] if s.kind in PROMPTS), "") for i in range(len(steps))]
    assert next_prompts(steps) == brute
    assert sum(1 for label in brute if label) > len(steps) // 2  # prompts follow most steps: the labels were read
    assert next_prompts([]) == []


def test_a_plan_whose_table_could_not_be_read_back_is_refused_before_its_steps(cell, plan, monkeypatch):
    # 10 poses from 2 stations at 3 points over 10^5 passes: 6,000,000 rows, where a table of the kr270's 6 joints
    # holds at most 30,000,000 / 14 = 2,142,857 (calib.io.table.MAX_CELLS); found by test_cli_fuzz: a `repeat` of
    # 10^6 built 5.5 GB of steps for minutes
    monkeypatch.setattr(steps_module, "campaign_order", lambda *a, **k: pytest.fail("the steps were built"))
    with pytest.raises(PlanError, match=r"would measure up to 6000000 rows, more than a measurement table holds "):
        plan_steps(cell, {**plan, "repeat": 10**5})
    # the largest number of passes that fits is not refused by the bound (its steps are what is refused here)
    with pytest.raises(pytest.fail.Exception, match="the steps were built"):
        plan_steps(cell, {**plan, "repeat": 2_142_857 // 60})


def test_full_campaign_then_identification(tmp_path, cell, plan):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    world, devices = live(cell)
    run_stored(store, devices)
    table = export_table(store)
    assert set(table.station) == {"S1", "S2"} and set(table.point) == {"P1", "P2", "P3"}
    assert np.all(np.diff(table.t_s) >= 0)
    res = identify(cell.chain, table, cell.tool_points, irreducible_params(cell.chain)[0])
    # the AT901-like noise of the twin: ~15 um per coordinate (calib/identify/noise.py at 2-4 m)
    assert np.sqrt(np.mean(res.residuals**2)) < 0.025
    # the engine never moved while a prompt was outstanding: each move follows a resume since the last prompt
    steps = [e.data["step"]["kind"] for e in store.events("step_started")]
    pending = False
    for k in steps:
        if k in ("change_station", "move_reflector"):
            pending = True
        elif k == "resume":
            pending = False
        elif k == "move":
            assert not pending


class Crash(Exception):
    """Stands for kill -9: the process dies between two calls (the subprocess test does it for real)."""


@pytest.mark.parametrize("when", ["while measuring", "just after the measurement is stored"])
@pytest.mark.parametrize("fraction", [0.02, 0.5, 0.97])
def test_crash_then_resume_gives_the_uninterrupted_table(tmp_path, cell, plan, fraction, when):
    ref, _ = new_session(tmp_path / "ref", "kr270", plan, "sim", 3)
    run_stored(ref, live(cell)[1])
    after_calls = max(1, int(fraction * len(ref.events("measurement"))))
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    _, devices = live(cell)
    append = store.append

    def crash():
        raise Crash()

    def dying_append(kind, *args):  # the measurement is committed, the step's end is not: a kill -9 there
        append(kind, *args)
        if kind == "measurement" and len(store.events("measurement")) == after_calls:
            raise Crash()

    if when == "while measuring":
        before_call(devices.tracker, "measure", after_calls, crash)
    else:
        store.append = dying_append
    with pytest.raises(Crash):
        run_stored(store, devices)
    store.close()
    store = SessionStore.open(tmp_path / "s")
    run_stored(store, live(cell, store=store)[1])
    a, b = export_table(ref), export_table(store)
    assert a.pose == b.pose and a.station == b.station and a.point == b.point
    np.testing.assert_array_equal(a.q_deg, b.q_deg)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    # the replay of the interrupted-and-resumed session gives the same table, byte for byte
    write_export(store, tmp_path / "s.csv")
    write_export(replay(store, tmp_path / "replay"), tmp_path / "r.csv")
    assert (tmp_path / "s.csv").read_bytes() == (tmp_path / "r.csv").read_bytes()


def test_a_session_made_before_the_approached_revisits_walks_its_own_order(tmp_path, cell, plan):
    """A session made before each block opened on the pose its closing drift revisit comes from (calib.doe.order)
    holds no `approached_revisits` meta: run, resume, check and replay walk the order it was made with, so its
    stored step numbers still name the same steps."""
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3, approached=False)
    store.conn.execute("DELETE FROM meta WHERE key = ?", (APPROACHED,))  # what a session made before holds
    legacy = plan_steps(cell, plan, approached=False)
    assert stored_campaign(store).steps == legacy != plan_steps(cell, plan)
    run_stored(store, live(cell)[1])
    done = completeness(store)
    assert done.complete and done.planned == sum(s.kind == StepKind.MEASURE for s in legacy) == done.measured
    write_export(store, tmp_path / "s.csv")
    write_export(replay(store, tmp_path / "replay"), tmp_path / "r.csv")
    assert (tmp_path / "s.csv").read_bytes() == (tmp_path / "r.csv").read_bytes()


def test_device_fault_stops_safely_and_resume_continues(tmp_path, cell, plan):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    world, devices = live(cell)
    devices.robot.faults = []
    before_call(devices.robot, "move", 7, lambda: devices.robot.faults.append("estop"))
    assert_stopped(run_stored(store, devices), "estop")
    assert store.events("error")[-1].data["type"] == "DeviceFault"
    run_stored(store, live(cell, store=store)[1])
    assert store.events("campaign_done")


def test_beam_break_looks_again_then_skips(tmp_path, cell, plan):
    """Three broken beams in a row: the first measurement fails twice (looked at again, then skipped there), the
    second fails once and the second look succeeds. Exactly one measurement is missing from the table."""
    reference, _ = new_session(tmp_path / "ref", "kr270", plan, "sim", 3)
    seen = []
    run_stored(
        reference, live(cell)[1], [lambda doc: seen.append(Progress(**doc.data)) if doc.name == "progress" else None]
    )
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    world, devices = live(cell)
    devices.tracker.faults = ["beam broken"] * 3
    told, progress = [], []

    def console(doc):  # what the console shows: the progress, and each warning
        if doc.name == "progress":
            progress.append(Progress(**doc.data))
        elif doc.name == "warning":
            told.append(doc.data["message"])

    run_stored(store, devices, [console])
    warnings = [e.data["message"] for e in store.events("warning") if "beam broken" in e.data["message"]]
    assert [w.endswith("skipped here") for w in warnings] == [False, True, False]
    assert store.events("campaign_done")
    n = len(reference.events("measurement"))
    assert len(store.events("measurement")) == n - 1
    # the operator is told every warning as it is stored, and the progress counts the skipped one as done
    assert told == [e.data["message"] for e in store.events("warning")]
    last, ref = progress[-1], seen[-1]  # the reference skips too: points a station does not see at a pose
    assert (ref.measured, ref.measured + ref.skipped) == (n, ref.planned)
    assert (last.measured, last.skipped, last.planned) == (n - 1, ref.skipped + 1, ref.planned)
    assert all(p.measured + p.skipped <= p.planned for p in progress)


class DoorLeftOpen(SimOperator):
    """An operator who forgets to close the door the first time he acknowledges a resume."""

    def __init__(self, world):
        super().__init__(world)
        self.forgot = False

    def ask(self, kind, target, text):
        answer = super().ask(kind, target, text)
        if kind == "resume" and not self.forgot:
            self.forgot = True
            self.world.door_closed = False
        return answer


def test_door_left_open_blocks_motion_until_closed(tmp_path, cell, plan):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    world = World(Twin(cell, seed=3))
    operator = DoorLeftOpen(world)
    devices = Live(InprocTracker(world), InprocRobot(world), operator, world.clock, InprocCellIO(world))
    run_stored(store, devices)
    kinds = [(e.kind, e.data.get("op")) for e in store.events() if e.kind in ("warning", "call")]
    first_warning = next(i for i, k in enumerate(kinds) if k[0] == "warning")
    first_move = next(i for i, k in enumerate(kinds) if k == ("call", "move"))
    assert first_warning < first_move  # the open door was noticed before the robot ever moved
    assert "door is open" in store.events("warning")[0].data["message"]


def test_replay_of_a_changed_plan_stops_at_the_first_divergent_step(tmp_path, cell, plan):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    run_stored(store, live(cell)[1])
    changed = {"poses_deg": [list(plan["poses_deg"][1]), *plan["poses_deg"][1:]], "repeat": plan["repeat"]}
    with pytest.raises(ReplayDivergence, match=r"step \d+: this run asks robot.move"):
        replay(store, tmp_path / "r", plan_doc=changed)


@pytest.mark.parametrize(("off_deg", "stops"), [(0.0001, False), (-0.0002, True), (0.5, True)])
def test_a_robot_that_settles_off_its_target_stops_before_the_pose_is_measured(tmp_path, cell, plan, off_deg, stops):
    """Issue 27, finding 1, for any Robot: after every move the settled joints must equal the target within the
    controller's resolution, one count of 0.0001 deg (KRL writes joints with 4 decimals). Two counts off stop the
    campaign safely at the settle, before anything is measured at that pose; `resume` then completes it."""
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    world, devices = live(cell)
    settle, calls = devices.robot.wait_settled, []

    def settled_off(*args):
        q = settle(*args)
        calls.append(q)
        return q[:2] + (q[2] + off_deg,) + q[3:] if len(calls) == 5 else q

    devices.robot.wait_settled = settled_off
    result = run_stored(store, devices)
    if not stops:
        assert result.exit_status == "success"
        return
    assert_stopped(
        result,
        rf"settled with joint 3 at {calls[4][2] + off_deg:.4f} deg, not at the target "
        rf"{calls[4][2]:.4f} deg .*nothing is measured at this pose",
    )
    assert result.code == "target_mismatch" and store.events("error")[-1].data["code"] == "target_mismatch"
    assert all(e.step < result.step for e in store.events("measurement"))
    run_stored(store, live(cell, store=store)[1])
    assert store.events("campaign_done")
