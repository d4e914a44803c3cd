"""The UR10 study's orientation residual (studies/ur10_ipa/orientation.py) on synthetic T-Mac data: a robot, a
station and a probe mount known exactly; the station comes from the positions alone, the mount from the
orientations, and the residual is the angle by which the measured orientations were turned."""

import numpy as np
import pytest

from studies.ur10_ipa.error_map_check import STATION_ONLY
from studies.ur10_ipa.orientation import ANGLE_COLUMNS, angular_rms_mrad
from trackcal.calib.identify.solver import identify
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.rigid import exp_so3
from trackcal.campaign.importers.ipa_ur10 import POINT


def tmac_table(q: np.ndarray, point: np.ndarray, turn_rad: float, rng: np.random.Generator) -> MeasurementTable:
    """Positions and XYZ Euler angles (as the importer stores them, 10 significant digits) of the T-Mac on the
    nominal UR10 seen from a fixed station, every orientation turned by `turn_rad` about a random axis."""
    chain = load_cell("ur10-ipa").chain
    r_st, t_st = exp_so3(np.array([0.3, -0.2, 1.9])), np.array([2500.0, -800.0, 300.0])
    mount = exp_so3(np.array([0.01, 0.02, -1.2]))
    r_fl, _ = Kinematics(chain, []).end_frames(q)
    xyz = Kinematics(chain, []).points(q, np.tile(point, (len(q), 1))) @ r_st.T + t_st
    axes = rng.normal(size=(len(q), 3))
    turns = np.array([exp_so3(turn_rad * a / np.linalg.norm(a)) for a in axes])
    r_meas = r_st @ r_fl @ mount @ turns
    # R = Rx(a) Ry(b) Rz(c): b = asin(R02), a = atan2(-R12, R22), c = atan2(-R01, R00)
    angles = np.degrees(
        np.column_stack(
            [
                np.arctan2(-r_meas[:, 1, 2], r_meas[:, 2, 2]),
                np.arcsin(r_meas[:, 0, 2]),
                np.arctan2(-r_meas[:, 0, 1], r_meas[:, 0, 0]),
            ]
        )
    )
    n = len(q)
    return MeasurementTable(
        seq=np.arange(n),
        t_s=10.0 * np.arange(n),
        pose=[f"P{i}" for i in range(n)],
        station=["B"] * n,
        point=[POINT] * n,
        q_deg=np.degrees(q),
        xyz=xyz,
        extra={c: [format(v, ".10g") for v in angles[:, k]] for k, c in enumerate(ANGLE_COLUMNS)},
    )


def test_angular_residual_is_the_turn_of_the_measured_orientation():
    cell = load_cell("ur10-ipa")
    tmac = {POINT: cell.tool_points[POINT]}
    rng = np.random.default_rng(7)
    q = rng.uniform(-np.pi, np.pi, size=(40, 6))
    exact = tmac_table(q, tmac[POINT], 0.0, rng)
    turned = tmac_table(q, tmac[POINT], 1e-3, rng)
    fit = identify(cell.chain, exact, tmac, [], fixed=STATION_ONLY)  # the station from the positions alone
    # 10 significant digits of ~100 deg: 1e-8 deg = 2e-7 mrad per angle
    assert angular_rms_mrad(fit, exact, fit, exact) < 1e-5
    assert angular_rms_mrad(fit, exact, fit, turned) == pytest.approx(1.0, abs=1e-5)  # 1 mrad turn, every row
