"""The whole plan is checked before the first operator prompt; the planner keeps the same joint margin; a
measurement far from where the nominal model expects the reflector stops the campaign (in-process cell)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import assert_stopped, feasible_plan, inproc_live
from trackcal.calib.doe.design import design_for_cell, optimize_plan
from trackcal.calib.identify.unknowns import PAPER_KNOWN
from trackcal.calib.model.cell import CellError, load_cell, usable_limits_deg
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import param_by_name
from trackcal.campaign.engine.steps import PlanError, campaign_steps
from trackcal.campaign.jobs.campaign import new_session, run_stored


@pytest.fixture(scope="module")
def plan(kr270):
    return feasible_plan(kr270, 4, seed=5, repeat=1)


def test_a_pose_inside_the_joint_margin_is_refused_in_one_line_before_a_session_exists(tmp_path, kr270, plan):
    bad = np.array(plan["poses_deg"])
    lim = usable_limits_deg(kr270)  # the KR 270's limits less the cell's default 1 deg margin
    bad[2, 1] = lim[1, 1] + 0.5  # A2 half a degree inside its limit: inside the limits, not inside the margin
    with pytest.raises(PlanError) as info:
        new_session(tmp_path / "s", "kr270", {"poses_deg": bad.tolist(), "repeat": 1}, "sim", 3)
    message = str(info.value)
    assert "\n" not in message and "pose Q3 outside the joint limits less the 1 deg margin" in message
    assert "A2" in message
    assert not (tmp_path / "s").exists()  # no session, no device contacted, no prompt


def test_the_cell_box_is_checked_after_the_controllers_rounding(kr270, plan):
    q = np.array(plan["poses_deg"][:1])
    q[0, 0] = np.round(q[0, 0], 4) + 4e-5  # A1 between two controller steps: rounding moves it by -4e-5 deg
    kin = Kinematics(kr270.chain, [])
    pid = sorted(kr270.tool_points)[0]
    exact, rounded = (kin.points(np.radians(v), kr270.tool_points[pid])[0] for v in (q, np.round(q, 4)))
    axis = int(np.argmax(np.abs(rounded - exact)))
    shift = rounded[axis] - exact[axis]  # a few micrometres (4e-5 deg at metres of lever arm)
    # a box whose wall lies between the exact and the rounded point: the plan as written is inside, the plan as
    # the controller gets it is not
    box_min, box_max = kr270.box_min.copy(), kr270.box_max.copy()
    if shift > 0:
        box_max[axis] = exact[axis] + shift / 2
    else:
        box_min[axis] = exact[axis] + shift / 2
    tight = dataclasses.replace(kr270, box_min=box_min, box_max=box_max)
    with pytest.raises(PlanError, match="pose Q1 put a reference point outside the cell box"):
        list(campaign_steps(tight, q, 1))


def test_plans_keep_the_joint_margin(kr270):
    # a D-optimal plan of the paper's cell: optimal poses sit on the planner's bounds (section 7.2 parameters)
    params = [param_by_name(kr270.chain, n) for n in kr270.plan_params]
    plan = optimize_plan(
        design_for_cell(kr270, params, known=PAPER_KNOWN), 6, criterion="D", starts=20, refined=2, seed=2
    )
    rounded = np.round(np.degrees(plan.poses), 4)  # as `trackcal plan` writes them
    lim = usable_limits_deg(kr270)
    assert np.all((rounded >= lim[:, 0]) & (rounded <= lim[:, 1]))
    list(campaign_steps(kr270, rounded, 1))  # the whole-plan check accepts it


def test_a_margin_that_leaves_no_range_is_a_cell_error(tmp_path):
    cell = tmp_path / "narrow.yaml"
    cell.write_text("robot: kr270\ntool: kr270-3point\njoint_margin_deg: 80\n")  # A2 spans 145 deg only
    with pytest.raises(CellError, match="joint_margin_deg 80 leaves no range for A2"):
        load_cell(str(cell))


def test_a_measurement_far_from_the_expected_position_stops_the_campaign(tmp_path, kr270, plan):
    # 1 um: less than any real station set-up error, so the very first measurement is implausible
    strict = tmp_path / "strict.yaml"
    strict.write_text(Path(kr270.source).read_text() + "measurement_tolerance_mm: 0.001\n")
    store, _ = new_session(tmp_path / "s", str(strict), plan, "sim", 3)
    assert_stopped(
        run_stored(store, inproc_live(kr270, 3)[1]), "units or coordinate system were changed.*wrong reflector.*moved"
    )
    assert not store.events("measurement")  # nothing wrong is stored
    assert store.events("error")[-1].data["type"] == "ImplausibleMeasurement"


def test_the_tracker_is_configured_at_every_station_and_before_every_point_block(tmp_path, kr270, plan):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    run_stored(store, inproc_live(kr270, 3)[1])
    # the recorded device calls, in order: each prompt for a station or a point is followed by configure()
    calls = [e.data["op"] for e in store.events("call") if e.data["device"] in ("tracker", "operator")]
    blocks = [e.data["args"][0] for e in store.events("call") if e.data["op"] == "ask"]
    for i, op in enumerate(calls):
        if op == "ask" and blocks.pop(0) in ("change_station", "move_reflector"):
            nxt = calls[i + 1 : i + 3]
            assert "configure" in nxt, nxt  # after initialize() for a station, at once for a point
    n_blocks = len([e for e in store.events("prompt") if e.data["kind"] in ("change_station", "move_reflector")])
    assert calls.count("configure") == n_blocks
