"""The robot's own calibration as trackcal's nominal: standard DH -> chain (calib/model/dh.py) against the UR10 chain
of configs/robots/ur10.yaml, the deltas of a calibration.conf, and the calibrated table of the mock controller's
primary interface (KINEMATICS_INFO) against the mock's own forward kinematics."""

import json
import math
import subprocess

import numpy as np
import pytest

from tests.helpers import ROOT, TRACKCAL
from trackcal.calib.model.cell import load_robot
from trackcal.calib.model.dh_chain import dh_chain
from trackcal.calib.model.identifiability import identification_jacobian, numerical_rank, random_configuration
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.ur.calibration import DhTable, read_calibration_conf, read_kinematics_info
from trackcal.mocks.servers.ur.kinematics import factory_calibration, flange
from trackcal.mocks.servers.ur.process import MockUrProcess

# Universal Robots' published UR10 (CB3) table (universal-robots.com, "DH Parameters for calculations of kinematics and
# dynamics"): a, d in m there, mm here
UR10 = DhTable(
    (0.0,) * 6,
    (0.0, -612.0, -572.3, 0.0, 0.0, 0.0),
    (127.3, 0.0, 0.0, 163.941, 115.7, 92.2),
    (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0),
    "UR10 CB3 nominal",
)
TOOL = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 120.0], [-50.0, 86.6, 120.0]])


def points(chain, q):
    kin = Kinematics(chain, [])
    return np.stack([kin.points(q, p) for p in TOOL])


def ur10():
    return load_robot("ur10")[0]


def test_the_published_table_is_the_ur10_chain_to_1e9_mm():
    chain = ur10()
    q = random_configuration(chain, 200, np.random.default_rng(3))
    from_dh = dh_chain(UR10.theta, UR10.a_mm, UR10.d_mm, UR10.alpha, "ur10-dh", chain)
    assert np.abs(points(from_dh, q) - points(chain, q)).max() < 1e-9
    assert [j.name for j in from_dh.joints] == [j.name for j in chain.joints]


CONF = """# calibration.conf of a UR controller (/root/.urcontrol), as the factory writes it
[mounting]
delta_theta = [ 1e-05, -2e-05, 3e-05, 0.0, 1e-05, 0.0 ]   # rad
delta_a = [ 0.0, 0.0002, -0.0001, 0.0, 0.0, 0.0 ]
delta_d = [ 0.0001, 0.0, 0.0, -0.0002, 0.0001, 0.0 ]
delta_alpha = [ 0.0, 1e-05, 0.0, 0.0, -1e-05, 0.0 ]
joint_checksum = [ 1, 2, 3, 4, 5, 6 ]
calibration_status = 2
"""


def test_calibration_conf_deltas_move_the_flange_by_their_size(tmp_path):
    path = tmp_path / "calibration.conf"
    path.write_text(CONF)
    delta = read_calibration_conf(path)
    assert delta.a_mm == pytest.approx((0.0, 0.2, -0.1, 0.0, 0.0, 0.0))
    table = UR10.plus(delta, "UR10 + calibration.conf")
    chain = ur10()
    q = random_configuration(chain, 100, np.random.default_rng(4))
    moved = np.linalg.norm(
        points(dh_chain(table.theta, table.a_mm, table.d_mm, table.alpha, "cal", chain), q) - points(chain, q), axis=2
    )
    # 0.1-0.2 mm of length deltas and 1e-5 rad tilts at ~1.5 m (3e-5 rad x 1.5 m = 0.045 mm): a few tenths of a mm
    assert 0.01 < moved.max() < 1.0
    path.write_text(CONF.replace("delta_d = [ 0.0001, 0.0, 0.0, -0.0002, 0.0001, 0.0 ]", "delta_d = [ 1, 2 ]"))
    with pytest.raises(ProtocolError, match="mounting.delta_d: expected 6 numbers"):
        read_calibration_conf(path)
    path.write_text("[other]\nx = 1\n")
    with pytest.raises(ProtocolError, match=r"no \[mounting\] section"):
        read_calibration_conf(path)


