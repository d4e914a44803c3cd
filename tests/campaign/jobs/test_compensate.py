"""Compensation (paper section 3, step 5): corrected joint targets, their KRL program and the CLI.

Deviations are the paper's Table 8 (the KR-270's identified values, as the twin uses them); the exact
expectations come from the model's definition: a joint offset dq_j enters as q_j + dq_j, an encoder scale
k_j as q_j (1 + k_j), a compliance c_j as q_j + c_j tau_j(q) (calib/diagnose/extensions.py).
"""

import csv
import json
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from tests.helpers import kr270_campaign
from trackcal.calib.compensate import compensate
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.extension import UNIT_FACTORS
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params, param_by_name
from trackcal.calib.model.pinmodel import gravity_torques
from trackcal.calib.model_file import Model, load_model
from trackcal.calib.model_trust import sealed
from trackcal.campaign.cli import main
from trackcal.campaign.jobs.compensate import write_program
from trackcal.campaign.jobs.identify import choose_params, run_identify
from trackcal.drivers.kuka.program import PROGRAM as KRL
from trackcal.drivers.kuka.program import KrlError, krl_texts, point_names
from trackcal.mocks.twin import PAPER_TABLE8

LEVER = 100.0  # mm, the tool points offset along x and y of the last frame (calib.compensate default)


def make_model(cell, values: dict[str, float], extension: dict | None = None) -> Model:
    """A model of `cell`'s robot with the given deviations (boundary units: mm, deg)."""
    params = [param_by_name(cell.chain, n) for n in values]
    dev = np.array([v if p.is_length else np.radians(v) for p, v in zip(params, values.values(), strict=True)])
    doc = {"extension": extension or {"cause": "none"}}
    return Model(cell.chain, params, dev, {}, dict(cell.tool_points), doc)


def table8_model(cell, extension=None) -> Model:
    return make_model(cell, {p.name: PAPER_TABLE8[p.name] for p in irreducible_params(cell.chain)[0]}, extension)


def tool_points(tcp):
    return tcp + np.array([[0.0, 0.0, 0.0], [LEVER, 0.0, 0.0], [0.0, LEVER, 0.0]])


def pose_points(model: Model, q_true: np.ndarray, tcp, nominal: bool = False) -> np.ndarray:
    """(N, 3, 3): the three tool points, computed here from the kinematics (not through compensate)."""
    kin = Kinematics(model.chain, model.params)
    n = len(q_true)
    p = kin.points(np.repeat(q_true, 3, axis=0), np.tile(tool_points(tcp), (n, 1)), None if nominal else model.dev)
    return p.reshape(n, 3, 3)


def conditioning(cell, q):
    """(N,) smallest / largest singular value of the 9 x n Jacobian of the three tool points."""
    jac = Kinematics(cell.chain, []).jacobian(np.repeat(q, 3, axis=0), np.tile(tool_points(cell.tcp), (len(q), 1)))
    sv = np.linalg.svd(jac.d_q.reshape(len(q), 9, -1), compute_uv=False)
    return sv[:, -1] / sv[:, 0]


def inner_targets(cell, n, seed, margin_deg=5.0, min_conditioning=0.0):
    """Random feasible poses at least `margin_deg` inside every joint limit (and away from singularities)."""
    q = random_poses(cell, 4 * n, np.random.default_rng(seed))
    lim = cell.chain.limits_array()
    m = np.radians(margin_deg)
    ok = np.all((q > lim[:, 0] + m) & (q < lim[:, 1] - m), axis=1) & (conditioning(cell, q) > min_conditioning)
    assert ok.sum() >= n
    return q[ok][:n]


