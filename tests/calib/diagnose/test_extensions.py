"""Extensions compose, and the thermal form is every length of the arm, tool included, the base column an option.

Thermal numbers from physics: a steel arm grows 11.5 ppm/K; warming 2 K/h gives 23 ppm/h, over a two-hour
campaign 46 ppm, 0.14 mm at the KR-270's 3 m and 31 um over its 675 mm base column (configs/robots/kr270.yaml),
twice the AT901 tracker noise (15 um per coordinate, calib/identify/noise.py): enough rows tell the two forms apart.
"""

import numpy as np
import pytest

from trackcal.calib.diagnose.extensions import THERMAL_FORMS, build_extension
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify import solver
from trackcal.calib.identify.solver import Problem, Station, identify, predict_points
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.extension import combine
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model.rigid import exp_so3

NOISE_MM = 0.015
GROWTH_PER_S = 23e-6 / 3600.0  # 11.5 ppm/K x 2 K/h


def campaign(cell, n_poses: int, seed: int, pivot: np.ndarray, rate: float) -> MeasurementTable:
    """Every reference point of every pose from one station, 20 s per measurement, the arm growing by
    rate * t about `pivot` (the robot base frame's origin: the whole robot warms; the first joint's frame:
    the base column does not)."""
    rng = np.random.default_rng(seed)
    q = random_poses(cell, n_poses, rng)
    pids = sorted(cell.tool_points)
    rows_q = np.repeat(q, len(pids), axis=0)
    rows_p = np.tile(np.array([cell.tool_points[p] for p in pids]), (n_poses, 1))
    t = np.arange(len(rows_q)) * 20.0
    pb = Kinematics(cell.chain, []).points(rows_q, rows_p)
    pb = pivot + (1.0 + rate * t)[:, None] * (pb - pivot)
    rot, trans = exp_so3(np.array([0.1, -0.2, 2.5])), np.array([3000.0, -1000.0, -800.0])
    xyz = pb @ rot.T + trans + rng.normal(0.0, NOISE_MM, pb.shape)
    n = len(t)
    return MeasurementTable(
        seq=np.arange(n),
        t_s=t,
        pose=[f"Q{i // len(pids)}" for i in range(n)],
        station=["S"] * n,
        point=pids * n_poses,
        q_deg=np.degrees(rows_q),
        xyz=xyz,
    )


@pytest.mark.parametrize("form", THERMAL_FORMS)
def test_thermal_form_is_recovered_and_the_data_choose_the_pivot(kr270, form):
    cell = kr270
    chain = cell.chain
    pivot = np.zeros(3) if form == "e_base" else chain.base[:3, 3]
    table = campaign(cell, 120, 3, pivot, GROWTH_PER_S)
    params = irreducible_params(chain)[0]
    fits = {}
    for name in THERMAL_FORMS:
        ext = build_extension("thermal_drift", chain, table, names=[name])
        fits[name] = identify(chain, table, cell.tool_points, params, extension=ext)
    res = fits[form]
    assert abs(res.ext[0] - GROWTH_PER_S) < res.ext_ci95()[0]  # the rate comes back within its 95 % interval
    other = next(f for f in THERMAL_FORMS if f != form)
    assert fits[form].variance_factor < fits[other].variance_factor  # the true pivot fits better


def test_thermal_growth_includes_the_tool(kr270):
    cell = kr270
    chain = cell.chain
    rows = campaign(cell, 4, 5, np.zeros(3), 0.0)
    ext = build_extension("thermal_drift", chain, rows, names=["e_base"])
    ext.growth[:] = 1.0  # unit growth feature: theta is the growth itself
    theta = np.array([1e-3])
    kin = Kinematics(chain, [])
    pts = {p: cell.tool_points[p] for p in sorted(cell.tool_points)}
    stations = {"S": Station(np.eye(3), np.zeros(3))}
    pred = predict_points(chain, [], np.zeros(0), stations, pts, rows, ext, theta)
    tool = np.array([pts[p] for p in rows.point])
    rigid = kin.points(np.radians(rows.q_deg), tool)
    np.testing.assert_allclose(pred, (1.0 + 1e-3) * rigid, atol=1e-9)  # every length, the tool's too


