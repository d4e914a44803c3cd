"""The robot's own calibration as trackcal's nominal: standard DH -> chain (calib/model/dh.py) against the UR10 chain
of configs/robots/ur10.yaml, the deltas of a calibration.conf, and the calibrated table of the mock controller's
primary interface (KINEMATICS_INFO) against the mock's own forward kinematics."""

import math
import subprocess

import numpy as np
import pytest

from tests.helpers import TRACKCAL
from trackcal.calib.model.cell import load_robot
from trackcal.calib.model.dh_chain import dh_chain
from trackcal.calib.model.identifiability import random_configuration
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.drivers.errors import ProtocolError
from trackcal.drivers.ur.calibration import DhTable, read_calibration_conf, read_kinematics_info
from trackcal.mocks.servers.ur.kinematics import factory_calibration, flange
from trackcal.mocks.servers.ur.process import MockUrProcess

# Universal Robots' published UR10 (CB3) table (universal-robots.com, "DH Parameters for calculations of kinematics and
# dynamics"): a, d in m there, mm here
UR10 = DhTable((0.0,) * 6, (0.0, -612.0, -572.3, 0.0, 0.0, 0.0), (127.3, 0.0, 0.0, 163.941, 115.7, 92.2),
               (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0), "UR10 CB3 nominal")  # fmt: skip
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
    moved = np.linalg.norm(points(dh_chain(table.theta, table.a_mm, table.d_mm, table.alpha, "cal", chain), q)
                           - points(chain, q), axis=2)  # fmt: skip
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


def test_factory_robot_writes_an_identifiable_robot_with_the_calibrated_lengths(tmp_path):
    conf = tmp_path / "calibration.conf"
    conf.write_text(CONF)
    out = tmp_path / "robot.yaml"
    r = subprocess.run([*TRACKCAL, "factory-robot", "--cell", "ur10", "--conf", str(conf), "--out", str(out)],
                       capture_output=True, text=True)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "nominal: the factory calibration of" in r.stdout and "calibration.conf" in r.stdout
    chain, doc = load_robot(str(out))
    assert doc["controller"] == "ur" and len(irreducible_params(chain)[0]) == 18  # as the published UR10's
    # the lengths are the calibrated ones: a2 = -612 + 0.2 mm, a3 = -572.3 - 0.1 mm, d1 = 127.3 + 0.1 mm; a theta
    # offset turns a link by it: its x component is a cos(theta), 612 mm x (2e-5)^2 / 2 = 1.2e-7 mm shorter
    assert chain.joints[1].translation[0] == pytest.approx(-611.8, abs=1e-6)
    assert chain.joints[2].translation[0] == pytest.approx(-572.4, abs=1e-6)
    assert chain.joints[0].translation[2] == pytest.approx(127.4, abs=1e-9)
    bad = subprocess.run([*TRACKCAL, "factory-robot", "--cell", "kr270", "--conf", str(conf), "--out", str(out)],
                         capture_output=True, text=True)  # fmt: skip
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1