# ---------------------------------------------------------------------------------------------- the math
def test_identified_model_at_compensated_targets_reproduces_the_nominal_pose(kr270):
    model = table8_model(kr270)
    q0 = inner_targets(kr270, 40, seed=3)
    # the mathematics, unbounded: the cell's max_correction refuses a target near the wrist singularity among these
    qc, rep = compensate(model, q0, kr270.tcp, max_correction=(np.inf, np.inf))
    intended = pose_points(model, q0, kr270.tcp, nominal=True)
    reached = pose_points(model, qc, kr270.tcp)
    assert np.abs(reached - intended).max() < 1e-9  # mm: position and (via the 100 mm lever) orientation
    assert rep.position_error_mm.max() < 1e-9 and rep.orientation_error_deg.max() < 1e-9
    # the paper's Table 8 deviations move the TCP by tenths of a mm to ~1.5 mm before compensation
    assert 0.1 < np.median(rep.uncompensated_position_mm) < 2.0
    assert rep.iterations.max() <= 6 and rep.cause == "none" and rep.ignored == []


def test_zero_deviations_leave_the_targets_unchanged(kr270):
    model = make_model(kr270, {p.name: 0.0 for p in irreducible_params(kr270.chain)[0]})
    q0 = inner_targets(kr270, 10, seed=4)
    qc, rep = compensate(model, q0, kr270.tcp)
    assert np.array_equal(qc, q0)
    assert np.all(rep.iterations == 0) and rep.uncompensated_position_mm.max() < 1e-9


@pytest.mark.parametrize("name", ["dq2", "dq3", "dq5"])
def test_a_pure_joint_offset_is_compensated_by_its_opposite(kr270, name):
    # the chain rotates joint j by q_j + dq_j (calib/model/chain.py), so q_c,j = q_j - dq_j and nothing else moves
    dq_deg = PAPER_TABLE8[name] * 10.0
    model = make_model(kr270, {name: dq_deg})
    q0 = inner_targets(kr270, 10, seed=5)
    qc, _ = compensate(model, q0, kr270.tcp)
    expected = q0.copy()
    expected[:, int(name[2]) - 1] -= np.radians(dq_deg)
    # exact up to the convergence tolerance (1e-10 mm at a ~2 m lever: ~1e-13 rad) and rounding
    np.testing.assert_allclose(qc, expected, rtol=0, atol=1e-12)


def test_correction_matches_the_first_order_prediction(kr270):
    # linearisation (paper eq. 1): J_q dq_c = -J_pi dpi on the three points. Away from singularities the
    # corrections are ~1e-3 rad and the second-order remainder a few per cent of them at most
    model = table8_model(kr270)
    q0 = inner_targets(kr270, 10, seed=6, min_conditioning=5e-3)
    qc, _ = compensate(model, q0, kr270.tcp)
    kin = Kinematics(kr270.chain, model.params)
    for i in range(len(q0)):
        jac = kin.jacobian(np.repeat(q0[i : i + 1], 3, axis=0), tool_points(kr270.tcp))
        jq = jac.d_q.reshape(9, -1)
        jp = jac.d_params.reshape(9, -1)
        linear = -np.linalg.lstsq(jq, jp @ model.dev, rcond=None)[0]
        scale = np.abs(linear).max()
        assert np.abs((qc[i] - q0[i]) - linear).max() < 0.02 * scale + 1e-9


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6), st.floats(0.5, 3.0))
def test_converges_for_random_targets(kr270, u, scale):
    lim = kr270.chain.limits_array()
    lo, hi = lim[:, 0] + np.radians(5), lim[:, 1] - np.radians(5)
    q0 = (0.5 * (lo + hi) + 0.5 * (hi - lo) * np.array(u))[None]
    values = {p.name: scale * PAPER_TABLE8[p.name] for p in irreducible_params(kr270.chain)[0]}
    model = make_model(kr270, values)
    assume(conditioning(kr270, q0)[0] > 5e-3)  # away from singularities: a well-posed target
    qc, rep = compensate(model, q0, kr270.tcp)
    if rep.failures[0]:
        assume("joint limits" not in rep.failures[0])  # a target 5 deg inside a limit may be corrected past it
    assert not rep.failures[0]
    assert rep.iterations[0] <= 6
    assert np.abs(pose_points(model, qc, kr270.tcp) - pose_points(model, q0, kr270.tcp, nominal=True)).max() < 1e-9


