"""The test conditions ISO 9283:1998 asks for (clause 6, numbers as calib/iso9283_clauses.py checked them): the load
of every test stated (6.6), the test velocities (6.7), the warm-up (6.2), and the report's box of departures."""

import json
import re
import subprocess

import numpy as np
import pytest

from tests.helpers import TRACKCAL, inproc_live
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.campaign.cli import main
from trackcal.campaign.engine.steps import StepKind, plan_steps
from trackcal.campaign.jobs.campaign import new_session, run_session
from trackcal.campaign.jobs.iso9283 import NO_LOAD, UNLOADED, CompareOptions, PlanOptions, compare, make_plan
from trackcal.campaign.jobs.iso9283_departures import departures
from trackcal.campaign.jobs.iso9283_field import field_check, mpe_mm
from trackcal.campaign.session.session import stored_measurements
from trackcal.campaign.session.store import SessionStore
from trackcal.mocks.twin import Twin

SEED = 4


def cli(*argv, cwd):
    return subprocess.run([*TRACKCAL, *argv], cwd=cwd, capture_output=True, text=True)


def test_a_plan_without_its_load_is_refused_in_one_line(tmp_path):
    """6.6 asks the test to run at the rated load: a plan that does not say what the robot carries is refused, in one
    line naming --load, and writes nothing."""
    done = cli(
        "iso9283", "plan", "--cell", "kr270", "--cycles", "2", "--vap-cycles", "0", "--json", "iso.json", cwd=tmp_path
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "--load" in done.stderr and "unloaded" in done.stderr
    assert not (tmp_path / "iso.json").exists()
    blank = cli("iso9283", "plan", "--cell", "kr270", "--load", " ", "--json", "iso.json", cwd=tmp_path)
    assert blank.returncode == 2 and blank.stderr.count("\n") == 1, blank.stderr


def test_unloaded_said_explicitly_is_recorded_and_a_smaller_cube_beside_the_largest(tmp_path):
    """`--load unloaded` is the plan's load; a cube given smaller (--side) keeps the largest the robot reaches about
    the same centre beside it, for the departures box (6.8)."""
    done = cli(
        "iso9283",
        "plan",
        "--cell",
        "kr270",
        "--cycles",
        "2",
        "--vap-cycles",
        "0",
        "--load",
        "unloaded",
        "--side",
        "300",
        "--json",
        "iso.json",
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    iso = json.loads((tmp_path / "iso.json").read_text())["iso9283"]
    assert iso["load"] == "unloaded" and iso["cube_side_mm"] == 300.0 and iso["largest_side_mm"] > 301.0


@pytest.fixture(scope="module")
def two_velocities(tmp_path_factory, kr270):
    """A calibration and one ISO session planned at 100 % and 10 % of the rated velocity, 2 cycles each after one
    warm-up cycle, run on the twin in process."""
    d = tmp_path_factory.mktemp("velocities")
    assert main(["simulate", "--cell", "kr270", "--poses", "40", "--seed", str(SEED), "--out", str(d / "t.csv")]) == 0
    assert main(["identify", str(d / "t.csv"), "--cell", "kr270", "--out", str(d / "model.json")]) == 0
    plan = make_plan(
        PlanOptions(
            cell="kr270",
            json=str(d / "iso.json"),
            cycles=2,
            vap_cycles=0,
            load="unloaded",
            velocities=(100.0, 10.0),
            warm_up_cycles=1,
        )
    )
    store, campaign = new_session(d / "s", "kr270", plan, "sim", SEED)
    assert run_session(store, campaign, inproc_live(kr270, SEED)[1]).exit_status == "success"
    store.close()
    return d, plan


def test_each_velocity_is_a_test_its_moves_at_that_speed(two_velocities, kr270):
    """6.7: every cycle of the 100 % test moves at a 100 % override, then every one of the 10 % test at 10 % (the
    session's own setting, 30 %, is no test velocity); each measurement records its test velocity."""
    d, plan = two_velocities
    steps = plan_steps(kr270, plan)
    measured = [s.speed_pct for s in steps if s.kind == StepKind.MEASURE]
    assert measured == [100.0] * 10 + [10.0] * 10  # 2 cycles of the 5 poses at each
    store = SessionStore.open(d / "s", readonly=True)
    try:
        moves = [
            float(e.data["args"][1])
            for e in store.events("call")
            if e.data.get("device") == "robot" and e.data.get("op") == "move"
        ]
        docs = stored_measurements(store)
    finally:
        store.close()
    assert set(moves) == {100.0, 10.0} and moves == sorted(moves, reverse=True)
    assert [m["velocity_pct"] for m in docs] == measured


def test_the_warm_up_runs_before_the_test_and_is_recorded(two_velocities, kr270):
    """6.2: the warm-up cycle moves through the test's poses in the test's order at the first velocity before the
    first measurement, measures nothing, and the comparison states it: its cycles, velocity, start and end."""
    d, plan = two_velocities
    steps = plan_steps(kr270, plan)
    first = next(i for i, s in enumerate(steps) if s.kind == StepKind.MEASURE)
    warm = [s for s in steps if s.warm_up]
    assert [s.pose for s in warm if s.kind == StepKind.MOVE] == ["Q1", "Q5", "Q4", "Q3", "Q2"]  # 7.2's order
    assert all(steps.index(s) < first and s.speed_pct == 100.0 and s.kind != StepKind.MEASURE for s in warm)
    tests, _ = compare(CompareOptions(sessions=[str(d / "s")], model=str(d / "model.json")))
    record = tests[0].conditions["warm-up"]
    assert re.fullmatch(
        r"1 cycle of P1 P5 P4 P3 P2 at 100 %, nothing measured, \S+ \S+ UTC to \S+ \S+ UTC "
        r"\(ISO 9283:1998, 6\.2\)",
        record,
    ), record
    assert all(t.conditions["warm-up"] == record for t in tests)


@pytest.fixture(scope="module")
def compared(two_velocities):
    """The session compared once (its JSON and its report): the tests below read one output each."""
    d, _ = two_velocities
    args = ["--json", str(d / "cmp.json"), "--report", str(d / "r.html")]
    assert main(["iso9283", "compare", str(d / "s"), "--model", str(d / "model.json"), *args]) == 0
    return d


def test_figures_per_velocity_recomputed_from_the_rows(two_velocities, compared):
    """`compare` states one test per velocity; AP_P and RP_l of each recomputed here from that velocity's stored rows
    alone (plain numpy, the station from model.json, the standard's formulas of 7.2 written out again)."""
    d, plan = two_velocities
    cmp = json.loads((d / "cmp.json").read_text())
    assert [t["velocity_pct"] for t in cmp["tests"]] == [100.0, 10.0]
    assert [t["session"] for t in cmp["tests"]] == [f"{d / 's'} at 100 %", f"{d / 's'} at 10 %"]
    assert cmp["tests"][1]["conditions"]["speed"].startswith("10 % of the rated velocity (ISO 9283:1998, 6.7")
    model = json.loads((d / "model.json").read_text())
    iso = plan["iso9283"]
    st = model["stations"][iso["station"]]
    rot, t = np.array(st["rotation"]), np.array(st["translation_mm"])
    tool = np.array(model["tool_points"][iso["point"]]["xyz_mm"])
    commanded = Kinematics(load_cell("kr270").chain, []).points(np.radians(iso["nominal_poses_deg"]), tool)
    store = SessionStore.open(d / "s", readonly=True)
    try:
        docs = stored_measurements(store)
    finally:
        store.close()
    for test in cmp["tests"]:
        for i in range(5):
            xyz = np.array(
                [m["xyz_mm"] for m in docs if m["pose"] == f"Q{i + 1}" and m["velocity_pct"] == test["velocity_pct"]]
            )
            assert len(xyz) == 2
            base = (xyz - t) @ rot
            bar = base.mean(axis=0)
            ell = np.linalg.norm(base - bar, axis=1)
            rp = ell.mean() + 3 * ell.std(ddof=1)
            assert test["poses"][i]["AP_P"]["value_mm"] == pytest.approx(np.linalg.norm(bar - commanded[i]), abs=1e-9)
            assert test["poses"][i]["RP_l"]["value_mm"] == pytest.approx(rp, abs=1e-9)


@pytest.mark.parametrize("given", ["0", "120", "100,100", "fast", "nan"])
def test_a_velocity_outside_the_rated_is_refused_in_one_line(tmp_path, given):
    done = cli(
        "iso9283",
        "plan",
        "--cell",
        "kr270",
        "--load",
        "unloaded",
        "--velocities",
        given,
        "--json",
        "iso.json",
        cwd=tmp_path,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "--velocities" in done.stderr, done.stderr
    assert not (tmp_path / "iso.json").exists()


def test_departures_of_a_test_each_in_one_line():
    """Every condition of clause 6 a test can miss, alone (the clause numbers: calib/iso9283_clauses.py); a test
    under the standard's conditions has none."""
    clean = {"velocities": [100.0, 50.0, 10.0], "warm_up_cycles": 1, "cube_side_mm": 800.0, "largest_side_mm": 800.4}
    loaded = {"load": "270 kg, 100 % rated", "speed": "-"}
    assert departures(clean, 50.0, 30, loaded, NO_LOAD, UNLOADED) == []
    assert departures(
        {**clean, "velocities": None}, 0.0, 30, {**loaded, "speed": "30 % joint speed override"}, NO_LOAD, UNLOADED
    ) == [
        "no test velocity planned: 30 % joint speed override (ISO 9283:1998, "
        "6.7 asks 100 %, 50 % and 10 % of the rated velocity)"
    ]
    assert departures({**clean, "velocities": [100.0]}, 100.0, 30, loaded, NO_LOAD, UNLOADED) == [
        "test velocities 100 % of the rated, not the standard's 100, 50 and 10 % (ISO 9283:1998, 6.7)"
    ]
    assert departures(clean, 50.0, 30, {"load": NO_LOAD}, NO_LOAD, UNLOADED) == [
        "load not stated (ISO 9283:1998, 6.6: the test at 100 % of the rated load)"
    ]
    assert departures(clean, 50.0, 30, {"load": "unloaded"}, NO_LOAD, UNLOADED) == [
        "tested unloaded (ISO 9283:1998, 6.6: the test at 100 % of the rated load)"
    ]
    assert departures({**clean, "warm_up_cycles": 0}, 50.0, 30, loaded, NO_LOAD, UNLOADED) == [
        "no warm-up before the test (ISO 9283:1998, 6.2)"
    ]
    assert departures(clean, 50.0, 29, loaded, NO_LOAD, UNLOADED) == [
        "29 cycles, fewer than the 30 of ISO 9283:1998, 6.9"
    ]
    assert departures({**clean, "cube_side_mm": 500.0}, 50.0, 30, loaded, NO_LOAD, UNLOADED) == [
        "cube side 500.0 mm, smaller than the largest the robot reaches about its centre (800.4 mm; ISO 9283:1998, 6.8)"
    ]


def test_the_report_lists_every_departure_once_in_one_box(compared):
    """The session of 2 cycles, unloaded, at 100 % and 10 %: its two tests share three departures, listed once each
    in the box; the warm-up ran and the cube is the largest, so neither is one."""
    d = compared
    page = (d / "r.html").read_text(encoding="utf-8")
    box = re.search(r"<div class=departures><h2>Departures from ISO 9283:1998</h2><ul>(.*?)</ul></div>", page)
    assert box is not None
    assert re.findall(r"<li>(.*?)</li>", box[1]) == [
        "test velocities 100, 10 % of the rated, not the standard&#x27;s 100, 50 and 10 % (ISO 9283:1998, 6.7)",
        "tested unloaded (ISO 9283:1998, 6.6: the test at 100 % of the rated load)",
        "2 cycles, fewer than the 30 of ISO 9283:1998, 6.9",
    ]
    assert page.count("<div class=departures>") == 1


def test_the_drift_test_and_its_figures_by_a_second_route(two_velocities, kr270, tmp_path):
    """7.6: `--drift 2` with 3 groups of 2 cycles plans P1 measured in each cycle, the groups at 0, 1 and 2 h of
    campaign time (the twin's virtual clock); dAP and dRP recomputed here from the stored rows of the first and the
    last group with 7.2's formulas written out again, and |AP_1 - AP_3| taken here too."""
    d, _ = two_velocities
    plan = make_plan(
        PlanOptions(
            cell="kr270", json=str(tmp_path / "drift.json"), cycles=2, load="unloaded", drift_hours=2.0, drift_groups=3
        )
    )
    assert plan["iso9283"]["drift"] == {"hours": 2.0, "groups": 3, "cycles": 2}
    steps = plan_steps(kr270, plan)
    assert [s.pose for s in steps if s.kind == StepKind.MEASURE] == ["Q1"] * 6
    assert [s.not_before_s for s in steps if s.not_before_s] == [3600.0, 7200.0]
    store, campaign = new_session(tmp_path / "drift", "kr270", plan, "sim", SEED)
    assert run_session(store, campaign, inproc_live(kr270, SEED)[1]).exit_status == "success"
    docs = stored_measurements(store)
    times = [e.t_campaign for e in store.events("measurement")]
    store.close()
    assert [m["drift_group"] for m in docs] == [1, 1, 2, 2, 3, 3]
    assert times[2] >= 3600.0 and times[4] >= 7200.0  # each group at its time
    _, found = compare(CompareOptions(sessions=[str(tmp_path / "drift")], model=str(d / "model.json")))
    (drift,) = found
    model = json.loads((d / "model.json").read_text())
    iso = plan["iso9283"]
    st = model["stations"][iso["station"]]
    rot, t = np.array(st["rotation"]), np.array(st["translation_mm"])
    tool = np.array(model["tool_points"][iso["point"]]["xyz_mm"])
    c = Kinematics(load_cell("kr270").chain, []).points(np.radians(iso["nominal_poses_deg"]), tool)[0]
    by_group = {}
    for g in (1, 2, 3):
        base = (np.array([m["xyz_mm"] for m in docs if m["drift_group"] == g]) - t) @ rot
        bar = base.mean(axis=0)
        ell = np.linalg.norm(base - bar, axis=1)
        by_group[g] = (np.linalg.norm(bar - c), ell.mean() + 3 * ell.std(ddof=1))
    assert [g["AP_P_mm"] for g in drift["groups"]] == pytest.approx([by_group[g][0] for g in (1, 2, 3)], abs=1e-9)
    assert [g["RP_l_mm"] for g in drift["groups"]] == pytest.approx([by_group[g][1] for g in (1, 2, 3)], abs=1e-9)
    (p1,) = drift["poses"]
    assert p1["dAP"].value == pytest.approx(abs(by_group[1][0] - by_group[3][0]), abs=1e-9)
    assert p1["dRP"].value == pytest.approx(abs(by_group[1][1] - by_group[3][1]), abs=1e-9)


def test_the_tracker_mpe_of_the_field_check():
    """The MPE of a point as Leica states it, A um + B um/m of range (ASME B89.4.19): the hardware file's when it
    states one (20 + 5 um/m at 3 m = 35 um), else the AT901 datasheet's 15 um + 6 um/m (at 3 m: 33 um)."""
    at901 = load_cell("kr270").tracker
    assert mpe_mm(3.0, {"mpe_um": 20.0, "mpe_um_per_m": 5.0}, at901) == (
        pytest.approx(0.035),
        "20 µm + 5 µm/m, the hardware file",
    )
    limit, source = mpe_mm(3.0, None, at901)
    assert limit == pytest.approx(0.033) and "datasheet" in source


def test_the_field_check_measures_the_certified_length_before_the_test(two_velocities, kr270, tmp_path):
    """`--field-check A,B,L`: before the test the reflector is put on A, then on B, the robot standing at P1; the
    measured length (recomputed here from the stored rows) against the twin's true distance between the two points
    passes within the AT901's MPE; 1 mm off the same measurement fails; neither row enters the pose test."""
    d, _ = two_velocities
    twin = Twin(load_cell("kr270"), seed=SEED)
    probe = make_plan(
        PlanOptions(
            cell="kr270", json=str(tmp_path / "p.json"), cycles=2, vap_cycles=0, load="unloaded", velocities=(100.0,)
        )
    )
    test_point = probe["iso9283"]["point"]
    other = next(p for p in sorted(kr270.tool_points) if p != test_point)
    true = float(np.linalg.norm(twin.true_points[test_point] - twin.true_points[other]))
    plan = make_plan(
        PlanOptions(
            cell="kr270",
            json=str(tmp_path / "f.json"),
            cycles=2,
            vap_cycles=0,
            load="unloaded",
            velocities=(100.0,),
            field_check=(test_point, other, true),
        )
    )
    steps = plan_steps(kr270, plan)
    first_test = next(i for i, s in enumerate(steps) if s.kind == StepKind.MEASURE and not s.check)
    checks = [(s.point, s.pose) for s in steps[:first_test] if s.kind == StepKind.MEASURE]
    assert checks == [(test_point, "Q1"), (other, "Q1")]
    store, campaign = new_session(tmp_path / "f", "kr270", plan, "sim", SEED)
    assert run_session(store, campaign, inproc_live(kr270, SEED)[1]).exit_status == "success"
    docs = stored_measurements(store)
    store.close()
    ends = [np.array(m["xyz_mm"]) for m in docs if m.get("field_check")]
    measured = float(np.linalg.norm(ends[0] - ends[1]))
    (test,) = compare(CompareOptions(sessions=[str(tmp_path / "f")], model=str(d / "model.json")))[0]
    text = test.conditions["field check"]
    assert text.startswith(f"length {test_point}-{other}: measured {measured:.4f} mm, certified {true:.4f} mm")
    assert text.endswith(": pass (ASME B89.4.19 / ISO 10360-10 length check)")
    assert all(p.n == 2 for p in test.poses)  # the check's two rows are no cycle of P1
    failed = field_check(
        {"points": [test_point, other], "length_mm": true + 1.0},
        {test_point: ends[0][None], other: ends[1][None]},
        None,
        kr270.tracker,
    )
    assert failed.verdict == "fail" and failed.error_mm == pytest.approx(measured - true - 1.0)


def test_a_field_check_of_unknown_points_is_refused_in_one_line(tmp_path):
    done = cli(
        "iso9283",
        "plan",
        "--cell",
        "kr270",
        "--load",
        "unloaded",
        "--field-check",
        "P1,P9,100",
        "--json",
        "iso.json",
        cwd=tmp_path,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "--field-check" in done.stderr, done.stderr
