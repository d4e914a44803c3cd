"""DH tables in the robot YAML (calib.model.dh): standard and modified DH, theta offsets and joint signs, give the
forward kinematics of the chains in configs/robots and of the tables' own products to 1e-9 mm."""

import numpy as np
import pytest

from trackcal.calib.model.cell import load_robot
from trackcal.calib.model.chain import ChainError, chain_from_dict
from trackcal.calib.model.identifiability import identification_jacobian, numerical_rank, random_configuration
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params

# Universal Robots' published UR10 (CB3) DH parameters (universal-robots.com, "DH parameters for calculations of
# kinematics and dynamics"): d1 = 0.1273, a2 = -0.612, a3 = -0.5723, d4 = 0.163941, d5 = 0.1157, d6 = 0.0922 m,
# alpha1 = pi/2, alpha4 = pi/2, alpha5 = -pi/2, the others 0.
UR10_A = [0.0, -612.0, -572.3, 0.0, 0.0, 0.0]
UR10_D = [127.3, 0.0, 0.0, 163.941, 115.7, 92.2]
UR10_ALPHA = [90.0, 0.0, 0.0, 90.0, -90.0, 0.0]


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _tz(d):
    m = np.eye(4)
    m[2, 3] = d
    return m


def _tx(a):
    m = np.eye(4)
    m[0, 3] = a
    return m


def textbook_standard(a, alpha_deg, d, theta):
    """Rz(theta) Tz(d) Tx(a) Rx(alpha) per row, multiplied out: the textbook formula, written here independently."""
    t = np.eye(4)
    for ai, al, di, th in zip(a, alpha_deg, d, theta, strict=True):
        t = t @ _rz(th) @ _tz(di) @ _tx(ai) @ _rx(np.radians(al))
    return t


def end_frames(chain, q):
    r, o = Kinematics(chain, []).end_frames(q)
    t = np.tile(np.eye(4), (len(q), 1, 1))
    t[:, :3, :3], t[:, :3, 3] = r, o
    return t


def rows(a, alpha, d, **extra):
    return [
        {"a_mm": ai, "alpha_deg": al, "d_mm": di, **{k: v[i] for k, v in extra.items()}}
        for i, (ai, al, di) in enumerate(zip(a, alpha, d, strict=True))
    ]


def modified_rows(a, alpha, d, **extra):
    """A standard table written as Craig's modified one: row i carries a_{i-1}, alpha_{i-1} (the same product)."""
    return rows([0.0, *a[:-1]], [0.0, *alpha[:-1]], d, **extra)


Q = np.random.default_rng(23).uniform(-np.pi, np.pi, size=(50, 6))


def test_ur10_published_dh_is_the_ur10_chain():
    ur10, _ = load_robot("ur10")
    for doc in (
        load_robot("ur10-dh")[1],
        {"dh": {"convention": "standard", "rows": rows(UR10_A, UR10_ALPHA, UR10_D)}},
        {"dh": {"convention": "modified", "rows": modified_rows(UR10_A, UR10_ALPHA, UR10_D)}},
    ):
        chain = chain_from_dict(doc)
        got, want = end_frames(chain, Q), end_frames(ur10, Q)
        np.testing.assert_allclose(got[:, :3, 3], want[:, :3, 3], atol=1e-9)
        np.testing.assert_allclose(got[:, :3, :3], want[:, :3, :3], atol=1e-12)
        for qi, g in zip(Q, got, strict=True):
            np.testing.assert_allclose(g, textbook_standard(UR10_A, UR10_ALPHA, UR10_D, qi), atol=1e-9)


def test_kr270_standard_and_modified_dh_are_the_kr270_chain():
    kr270, _ = load_robot("kr270")
    std = load_robot("kr270-dh")[1]["dh"]
    a, alpha, d = ([r.get(k, 0.0) for r in std["rows"]] for k in ("a_mm", "alpha_deg", "d_mm"))
    offsets = [r.get("theta_offset_deg", 0.0) for r in std["rows"]]
    modified = {
        "convention": "modified",
        "rows": modified_rows(a, alpha, d, theta_offset_deg=offsets),
        "flange": std["flange"],
    }
    for doc in ({"dh": std}, {"dh": modified}):
        got, want = end_frames(chain_from_dict(doc), Q), end_frames(kr270, Q)
        np.testing.assert_allclose(got[:, :3, 3], want[:, :3, 3], atol=1e-9)
        np.testing.assert_allclose(got[:, :3, :3], want[:, :3, :3], atol=1e-12)
    # the paper's eq. (5) lengths at the zero pose: 350 + 1150 + 1200 = 2700 mm out, 675 mm up less the 41 mm the A3
    # link goes down
    np.testing.assert_allclose(
        end_frames(chain_from_dict({"dh": std}), np.zeros((1, 6)))[0, :3, 3], [2700, 0, 634], atol=1e-9
    )