def test_encoder_scale_extension(kr270):
    # q_true = q_cmd (1 + k): with no geometric deviation q_c = q_nom / (1 + k) on the scaled joints
    k = {"k2": 300.0, "k3": -200.0, "k5": 150.0}  # ppm
    ext = {"cause": "encoder_scale", "parameters": {n: {"value": v, "ci95": 1.0, "unit": "ppm"} for n, v in k.items()}}
    model = make_model(kr270, {p.name: 0.0 for p in irreducible_params(kr270.chain)[0]}, ext)
    q0 = inner_targets(kr270, 10, seed=7)
    qc, rep = compensate(model, q0, kr270.tcp)
    expected = q0.copy()
    for name, v in k.items():
        expected[:, int(name[1]) - 1] /= 1.0 + v / UNIT_FACTORS["ppm"]
    np.testing.assert_allclose(qc, expected, rtol=0, atol=1e-12)
    # and with the Table 8 geometry on top, checked through q_true = q_c (1 + k) computed here
    model = table8_model(kr270, ext)
    qc, rep = compensate(model, q0, kr270.tcp)
    scale = np.ones(6)
    for name, v in k.items():
        scale[int(name[1]) - 1] += v / UNIT_FACTORS["ppm"]
    assert np.abs(pose_points(model, qc * scale, kr270.tcp) - pose_points(model, q0, kr270.tcp, True)).max() < 1e-9
    assert rep.cause == "encoder_scale" and rep.ignored == []


def test_joint_compliance_extension(kr270):
    # q_true = q_cmd + c tau(q_cmd), tau the gravity torque at the commanded pose (pinocchio RNEA)
    c = {"c2": 0.02, "c3": 0.03}  # deg/kNm
    ext = {
        "cause": "joint_compliance",
        "parameters": {n: {"value": v, "ci95": 0.001, "unit": "deg/kNm"} for n, v in c.items()},
    }
    model = table8_model(kr270, ext)
    q0 = inner_targets(kr270, 8, seed=8)
    # the mathematics, unbounded: the cell's max_correction refuses a target near the wrist singularity among these
    qc, rep = compensate(model, q0, kr270.tcp, max_correction=(np.inf, np.inf))
    tau = gravity_torques(kr270.chain, qc)
    qt = qc.copy()
    for name, v in c.items():
        j = int(name[1]) - 1
        qt[:, j] += v / UNIT_FACTORS["deg/kNm"] * tau[:, j]
    assert np.abs(pose_points(model, qt, kr270.tcp) - pose_points(model, q0, kr270.tcp, True)).max() < 1e-9
    assert rep.iterations.max() <= 8


def test_backlash_has_no_static_compensation(kr270):
    ext = {"cause": "backlash", "parameters": {"b2": {"value": 0.01, "ci95": 0.001, "unit": "deg"}}}
    model = make_model(kr270, {"dq2": 0.0}, ext)
    q0 = inner_targets(kr270, 3, seed=9)
    qc, rep = compensate(model, q0, kr270.tcp)
    assert np.array_equal(qc, q0)
    assert len(rep.ignored) == 1 and "backlash" in rep.ignored[0]


def test_targets_outside_the_joint_limits_are_reported_in_their_row(kr270):
    model = make_model(kr270, {"dq4": 0.05})
    # A4 at -179.99 deg: the +0.05 deg offset is compensated to -180.04 deg, past the limit
    q0 = np.radians(
        [
            [10.0, -90.0, 90.0, 0.0, 45.0, 0.0],
            [10.0, -150.0, 90.0, 0.0, 45.0, 0.0],
            [10.0, -90.0, 90.0, -179.99, 45.0, 0.0],
        ]
    )
    qc, rep = compensate(model, q0, kr270.tcp)
    assert rep.failures[0] == "" and np.degrees(qc[0, 3]) == pytest.approx(-0.05, abs=1e-9)  # A4 offset undone
    assert re.fullmatch(
        r"nominal target outside the joint limits: A2 = -150\.0000 deg not in \[-145, 0\]", rep.failures[1]
    )
    assert re.match(r"the compensated target leaves the joint limits: A4 = -180\.0400", rep.failures[2])
    np.testing.assert_array_equal(qc[1:], q0[1:])  # the failed ones keep their nominal angles
    assert rep.ok.tolist() == [True, False, False] and rep.to_doc()["compensated"] == 1