def test_kinematics_info_of_the_mock_gives_the_mocks_own_forward_kinematics():
    with MockUrProcess("127.0.0.28", seed=11):
        table = read_kinematics_info("127.0.0.28")
    cal = factory_calibration(11)  # what the mock computes its TCP with (mocks/servers/ur/kinematics.py)
    chain = dh_chain(table.theta, table.a_mm, table.d_mm, table.alpha, "ur10-factory", ur10())
    q = random_configuration(chain, 50, np.random.default_rng(5))
    ours = points(chain, q)[0]  # the flange origin
    theirs = np.array([np.array(flange(row, cal))[:3, 3] * 1000.0 for row in q])
    assert np.abs(ours - theirs).max() < 1e-9
    # the factory table differs from the published one by its calibration (0.2 mm, 1e-4 rad deviations)
    nominal = points(dh_chain(UR10.theta, UR10.a_mm, UR10.d_mm, UR10.alpha, "n", ur10()), q)[0]
    assert 0.01 < np.abs(ours - nominal).max() < 5.0


def factory_robot(tmp_path):
    """`trackcal factory-robot` of CONF for the ur10: (robot file, its output)."""
    conf = tmp_path / "calibration.conf"
    conf.write_text(CONF)
    out = tmp_path / "robot.yaml"
    r = subprocess.run(
        [*TRACKCAL, "factory-robot", "--cell", "ur10", "--conf", str(conf), "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    return out, r.stdout


def test_factory_robot_writes_an_identifiable_robot_with_the_calibrated_lengths(tmp_path):
    out, stdout = factory_robot(tmp_path)
    assert "nominal: the factory calibration of" in stdout and "calibration.conf" in stdout
    chain, doc = load_robot(str(out))
    assert doc["controller"] == "ur" and len(irreducible_params(chain)[0]) == 18  # as the published UR10's
    # the lengths are the calibrated ones: a2 = -612 + 0.2 mm, a3 = -572.3 - 0.1 mm, d1 = 127.3 + 0.1 mm; a theta
    # offset turns a link by it: its x component is a cos(theta), 612 mm x (2e-5)^2 / 2 = 1.2e-7 mm shorter
    assert chain.joints[1].translation[0] == pytest.approx(-611.8, abs=1e-6)
    assert chain.joints[2].translation[0] == pytest.approx(-572.4, abs=1e-6)
    assert chain.joints[0].translation[2] == pytest.approx(127.4, abs=1e-9)
    conf = tmp_path / "calibration.conf"
    bad = subprocess.run(
        [*TRACKCAL, "factory-robot", "--cell", "kr270", "--conf", str(conf), "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1


# CONF's [mounting] deltas, written out again (rad, m -> mm): what the factory table is, independently of the reader
DELTA_THETA = np.array([1e-05, -2e-05, 3e-05, 0.0, 1e-05, 0.0])
DELTA_A_MM = np.array([0.0, 0.2, -0.1, 0.0, 0.0, 0.0])
DELTA_D_MM = np.array([0.1, 0.0, 0.0, -0.2, 0.1, 0.0])
DELTA_ALPHA = np.array([0.0, 1e-05, 0.0, 0.0, -1e-05, 0.0])


def dh_formula(q, theta, a, d, alpha, point):
    """The standard DH product (Denavit & Hartenberg 1955, the convention of the controller's table): link i is
    Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i); the point in the flange frame, in the base frame."""
    t = np.eye(4)
    for qi, th, ai, di, al in zip(q, theta, a, d, alpha, strict=True):
        c, s, ca, sa = math.cos(th + qi), math.sin(th + qi), math.cos(al), math.sin(al)
        t = t @ np.array([[c, -s * ca, s * sa, ai * c], [s, c * ca, -c * sa, ai * s], [0, sa, ca, di], [0, 0, 0, 1]])
    return (t @ np.append(point, 1.0))[:3]


def test_factory_robot_is_the_calibrated_table_exactly_and_identification_stays_well_posed(tmp_path):
    """No rounding of the factory's tilts to quarter turns: the written chain's forward kinematics are the DH formula
    of the calibrated table (published UR10 + the calibration.conf deltas) to 1e-9 mm, and its parameter set (tilted
    axes, calib/model/params.py) is complete and irreducible: 4n - 6 = 18 for 6 revolute joints (Everett, Driels &
    Mooring), full column rank with a free station and free tool points, rank lost by adding back any eliminated one."""
    out, stdout = factory_robot(tmp_path)
    assert "exactly" in stdout
    chain, _ = load_robot(str(out))
    theta = np.array(UR10.theta) + DELTA_THETA
    a, d = np.array(UR10.a_mm) + DELTA_A_MM, np.array(UR10.d_mm) + DELTA_D_MM
    alpha = np.array(UR10.alpha) + DELTA_ALPHA
    q = random_configuration(chain, 200, np.random.default_rng(6))
    ours = points(chain, q)
    for k, point in enumerate(TOOL):
        want = np.array([dh_formula(row, theta, a, d, alpha, point) for row in q])
        assert np.abs(ours[k] - want).max() < 1e-9
    # the tilts are kept: a rounded chain would be off by ~1e-5 rad x 1.5 m = 0.015 mm
    rounded = points(dh_chain(UR10.theta, a, d, UR10.alpha, "r", ur10()), q)
    assert np.abs(rounded - ours).max() > 1e-3
    kept, eliminated = irreducible_params(chain)
    assert len(kept) == 4 * 6 - 6
    qs = random_configuration(chain, 60, np.random.default_rng(7))
    jac = identification_jacobian(chain, kept, qs, TOOL)
    assert numerical_rank(jac) == jac.shape[1] == 18 + 6 + 9
    for e in eliminated:
        more = identification_jacobian(chain, [*kept, e.param], qs, TOOL)
        assert numerical_rank(more) < more.shape[1], e.param.name


def test_the_nominal_used_is_recorded_by_identify_and_printed_in_the_report(tmp_path):
    """Which nominal: the factory calibration (factory-robot's robot config says where it came from) or the shipped
    robot config; model.json and the summary record it, the report's header prints it."""
    robot, _ = factory_robot(tmp_path)
    cell = (ROOT / "configs" / "cells" / "ur10.yaml").read_text()
    assert "\nrobot: ur10\n" in cell and "\ntool: ur10-3point\n" in cell
    tool = ROOT / "configs" / "tools" / "ur10-3point.yaml"
    (tmp_path / "cell.yaml").write_text(
        cell.replace("\nrobot: ur10\n", f"\nrobot: {robot}\n").replace("\ntool: ur10-3point\n", f"\ntool: {tool}\n")
    )

    def cli(*args):
        r = subprocess.run([*TRACKCAL, *args], capture_output=True, text=True, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        return r.stdout

    cli("simulate", "--cell", "cell.yaml", "--poses", "12", "--seed", "1", "--out", "t.csv")
    stdout = cli("identify", "t.csv", "--cell", "cell.yaml", "--out", "m.json", "--json", "s.json")
    factory = f"the factory calibration of {tmp_path / 'calibration.conf'}"
    assert "".join(f"nominal robot: {factory}".split()) in "".join(stdout.split())  # the console folds long lines
    for name in ("m.json", "s.json"):
        assert json.loads((tmp_path / name).read_text())["nominal"].startswith(factory)
    cli("report", "--table", "t.csv", "--model", "m.json", "--out", "rep")
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "nominal robot</td>" in page and factory in page
    cli("identify", "t.csv", "--cell", "ur10", "--out", "p.json")
    assert json.loads((tmp_path / "p.json").read_text())["nominal"] == "the robot config configs/robots/ur10.yaml"