def test_irb120_literature_dh_is_the_ros_industrial_chain_and_the_datasheet():
    irb, _ = load_robot("irb120")
    dh, _ = load_robot("irb120-dh")
    got, want = end_frames(dh, Q), end_frames(irb, Q)
    np.testing.assert_allclose(got[:, :3, 3], want[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(got[:, :3, :3], want[:, :3, :3], atol=1e-12)
    # ABB's product specification (3HAC035960-001): at the calibration position (all zeros) the flange is
    # 302 + 72 = 374 mm out and 290 + 270 + 70 = 630 mm up
    np.testing.assert_allclose(end_frames(dh, np.zeros((1, 6)))[0, :3, 3], [374, 0, 630], atol=1e-9)


def test_irb6700_dh_is_the_ros_industrial_chain_and_the_datasheet():
    irb, _ = load_robot("irb6700")
    dh, _ = load_robot("irb6700-dh")
    got, want = end_frames(dh, Q), end_frames(irb, Q)
    np.testing.assert_allclose(got[:, :3, 3], want[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(got[:, :3, :3], want[:, :3, :3], atol=1e-12)
    # ABB's dimension drawing of the IRB 6700-200/2.60 (as abb_irb6700_support carries it): at the calibration
    # position (all zeros) the flange is 320 + 1142.5 + 200 = 1662.5 mm out and 780 + 1125 + 200 = 2105 mm up
    np.testing.assert_allclose(end_frames(dh, np.zeros((1, 6)))[0, :3, 3], [1662.5, 0, 2105], atol=1e-9)


def test_signs_and_offsets_are_the_datasheet_theta():
    """theta_i = sign_i q_i + offset_i, against the textbook product with that theta."""
    sign = [1, -1, 1, -1, -1, 1]
    off = [10.0, -90.0, 0.0, 180.0, 33.0, -5.0]
    doc = {"dh": {"rows": rows(UR10_A, UR10_ALPHA, UR10_D, sign=sign, theta_offset_deg=off)}}
    got = end_frames(chain_from_dict(doc), Q)
    for qi, g in zip(Q, got, strict=True):
        theta = np.array(sign) * qi + np.radians(off)
        np.testing.assert_allclose(g, textbook_standard(UR10_A, UR10_ALPHA, UR10_D, theta), atol=1e-9)


@pytest.mark.parametrize("robot", ["ur10-dh", "kr270-dh", "irb120-dh", "irb120", "irb6700-dh", "irb6700"])
def test_dh_robots_get_a_complete_irreducible_set(robot):
    chain, _ = load_robot(robot)
    kept, eliminated = irreducible_params(chain)
    assert len(kept) == 18  # 4 x 6 - 6 (calib.model.params)
    tool = np.array([[100.0, 20, 30], [80, -40, 50], [120, 0, -60]])
    q = random_configuration(chain, 30, np.random.default_rng(1))
    j = identification_jacobian(chain, kept, q, tool)
    assert numerical_rank(j) == j.shape[1]
    for e in eliminated:
        j_plus = identification_jacobian(chain, kept + [e.param], q, tool)
        assert numerical_rank(j_plus) == j_plus.shape[1] - 1, e.param.name


@pytest.mark.parametrize(
    ("dh", "message"),
    [
        ({"convention": "craig", "rows": [{}]}, r"dh.convention: expected standard or modified, got 'craig'"),
        ({"rows": [{"a_mm": 1, "sign": 2}]}, r"dh.rows\[0\].sign: expected 1 or -1"),
        ({"rows": [{"a": 1}]}, r"dh.rows\[0\]: unknown key 'a'"),
        ({"rows": [{"d_mm": "x"}]}, r"dh.rows\[0\].d_mm"),
        ({"rows": []}, r"dh.rows: the table has no rows"),
    ],
)
def test_dh_mistakes_name_the_key(dh, message):
    with pytest.raises(ChainError, match=message):
        chain_from_dict({"dh": dh}, "robot.yaml")


def test_joints_and_dh_together_are_refused():
    with pytest.raises(ChainError, match="either 'joints' or 'dh'"):
        chain_from_dict({"joints": [{"axis": "z"}], "dh": {"rows": [{}]}})
