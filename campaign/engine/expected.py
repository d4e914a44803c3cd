"""Where the nominal model expects each measurement (the position FindReflector is given), and how far from it
a measurement may lie before the campaign stops (Devices.expected and Devices.tolerance of the engine)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from trackcal.calib.model.cell import Cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.campaign.engine.steps import Step


def expected_position(cell: Cell) -> Callable[[Step], tuple[float, float, float] | None]:
    """Where the reflector should be, in the station's frame, by the nominal model (for FindReflector)."""
    kin = Kinematics(cell.chain, [])

    def expected(step: Step):
        st = cell.stations.get(step.station)
        if st is None or step.point not in cell.tool_points:
            return None
        p = kin.points(np.radians(np.asarray(step.q_deg))[None], cell.tool_points[step.point])[0]
        x = st.rotation.T @ (p - st.position)
        return float(x[0]), float(x[1]), float(x[2])

    return expected


# How far a measurement may lie from where the nominal model expects it, before the campaign stops. The
# expectation errs by the robot's nominal-model error and by the station's placement error:
# - the uncalibrated KR-270 of the paper misses by at most 1.31 mm (Table 9, distance residuals before calibration);
# - a tracker set up on a nominal station of the cell config sits within about 20 mm (position) and 0.5 deg
#   (orientation) of it per axis, one standard deviation: the digital twin's model of a station set-up
#   (mocks/twin.py); an orientation error w moves a point at range r by |w x r| <= |w| r.
# Three standard deviations on each of the three axes: 3 * sqrt(3) * (20 mm + 0.5 deg * r) + 1.31 mm, i.e.
# 105 mm next to the tracker, 264 mm at 3.5 m. A cell's `measurement_tolerance_mm` replaces it.
NOMINAL_ROBOT_ERROR_MM = 1.31
STATION_POSITION_SIGMA_MM = 20.0
STATION_ORIENTATION_SIGMA_DEG = 0.5


def measurement_tolerance(cell: Cell) -> Callable[[float], float]:
    """range from the tracker (mm) -> how far (mm) a measurement may lie from its expected position."""
    if cell.measurement_tolerance_mm is not None:
        fixed = cell.measurement_tolerance_mm
        return lambda reach_mm: fixed

    def tolerance(reach_mm: float) -> float:
        station = STATION_POSITION_SIGMA_MM + np.radians(STATION_ORIENTATION_SIGMA_DEG) * reach_mm
        return float(3.0 * np.sqrt(3.0) * station + NOMINAL_ROBOT_ERROR_MM)

    return tolerance