def test_combined_extension_jacobian_matches_finite_differences(kr270):
    cell = kr270
    chain = cell.chain
    table = campaign(cell, 12, 9, np.zeros(3), 0.0)
    arcs_ext = build_extension("cyclic_error", chain, table, harmonics=3)
    ext = combine(
        [
            build_extension("joint_compliance", chain, table),
            arcs_ext,
            build_extension("thermal_drift", chain, table, names=["e_base"]),
        ],
        cause="cyclic_error",
    )
    assert [c for c, _ in ext.parts()] == ["joint_compliance", "cyclic_error", "thermal_drift"]
    params = irreducible_params(chain)[0]
    rng = np.random.default_rng(2)
    theta = rng.normal(0.0, 1e-4, ext.size)
    theta[-1] = GROWTH_PER_S
    problem = Problem(
        chain, table, cell.tool_points, params, extension=ext, ext0=theta, dev0=rng.normal(0.0, 1e-3, len(params))
    )
    state = problem.initial
    r0, jm = problem.residual_and_jacobian(state)
    k = len(params)
    for c in [0, k, k + 1, k + ext.size - 2, k + ext.size - 1, problem.n_cols - 1]:
        step = np.zeros(problem.n_cols)
        h = 1e-4 / np.sqrt(np.mean(jm[:, c] ** 2))  # moves the prediction by ~0.1 um
        step[c] = h
        rp = problem.residual(problem.retract(state, step))
        rm = problem.residual(problem.retract(state, -step))
        # the Jacobian is of the prediction: residual = measured - predicted
        np.testing.assert_allclose(-(rp - rm) / (2 * h), jm[:, c], rtol=1e-5, atol=1e-6 * np.abs(jm[:, c]).max())


def test_growth_and_joint_columns_equal_the_dense_form(kr270):
    """A growing arm with joint features and a joint error map (a diagnosis's map search on top of thermal_drift): the
    Jacobian's extension columns as before issue 41, every column's growth term (zero off the growth parameter) plus
    the dense features' product, bit for bit."""
    cell = kr270
    chain = cell.chain
    table = campaign(cell, 12, 9, np.zeros(3), 0.0)
    ext = combine(
        [
            build_extension("joint_compliance", chain, table),
            build_extension("thermal_drift", chain, table, names=["e_base"]),
            build_extension("cyclic_error", chain, table, harmonics=3),
        ],
        cause="cyclic_error",
    )
    params = irreducible_params(chain)[0]
    rng = np.random.default_rng(3)
    theta = rng.normal(0.0, 1e-4, ext.size)
    problem = Problem(chain, table, cell.tool_points, params, extension=ext, ext0=theta)
    state = problem.initial
    _, jm = problem.residual_and_jacobian(state)
    # before: every extension column's growth term, then the dense features' product added a piece of rows at a time
    ch = problem._every_row
    assert len(ch.stations) == 1 and problem.noise is None  # one station, unwhitened: its rotation for every row
    jac = problem.kin.jacobian(
        problem._q(state)[problem.pose_first[ch.poses]], state.points[problem.pt_idx[ch.take]], state.dev, ch.of_row
    )
    m, grow = state.stations[0].rotation, 1.0 + ext.growth_of(theta)[ch.take]
    before = (m @ (jac.p - ext.pivot)[:, :, None]) * ext.growth[ch.take][:, None, :]
    m_dq = solver._rotated(m, grow * jac.d_q_t)
    before += m_dq @ ext.joint_features.take(ch.take).dense()
    k = len(params)
    assert np.array_equal(jm.reshape(len(table), 3, -1)[ch.order][:, :, k : k + ext.size], before)  # in chunk order