def test_a_pose_the_identified_robot_cannot_reach_is_reported():
    # a planar 2R arm with a longer first link reaches the intended TCP only with another end orientation
    cell = load_cell("planar2r")
    model = make_model(cell, {"px1": 0.5})
    _, rep = compensate(model, np.radians([[-45.0, 20.0]]), cell.tcp)
    assert rep.failures[0].startswith("did not converge")


def test_the_kuka_home_is_reported_and_the_other_targets_are_compensated(kr270):
    # HOME (0, -90, 90, 0, 0, 0): A5 = 0 aligns the A4 and A6 axes, a wrist singularity where no joint
    # correction reaches an arbitrary small orientation error
    model = table8_model(kr270)
    q0 = np.vstack(
        [np.radians([[0.0, -90.0, 90.0, 0.0, 0.0, 0.0]]), inner_targets(kr270, 3, seed=5, min_conditioning=5e-3)]
    )
    qc, rep = compensate(model, q0, kr270.tcp)
    assert rep.failures[0].startswith("did not converge") and not any(rep.failures[1:])
    assert rep.position_error_mm[1:].max() < 1e-9
    np.testing.assert_array_equal(qc[0], q0[0])


def test_compensation_of_an_identified_twin_brings_the_true_robot_to_the_intended_pose(kr270, tmp_path):
    # twin with the paper's Table 8 deviations, a 40-pose campaign, identified: the true robot, commanded
    # to the compensated targets, must land where the nominal model meant, to the identification accuracy
    twin, table = kr270_campaign(kr270, seed=31, n_poses=40)
    outcome = run_identify(kr270, table, choose_params(kr270, None), "tracker")
    path = tmp_path / "model.json"
    path.write_text(json.dumps(outcome.doc))
    model = load_model(path)
    tcp = np.mean(list(model.points.values()), axis=0)
    q0 = np.vstack([kr270.test_pose[None], inner_targets(kr270, 20, seed=11)])
    qc, _ = compensate(model, q0, tcp)
    intended = Kinematics(kr270.chain, model.params).points(q0, tcp)
    true_tcp = np.mean(list(twin.true_points.values()), axis=0)

    def true_robot(q):
        r, o = twin.kin.end_frames(q, twin.true_dev)
        return o + r @ true_tcp

    before = np.linalg.norm(true_robot(q0) - intended, axis=1)
    after = np.linalg.norm(true_robot(qc) - intended, axis=1)
    assert np.median(before) > 0.3  # Table 8 deviations: tenths of a mm to ~1.5 mm
    assert after.max() < 0.1 and np.median(after) < np.median(before) / 10


# ---------------------------------------------------------------------------------------------------- KRL
GOLDEN_SRC = (
    "DEF COMP_TEST()\r\n"
    "; trackcal: 2 compensated joint targets, PTP at 20 % axis speed\r\n"
    "BAS(#INITMOV,0)\r\n"
    "$VEL_AXIS[1]=20\r\n$VEL_AXIS[2]=20\r\n$VEL_AXIS[3]=20\r\n$VEL_AXIS[4]=20\r\n$VEL_AXIS[5]=20\r\n$VEL_AXIS[6]=20\r\n"
    "$ACC_AXIS[1]=20\r\n$ACC_AXIS[2]=20\r\n$ACC_AXIS[3]=20\r\n$ACC_AXIS[4]=20\r\n$ACC_AXIS[5]=20\r\n$ACC_AXIS[6]=20\r\n"
    "PTP XP1\r\n"
    "PTP XP2\r\n"
    "END\r\n"
)
GOLDEN_DAT = (
    "DEFDAT COMP_TEST PUBLIC\r\n"
    "EXT BAS (BAS_COMMAND :IN,REAL :IN )\r\n"
    "DECL E6AXIS XP1={A1 10.0000,A2 -90.0000,A3 90.0000,A4 0.0000,A5 45.5000,A6 0.0000,"
    "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}\r\n"
    "DECL E6AXIS XP2={A1 -12.3457,A2 -100.5000,A3 110.2500,A4 180.0000,A5 -30.0000,A6 360.0000,"
    "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}\r\n"
    "ENDDAT\r\n"
)


