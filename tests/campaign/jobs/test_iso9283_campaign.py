"""The ISO 9283 acceptance test on the twin, through the command line: calibrate, plan the cube, run it with the
nominal and with the compensated targets, compare; the figures against what the twin knows."""

import csv
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from tests.helpers import TRACKCAL
from trackcal.calib.doe.iso_cube import CYCLE_ORDER, IsoCube
from trackcal.calib.iso9283 import Figure, IsoFigures, PoseFigures
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.campaign.engine.steps import PlanError, StepKind, plan_steps
from trackcal.campaign.jobs.iso9283 import drifts
from trackcal.mocks.twin import Twin

SEED = 1
CYCLES = 3  # the standard asks for 30 (6.9); 3 keep the test short and still give a repeatability


def run(*argv, cwd):
    done = subprocess.run([*TRACKCAL, *argv], cwd=cwd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture(scope="module")
def acceptance(tmp_path_factory):
    d = tmp_path_factory.mktemp("iso")
    run("simulate", "--cell", "kr270", "--poses", "40", "--seed", str(SEED), "--out", "t.csv", cwd=d)
    run("identify", "t.csv", "--cell", "kr270", "--out", "model.json", cwd=d)
    # the unidirectional test only: vAP's approach moves are tests/test_iso9283_vap.py's (they double the run)
    one_way = ("--cycles", str(CYCLES), "--vap-cycles", "0", "--load", "unloaded", "--velocities", "100")
    run("iso9283", "plan", "--cell", "kr270", *one_way, "--json", "iso.json", cwd=d)
    run("iso9283", "plan", "--cell", "kr270", *one_way, "--model", "model.json", "--json", "iso-comp.json", cwd=d)
    for plan, session in (("iso.json", "before"), ("iso-comp.json", "after")):
        run(
            "run",
            "--sim",
            "--cell",
            "kr270",
            "--plan",
            plan,
            "--seed",
            str(SEED),
            "--session",
            session,
            "--no-analysis",
            cwd=d,
        )
    # one compare serves every test of its outputs (each compare draws the same Monte-Carlo budgets again): the
    # tolerances' conformity statement (guarded acceptance, the default rule) and, where chromium is, the PDF
    pdf = ["--pdf", "iso.pdf"] if shutil.which("chromium") else []
    out = run(
        "iso9283",
        "compare",
        "before",
        "after",
        "--model",
        "model.json",
        "--tolerance",
        "AP=0.5,RP=0.1",
        "--json",
        "cmp.json",
        "--report",
        "iso.html",
        *pdf,
        cwd=d,
    )
    return d, json.loads((d / "iso.json").read_text()), json.loads((d / "cmp.json").read_text()), out


def test_plan_is_the_standard_cube(acceptance):
    """The plan's TCP positions are the cube's P1..P5 and the nominal joints reach them (forward kinematics)."""
    _, plan, _, _ = acceptance
    iso = plan["iso9283"]
    cube = IsoCube(tuple(iso["cube_centre_mm"]), iso["cube_side_mm"])
    assert np.array(iso["tcp_mm"]) == pytest.approx(cube.poses(), abs=1e-3)
    cell = load_cell("kr270")
    r, o = Kinematics(cell.chain, []).end_frames(np.radians(plan["poses_deg"]))
    tcp = o + r @ cell.tcp
    assert tcp == pytest.approx(cube.poses(), abs=0.01)  # the joints are written to 1e-4 deg (~0.005 mm at 3 m)
    assert len({tuple(np.round(ri, 9).ravel()) for ri in r}) >= 1
    assert np.abs(r - r[0]).max() < 1e-5  # one tool orientation: the poses differ in position only


def test_figures_against_the_twin(acceptance):
    """Before compensation AP_P is the error the twin knows at each pose: its true point against where the nominal
    robot puts it. The difference is the calibration's own error (the station and the tool point it estimated:
    README, held-out RMS of a 30-pose geometric calibration 20-30 µm) plus the mean of 3 noisy cycles (~10 µm), so
    0.05 mm. After compensation AP_P is of that size too, against 1.3-1.7 mm before. RP measures the robot's
    repeatability, which compensation leaves alone: here the twin's robot returns to the same joints, so the two
    tests' RP differ by tracker noise only, within 1.5 times their combined U (k = 2): 3 standard deviations."""
    _, plan, cmp, _ = acceptance
    before, after = cmp["tests"]
    assert not before["compensated"] and after["compensated"]
    twin = Twin(load_cell("kr270"), seed=SEED)
    point = plan["iso9283"]["point"]
    q_nom = np.array(plan["poses_deg"])
    true_point = twin.true_points[point]
    nominal = Kinematics(twin.cell.chain, []).points(np.radians(q_nom), true_point)
    for i, (b, a) in enumerate(zip(before["poses"], after["poses"], strict=True)):
        known = np.linalg.norm(twin.point_in_base(q_nom[i], point) - nominal[i])
        assert known > 1.0  # the twin's robot is off by more than a millimetre: the test has something to show
        assert b["AP_P"]["value_mm"] == pytest.approx(known, abs=0.05)
        assert a["AP_P"]["value_mm"] < 0.05
        assert b["cycles"] == a["cycles"] == CYCLES
        tol = 1.5 * np.hypot(b["RP_l"]["u95_mm"], a["RP_l"]["u95_mm"])
        assert abs(b["RP_l"]["value_mm"] - a["RP_l"]["value_mm"]) <= tol


def test_console_shows_both_tests(acceptance):
    _, _, _, out = acceptance
    assert "AP_P nominal" in out and "compensated" in out and "P5" in out


def test_compare_states_conformity_and_prints_the_pdf(acceptance):
    """`--tolerance AP=0.5,RP=0.1 --pdf`: the nominal AP_P (above 1 mm on the twin: test_figures_against_the_twin)
    fails a 0.5 mm tolerance under guarded acceptance, the default rule (its U is micrometres); the report and the
    PDF say so."""
    if shutil.which("chromium") is None:
        pytest.skip("chromium is not installed (apt-get install chromium; CI installs it)")
    d, _, _, out = acceptance
    assert "guarded acceptance" in out and "PDF written to iso.pdf" in out
    page = (d / "iso.html").read_text(encoding="utf-8")
    assert "Conformity statement" in page and "guarded acceptance (ISO 14253-1:2017" in page
    assert re.search(
        r"before at 100 % \(nominal\)</td><td class=l>AP_P P1</td><td>[^<]+</td><td>500</td>"
        r"<td class='l fail'>fail</td>",
        page,
    )
    assert (d / "iso.pdf").read_bytes().startswith(b"%PDF-")


def test_compare_json_states_the_verdicts_with_their_guard_bands(acceptance):
    """`compare --json --tolerance AP=0.5,RP=0.1`: the JSON holds the rule and every verdict with its guard band (#39):
    guarded acceptance (ISO 14253-1:2017, the default rule: the fixture's compare) narrows the acceptance zone to
    T - U and widens the rejection zone to T + U; the nominal AP_P (above 1 mm: test_figures_against_the_twin) fails
    0.5 mm, the compensated (below 0.05 mm) passes; under simple acceptance (ILAC-G8, asked by name) the guard band
    is 0."""
    d, _, cmp, _ = acceptance
    args = ("--model", "model.json", "--tolerance", "AP=0.5,RP=0.1", "--decision-rule", "simple")
    run("iso9283", "compare", "before", "after", *args, "--json", "tol-simple.json", cwd=d)
    simple = json.loads((d / "tol-simple.json").read_text())["conformity"]
    for rule, doc in (("guarded", cmp["conformity"]), ("simple", simple)):
        assert doc["decision_rule"] == rule and doc["tolerances_mm"] == {"AP": 0.5, "RP": 0.1}
        found = doc["verdicts"]
        assert len(found) == 2 * 5 * 2 and sum(doc["counts"].values()) == len(found)  # 2 tests, 5 poses, AP and RP
        for v in found:
            w = v["u95_mm"] if rule == "guarded" else 0.0
            assert v["guard_band_mm"] == pytest.approx(w)
            assert v["acceptance_limit_mm"] == pytest.approx(v["tolerance_mm"] - w)
            assert v["rejection_limit_mm"] == pytest.approx(v["tolerance_mm"] + w)
            if v["figure"].startswith("AP_P"):
                assert v["verdict"] == ("pass" if v["compensated"] else "fail"), v


def test_iso_plan_walks_cycles_in_one_direction(acceptance, kr270):
    """A campaign of an ISO plan: one station, one point, then `repeat` cycles of P1, P5, P4, P3, P2 (7.2)."""
    _, plan, _, _ = acceptance
    steps = plan_steps(kr270, plan)
    measured = [s.pose for s in steps if s.kind == StepKind.MEASURE and not s.approach]
    assert measured == [f"Q{i + 1}" for i in CYCLE_ORDER] * CYCLES
    first = next(i for i, s in enumerate(steps) if s.kind == StepKind.MEASURE)
    # before the first cycle the robot goes to P2 unmeasured, so that P1 is approached from P2 in every cycle
    assert [(s.kind, s.pose, s.via) for s in steps[first - 4 : first]] == [
        (StepKind.MOVE, "Q2", True),
        (StepKind.SETTLE, "Q2", True),
        (StepKind.MOVE, "Q1", False),
        (StepKind.SETTLE, "Q1", False),
    ]
    assert {(s.station, s.point) for s in steps if s.kind == StepKind.MEASURE} == {
        (plan["iso9283"]["station"], plan["iso9283"]["point"])
    }
    assert [s.kind for s in steps[:4]] == [
        StepKind.CHANGE_STATION,
        StepKind.RESUME,
        StepKind.MOVE_REFLECTOR,
        StepKind.RESUME,
    ]
    with pytest.raises(PlanError, match="no station"):
        plan_steps(kr270, {**plan, "iso9283": {**plan["iso9283"], "station": "S9"}})
    with pytest.raises(PlanError, match="order"):
        plan_steps(kr270, {**plan, "order": "spiral"})
    with pytest.raises(PlanError, match="5 poses"):
        plan_steps(kr270, {**plan, "poses_deg": plan["poses_deg"][:4]})


def test_report_figures_by_a_second_route(acceptance):
    """Every AP_P and RP_l the report shows, recomputed from the exported table with plain numpy: the rows of each
    pose by their id, the station's rotation and translation read from model.json's JSON, the standard's formulas
    written out again here."""
    d, plan, cmp, _ = acceptance
    page = (d / "iso.html").read_text()
    assert "src='data:image/png;base64," in page and "<img alt='P5'" in page and ".png'" not in page  # one file
    model = json.loads((d / "model.json").read_text())
    iso = plan["iso9283"]
    st = model["stations"][iso["station"]]
    rot, t = np.array(st["rotation"]), np.array(st["translation_mm"])
    cell = load_cell("kr270")
    tool = np.array(model["tool_points"][iso["point"]]["xyz_mm"])
    commanded = Kinematics(cell.chain, []).points(np.radians(iso["nominal_poses_deg"]), tool)
    for session in ("before", "after"):
        run("export", session, "--csv", f"{session}.csv", cwd=d)
        with open(d / f"{session}.csv") as fh:
            rows = list(csv.DictReader(fh))
        for i in range(5):
            xyz = np.array(
                [
                    [float(r["x_mm"]), float(r["y_mm"]), float(r["z_mm"])]
                    for r in rows
                    if r["pose"] == f"Q{i + 1}" and r.get("approach", "none") == "none"
                ]
            )
            base = np.array([rot.T @ (x - t) for x in xyz])
            bar = base.mean(axis=0)
            ap = np.sqrt(((bar - commanded[i]) ** 2).sum())
            ell = np.sqrt(((base - bar) ** 2).sum(axis=1))
            rp = ell.mean() + 3 * np.sqrt(((ell - ell.mean()) ** 2).sum() / (len(ell) - 1))
            fig = cmp["tests"][0 if session == "before" else 1]["poses"][i]
            for key, value in (("AP_P", ap), ("RP_l", rp)):
                # the export writes 4 decimals (0.05 µm rounding per coordinate): the figures agree to 0.1 µm
                assert fig[key]["value_mm"] == pytest.approx(value, abs=1e-4), (session, i, key)
                assert f"{fig[key]['value_mm'] * 1000:.1f} ± {fig[key]['u95_mm'] * 1000:.1f}" in page


def test_every_figure_carries_its_budget_by_a_second_route(acceptance):
    """`compare --json` and the report carry each pose's AP_P and RP_l budget and AD_P's (#39). Recomputed from the
    files alone: the station lines from model.json's 95 % intervals (/ 1.96) and rotation, the sensitivity of AP_P the
    unit vector of its AP_x, AP_y, AP_z (e^T R^T diag(u^2) R e for the translation); u_c the root sum of squares of the
    lines; the U beside AP_P the larger distance from the value to the Monte-Carlo interval's ends, which hold it."""
    d, plan, cmp, _ = acceptance
    model = json.loads((d / "model.json").read_text())
    st = model["stations"][plan["iso9283"]["station"]]
    rot, u_t = np.array(st["rotation"]), np.array(st["ci95_translation_mm"]) / 1.96
    page = (d / "iso.html").read_text(encoding="utf-8")
    assert "<h2>Uncertainty budget</h2>" in page
    for test in cmp["tests"]:
        ad = test["AD_P_budget"]
        assert ad["figure"] == "AD_P" and ad["U_mm"] == pytest.approx(test["AD_P"]["u95_mm"])
        assert test["other_budgets"]["RD"]["U_mm"] == pytest.approx(test["RD"]["u95_mm"])  # the tracker's alone
        for pose in test["poses"]:
            ap, rp = pose["budget"]["AP_P"], pose["budget"]["RP_l"]
            lines = {ln["input"]: ln["contribution_mm"] for ln in ap["lines"]}
            assert {
                "tracker",
                "station estimate, translation",
                "station estimate, rotation",
                "tool point estimate",
                "robot repeatability (as measured)",
            } <= set(lines)
            e = np.array(pose["AP_xyz_mm"]) / pose["AP_P"]["value_mm"]
            g = rot @ e  # the offset moves by -R^T v: e^T R^T v
            assert lines["station estimate, translation"] == pytest.approx(np.sqrt((g**2 * u_t**2).sum()), rel=1e-6)
            assert ap["u_c_mm"] == pytest.approx(np.sqrt(sum(v**2 for v in lines.values())), rel=1e-9)
            lo, hi = ap["interval95_mm"]
            assert lo < pose["AP_P"]["value_mm"] < hi
            assert pose["AP_P"]["u95_mm"] == pytest.approx(
                max(pose["AP_P"]["value_mm"] - lo, hi - pose["AP_P"]["value_mm"])
            )
            assert pose["RP_l"]["u95_mm"] == pytest.approx(rp["U_decision_mm"])
            assert f"<td>{lines['station estimate, translation'] * 1000:.2f}</td>" in page


def test_drift_between_first_and_last_tests_of_the_same_targets():
    """dAP = |AP(first) - AP(last)| per pose over the tests of one kind of targets (7.6); a single test of a kind has
    no drift. By hand: AP 0.30 then 0.25 then 0.22 mm -> dAP 0.08 mm (first and last, not neighbours)."""

    def test(session, targets, ap):
        poses = [
            PoseFigures(n, 3, Figure(ap, 0.01, ""), np.zeros(3), Figure(0.05, 0.02, ""), 0.02, 0.01)
            for n in ("P1", "P2", "P3", "P4", "P5")
        ]
        return IsoFigures(session, targets != "nominal", poses, None, None, [], np.zeros((5, 3)), {"targets": targets})

    tests = [
        test("a", "nominal", 0.30),
        test("b", "nominal", 0.25),
        test("c", "nominal", 0.22),
        test("d", "compensated with m.json", 0.01),
    ]
    (d,) = drifts(tests)
    assert (d["first"], d["last"], d["targets"]) == ("a", "c", "nominal")
    assert d["poses"][0]["dAP"].value == pytest.approx(0.08)
    assert d["poses"][0]["dRP"].value == pytest.approx(0.0)
