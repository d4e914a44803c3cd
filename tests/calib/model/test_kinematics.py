"""Forward kinematics against pinocchio, analytic Jacobians against finite differences."""

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.helpers import ROOT
from trackcal.calib.model.chain import chain_from_urdf
from trackcal.calib.model.kinematics import Kinematics, cross3, turned
from trackcal.calib.model.params import complete_params
from trackcal.calib.model.pinmodel import pinocchio_model
from trackcal.calib.model.rigid import exp_so3, rot_axis

TOOL = np.array([277.0, -47.0, -94.0])


def test_nominal_fk_matches_pinocchio(kr270):
    model = pinocchio_model(kr270.chain, TOOL)
    data = model.createData()
    kin = Kinematics(kr270.chain, [])
    q = np.random.default_rng(3).uniform(-np.pi, np.pi, size=(50, 6))
    ours = kin.points(q, TOOL)
    for qi, p in zip(q, ours, strict=True):
        pin.framesForwardKinematics(model, data, qi)
        np.testing.assert_allclose(p, 1000.0 * data.oMf[model.getFrameId("tip")].translation, atol=1e-9)


def test_urdf_chain_matches_pinocchio_urdf():
    path = ROOT / "tests" / "data" / "ur_like_dh.urdf"
    chain = chain_from_urdf(str(path))
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    q = np.random.default_rng(4).uniform(-np.pi, np.pi, size=(20, 6))
    ours = Kinematics(chain, []).end_frames(q)
    for qi, r, o in zip(q, *ours, strict=True):
        pin.forwardKinematics(model, data, qi)
        np.testing.assert_allclose(o, 1000.0 * data.oMi[6].translation, atol=1e-9)
        np.testing.assert_allclose(r, data.oMi[6].rotation, atol=1e-12)


finite = st.floats(-np.pi, np.pi, allow_nan=False)


@settings(max_examples=30, deadline=None)
@given(q=st.lists(finite, min_size=6, max_size=6), seed=st.integers(0, 2**31))
def test_jacobians_match_central_differences(kr270, q, seed):
    """Every column (all 30 complete parameters, away from nominal; tool point; joints) vs central FD."""
    params = complete_params(kr270.chain)
    kin = Kinematics(kr270.chain, params)
    rng = np.random.default_rng(seed)
    dev = np.array([rng.normal(0, 1.0) if p.is_length else rng.normal(0, 0.01) for p in params])
    q = np.array(q)[None]
    jac = kin.jacobian(q, TOOL, dev)
    h = 1e-6

    def fd(f, x):
        cols = []
        for i in range(len(x)):
            e = np.zeros(len(x))
            e[i] = h
            cols.append((f(x + e) - f(x - e)) / (2 * h))
        return np.array(cols).T

    # O(h^2) truncation with ~2000 mm lever arms: ~1e-8 mm; rounding ~1e-16 * 2000 / 1e-6 ~ 2e-7 mm
    np.testing.assert_allclose(jac.d_params[0], fd(lambda d: kin.points(q, TOOL, d)[0], dev), atol=2e-6)
    np.testing.assert_allclose(jac.d_point[0], fd(lambda t: kin.points(q, t, dev)[0], TOOL), atol=2e-6)
    np.testing.assert_allclose(jac.d_q[0], fd(lambda qq: kin.points(qq[None], TOOL, dev)[0], q[0]), atol=2e-6)


@settings(max_examples=20, deadline=None)
@given(q=st.lists(finite, min_size=6, max_size=6), seed=st.integers(0, 2**31))
def test_jacobian_derivative_wrt_joints_matches_central_differences(kr270, q, seed):
    """d(identification Jacobian)/dq, used by the planner's analytic gradient, against central FD."""
    params = complete_params(kr270.chain)
    kin = Kinematics(kr270.chain, params)
    rng = np.random.default_rng(seed)
    dev = np.array([rng.normal(0, 1.0) if p.is_length else rng.normal(0, 0.01) for p in params])
    q = np.array(q)
    dd = kin.d_params_dq(kin.jacobian(q[None], TOOL, dev))[0]
    h = 1e-6
    for j in range(6):
        e = np.zeros(6)
        e[j] = h
        fd = kin.jacobian((q + e)[None], TOOL, dev).d_params[0] - kin.jacobian((q - e)[None], TOOL, dev).d_params[0]
        np.testing.assert_allclose(dd[:, :, j], fd / (2 * h), atol=2e-6)


def test_rows_sharing_a_pose_give_the_per_row_result(kr270):
    """jacobian/points on the distinct poses with each row's pose index equal the per-row computation."""
    params = complete_params(kr270.chain)
    kin = Kinematics(kr270.chain, params)
    rng = np.random.default_rng(31)
    poses, dev = rng.uniform(-np.pi, np.pi, size=(5, 6)), rng.normal(0, 1e-3, len(params))
    rows = rng.integers(0, 5, 17)
    tool = rng.normal(0, 300, (17, 3))
    a, b = kin.jacobian(poses, tool, dev, rows=rows), kin.jacobian(poses[rows], tool, dev)
    for name in ("p", "d_params", "d_point", "d_q", "joint_axes", "rot_axes"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(kin.points(poses, tool, dev, rows=rows), kin.points(poses[rows], tool, dev))


@settings(max_examples=30, deadline=None)
@given(
    axis=st.integers(0, 2),
    angles=st.lists(finite, min_size=1, max_size=5),
    w=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
)
def test_a_turn_is_the_product_with_the_axis_rotation(axis, angles, w):
    """The forward kinematics turns a frame about one of its axes by mixing two columns: r @ rot_axis."""
    angles = np.array(angles)
    r = exp_so3(np.array(w))
    columns = np.repeat(r.T[:, :, None], len(angles), axis=2)  # r[:, a] of every row: columns[a] (3, rows)
    out = turned(columns, axis, np.cos(angles), np.sin(angles))
    np.testing.assert_allclose(out.transpose(2, 1, 0), r @ rot_axis(axis, angles), atol=1e-15)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_cross3_moved_by_a_transpose_equals_np_cross(axis):
    """cross3 moves the coordinate axis to the front by a transpose (not np.moveaxis) and writes into `out` when given:
    bit for bit np.cross's products and differences, broadcast shapes and out alike."""
    rng = np.random.default_rng(axis)
    shape_a, shape_b = [4, 1, 5], [1, 2, 5]  # broadcast against each other to (4, 2, 5)
    shape_a.insert(axis, 3)
    shape_b.insert(axis, 3)
    a, b = rng.normal(size=shape_a), rng.normal(size=shape_b)
    want = np.cross(a, b, axisa=axis, axisb=axis, axisc=axis)
    np.testing.assert_array_equal(cross3(a, b, axis=axis), want)
    out = np.full(want.shape, np.nan)
    assert cross3(a, b, axis=axis, out=out) is out
    np.testing.assert_array_equal(out, want)