def test_krl_program_matches_the_golden_text(tmp_path):
    rows = [[10.0, -90.0, 90.0, 0.0, 45.5, -0.00001], [-12.34567, -100.5, 110.25, 180.0, -30.0, 359.99999]]
    src, dat = write_program(KRL, "COMP_TEST", rows, tmp_path / "krl", speed_pct=20)
    assert src.name == "COMP_TEST.src" and dat.name == "COMP_TEST.dat"
    assert src.read_bytes() == GOLDEN_SRC.encode()
    assert dat.read_bytes() == GOLDEN_DAT.encode()


@pytest.mark.parametrize("name", ["1ABC", "A" * 25, "MY-PROG", "", "Ü1", "PROG 1"])
def test_krl_names_are_checked(name):
    with pytest.raises(KrlError, match="not valid"):
        krl_texts(name, [[0.0] * 6])


def test_krl_rows_and_speed_are_checked():
    assert krl_texts("A" * 24, [[0.0] * 6])[0].startswith("DEF " + "A" * 24 + "()")
    with pytest.raises(KrlError, match="6 axis angles"):
        krl_texts("P", [[0.0] * 5])
    for bad in (0, 101, 12.5):
        with pytest.raises(KrlError, match="percentage"):
            krl_texts("P", [[0.0] * 6], bad)


# ---------------------------------------------------------------------------------------------------- CLI
@pytest.fixture()
def model_file(kr270, tmp_path):
    model = table8_model(kr270)
    doc = {
        "format": "trackcal-model/1",
        "robot": kr270.robot_doc,
        "extension": {"cause": "none"},
        "parameters": {
            p.name: {
                "value": float(v if p.is_length else np.degrees(v)),
                "ci95": 0.01,
                "unit": "mm" if p.is_length else "deg",
                "nominal": 0.0,
            }
            for p, v in zip(model.params, model.dev, strict=True)
        },
        "stations": {},
        "tool_points": {pid: {"xyz_mm": x.tolist(), "ci95_mm": [0.01] * 3} for pid, x in kr270.tool_points.items()},
    }
    path = tmp_path / "model.json"
    path.write_text(json.dumps(sealed(doc)))  # as trackcal writes it: with its digest
    return path, model


def write_targets(path, rows, names=True):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow((["name"] if names else []) + [f"q{j + 1}_deg" for j in range(6)])
        for i, r in enumerate(rows):
            w.writerow(([f"T{i + 1}"] if names else []) + [f"{v:.4f}" for v in r])


def test_cli_writes_compensated_targets_and_krl(kr270, tmp_path, model_file, capsys):
    path, model = model_file
    targets = tmp_path / "targets.csv"
    q0_deg = np.round(np.degrees(inner_targets(kr270, 5, seed=12)), 4)
    write_targets(targets, q0_deg)
    out = tmp_path / "out.csv"
    argv = ["compensate", "--model", str(path), str(targets), "--out", str(out), "--krl", "CELL1", "--speed", "15"]
    assert main(argv) == 0
    rows = list(csv.DictReader(out.read_text().splitlines()))
    assert [r["name"] for r in rows] == ["T1", "T2", "T3", "T4", "T5"] and {r["status"] for r in rows} == {"ok"}
    qc = np.array([[float(r[f"q{j + 1}_comp_deg"]) for j in range(6)] for r in rows])
    # same as the library (default TCP: the points centroid), to the 1e-6 deg the file carries
    expected, _ = compensate(model, np.radians(q0_deg), np.mean(list(kr270.tool_points.values()), axis=0))
    np.testing.assert_allclose(qc, np.degrees(expected), atol=0.51e-6)
    assert all(float(r["position_error_mm"]) < 1e-9 for r in rows)
    # rounding to 1e-4 deg moves the TCP by at most ~6 x 0.5e-4 deg x ~3 m lever = 0.016 mm
    assert all(float(r["rounded_position_error_mm"]) < 0.016 for r in rows)
    dat = (tmp_path / "CELL1.dat").read_text()
    krl = np.round(np.degrees(expected), 4)
    assert dat.count("DECL E6AXIS") == 5 and f"XT1={{A1 {krl[0, 0]:.4f},A2 {krl[0, 1]:.4f}," in dat  # T1 -> XT1
    assert "$VEL_AXIS[6]=15" in (tmp_path / "CELL1.src").read_text()
    assert "5 of 5 targets compensated" in capsys.readouterr().out


