"""A measurement table in the wrong units, told before any fit: positions in metres or inches, joints in radians.

Every fit takes millimetres and degrees (DESIGN.md). A table in metres fits "well" (the tiny positions are explained
by a shrunken robot: residual 0.0 um, px2 -1148.85 mm before this check), so the units are judged from physics
before anything is fitted:

- Positions. A reflector sits on a tool at the flange, so between two poses it moves as far as the flange does, give
  or take the tool's lever; the flange's motion is the nominal chain's, in millimetres. The scale of the table's
  lengths is the RMS spread of each (station, point)'s measured positions over the RMS spread of the flange at the
  same rows (the nominal model; rotations of the station frame do not change a spread). In millimetres it is about
  1 (the lever, a few centimetres against poses that span the workspace, as calib.identify.points also relies on);
  in inches it is 1/25.4 (the inch is 25.4 mm exactly, NIST SP 811 B.6), in metres 1/1000. The units are told apart
  at the geometric means of their scales: below sqrt(1/25.4) = 0.198 the lengths are not millimetres (a tool would
  need a lever of 80 % of the flange's spread, turning about the reflector itself, to shrink the motion so), and
  below sqrt(1/25400) = 0.0063 they are metres. The median distance from the tracker says the same on its own scale:
  a tracker sees the reflectors from about a metre to tens of metres (an AT901 measures to 80 m), which a table in
  metres writes as 1 to 80 "mm"; it is given with the verdict.
- Joints. A campaign spans the joints' ranges (paper section 6: the configurations are chosen over the whole joint
  space). Written in radians, every value lies within the joint's limits read in radians (pi where the robot file
  gives none; +-2 pi for a joint of +-360 deg), which in degrees is a few degrees about zero. A table whose every joint
  value lies so, while some joint moves by more than RADIAN_SPREAD (0.5 rad = 29 deg, read as radians; in degrees, a
  campaign whose joints never leave a few degrees about zero, which identifies nothing), is in radians. A table
  that does not move (one pose repeated) has no spread to tell by and passes.
"""

from __future__ import annotations

import math

import numpy as np

from trackcal.calib.io.table import MeasurementTable, TableError, label_codes, read_table
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.kinematics import Kinematics, row_runs

INCH_MM = 25.4  # NIST SP 811, B.6
NOT_MM_BELOW = 1.0 / math.sqrt(INCH_MM)  # between mm (1) and in (1/25.4)
METRES_BELOW = 1.0 / math.sqrt(INCH_MM * 1000.0)  # between in (1/25.4) and m (1/1000)
WRITTEN_RAD = 1e-3  # the rounding of joint values written in radians (four decimals), with room
RADIAN_SPREAD = 0.5  # rad: a joint moving by this much in a campaign, read as radians


class UnitsError(TableError):
    """A table whose numbers are in another unit than millimetres and degrees; the message names the likely one."""


def length_scale(table: MeasurementTable, chain: Chain) -> float | None:
    """The table's lengths per millimetre of the flange's nominal motion (about 1 in millimetres; see the module),
    None when no (station, point) is measured at two poses apart, or the table has no positions."""
    if table.xyz is None or len(table) < 2:
        return None
    q = np.radians(table.q_deg)
    runs, of_row = row_runs(q)  # the chain walked once for the rows of a pose that follow each other
    flange = Kinematics(chain, []).points(q[runs], np.zeros(3), rows=of_row)  # the flange's origin
    (station, _), (point, pids) = label_codes(table.station), label_codes(table.point)
    group = station * len(pids) + point  # one code per (station, point)
    count = np.bincount(group)
    measured, moved = (_spread(v, group, count) for v in (table.xyz, flange))
    if moved <= 1e-12 or not math.isfinite(measured):
        return None
    return math.sqrt(measured / moved)


def _spread(v: np.ndarray, group: np.ndarray, count: np.ndarray) -> float:
    """The sum of squared distances of rows v (N, 3) from their group's mean (a group of one row adds nothing)."""
    means = np.stack([np.bincount(group, weights=c, minlength=len(count)) for c in v.T], axis=1)
    return float(np.sum((v - means[group] / np.maximum(count, 1)[group, None]) ** 2))


def radian_bounds(chain: Chain) -> np.ndarray:
    """(n,) the largest magnitude of each joint's values written in radians: its limits (pi where none is given)."""
    lim = np.abs(chain.limits_array()).max(axis=1)
    return np.where(np.isfinite(lim), lim, np.pi) + WRITTEN_RAD


def joints_in_radians(q_deg: np.ndarray, chain: Chain) -> bool:
    """Every joint value within its limits read in radians while some joint moves by more than RADIAN_SPREAD."""
    q = np.asarray(q_deg, dtype=float)
    if q.ndim != 2 or len(q) < 2 or q.shape[1] != chain.dof:
        return False
    return bool(np.all(np.abs(q) <= radian_bounds(chain)) and np.max(np.ptp(q, axis=0)) > RADIAN_SPREAD)


def check_units(table: MeasurementTable, chain: Chain) -> None:
    """UnitsError, one line naming the likely unit, when the table's joints look like radians or its positions like
    metres or inches (the module says from what)."""
    if joints_in_radians(table.q_deg, chain):
        spread = float(np.max(np.ptp(table.q_deg, axis=0)))
        raise UnitsError(
            f"{table.source}: the joints look like radians, not degrees: every value is within the "
            f"joint's limits read in radians and a joint moves by {spread:.3g}, which in degrees would be "
            "a campaign that hardly moves; write q*_deg in degrees (trackcal import table: units: "
            "{joints: rad})"
        )
    scale = length_scale(table, chain)
    if scale is None or scale >= NOT_MM_BELOW:
        return
    unit, factor, key = ("metres", 1000.0, "m") if scale < METRES_BELOW else ("inches", INCH_MM, "in")
    median = float(np.median(np.linalg.norm(table.xyz, axis=1)))
    raise UnitsError(
        f"{table.source}: the positions look like {unit}, not millimetres: the reflectors move "
        f"{scale:.3g} times as far as the robot's flange between poses (1/{factor:g} in {unit}), and "
        f"their median distance from the tracker is {median:.4g}; write x_mm, y_mm, z_mm in millimetres "
        f"(trackcal import table: units: {{length: {key}}})"
    )


def read_measured(path, chain: Chain, require_xyz: bool = True) -> MeasurementTable:
    """The table at `path` for a fit on `chain` (calib.io.table.read_table: its joint count and limits), its units
    checked: the one way a command reads a measurement table for a robot."""
    table = read_table(path, require_xyz=require_xyz, chain=chain)
    check_units(table, chain)
    return table