def test_cli_reports_a_singular_target_in_its_row_and_writes_the_others(kr270, tmp_path, model_file, capsys):
    path, _ = model_file
    targets = tmp_path / "targets.csv"
    targets.write_text(
        "name,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\nHOME,0,-90,90,0,0,0\n"
        "weld 1,10,-80,80,10,40,5\nweld-1,20,-80,80,10,40,5\n"
    )
    out = tmp_path / "out.csv"
    assert main(["compensate", "--model", str(path), str(targets), "--out", str(out), "--krl", "P"]) == 0
    rows = list(csv.DictReader(out.read_text().splitlines()))
    assert rows[0]["status"].startswith("did not converge") and rows[0]["q1_comp_deg"] == ""
    assert rows[1]["status"] == rows[2]["status"] == "ok"
    captured = capsys.readouterr()
    assert "row 2 (HOME): not compensated" in captured.err and "2 of 3 targets compensated" in captured.out
    # the CSV names as KRL names: other characters -> _, made unique
    src = (tmp_path / "P.src").read_bytes().decode("ascii")
    assert "PTP Xweld_1\r\nPTP Xweld_1_2\r\n" in src


@pytest.mark.parametrize(
    "names, expected",
    [
        (None, ["XP1", "XP2"]),
        (["HOME", ""], ["XHOME", "XP2"]),
        (["a" * 30, "a" * 30], ["X" + "a" * 23, "X" + "a" * 21 + "_2"]),  # KRL names: at most 24 characters
        (["pt", "PT"], ["Xpt", "XPT_2"]),  # KRL is not case-sensitive
    ],
)
def test_krl_point_names(names, expected):
    assert point_names(names, 2) == expected


def test_cli_user_mistakes_end_in_one_line_and_exit_2(kr270, tmp_path, model_file, capsys):
    path, _ = model_file
    good = tmp_path / "good.csv"
    write_targets(good, [[10.0, -90.0, 90.0, 0.0, 45.0, 0.0]], names=False)
    bad_limits = tmp_path / "limits.csv"
    write_targets(bad_limits, [[10.0, -150.0, 90.0, 0.0, 45.0, 0.0]])
    bad_number = tmp_path / "number.csv"
    bad_number.write_text("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n1,2,x,4,5,6\n")
    short = tmp_path / "short.csv"
    short.write_text("q1_deg,q2_deg\n1,2\n")
    out = str(tmp_path / "o.csv")
    cases = [
        (["--model", str(path), str(bad_limits)], r"no target could be compensated"),
        (["--model", str(path), str(bad_number)], "row 2: column q3_deg: not a number"),
        (["--model", str(path), str(short)], "missing column"),
        (["--model", str(tmp_path / "none.json"), str(good)], "no such file"),
        (["--model", str(path), str(good), "--tcp", "1,2"], "--tcp"),
        (["--model", str(path), str(good), "--krl", "9LIVES"], "--krl"),
        (["--model", str(path), str(good), "--krl", "P", "--speed", "0"], "--speed"),
        (["--model", str(path), str(tmp_path / "missing.csv")], "cannot read"),
    ]
    for argv, message in cases:
        assert main(["compensate", *argv, "--out", out]) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("error: "), err
        assert re.search(message, err), (message, err)
