"""Where a calibration measured: the joint ranges of its table and the volume its reflectors swept (issue 38).

A model is a fit to the poses it was measured at; outside them its parameters, and above all its extension, are
extrapolated, and the uncertainty it states there (the covariance of its parameters) says nothing of what it does not
model. So model.json records where it was measured (`measured`), and whoever states an accuracy from it (the program
filter) says how far a target lies outside:

- **joints**: each joint's range of angles over the table's rows (deg in the file, rad here);
- **volume**: the reflector centres the tracker measured, in the robot's base frame (the identified model's forward
  kinematics at each row's joints and point), in the base's cylinder coordinates about its z axis (the axis of joint 1
  on every robot the project ships): the range of their radius (distance from that axis) and of their height. That is
  how a robot's data sheet draws its working envelope (the side view: reach against height, the azimuth being joint
  1's range), so a cell engineer reads "measured from 900 to 2300 mm out, -300 to 1500 mm high" against the drawing
  and the cell's layout without a tool; an axis-aligned box would depend on where joint 1 happened to point, and a
  convex hull cannot be read at all.

A point is outside the volume by its distance, in the (radius, height) half-plane, to the measured rectangle: how far
it would have to move, at its own azimuth, to come back into the ring the reflectors swept (mm). A joint is outside
by how far its angle leaves the range (deg). A model written before these were recorded has none: `space_of` gives
None and the reader says "unknown".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.io.table import label_codes
from trackcal.calib.model.kinematics import Kinematics, row_runs

KEY = "measured"  # model.json's entry
ROUNDING_RAD = 1e-9  # a joint angle within this of its range is inside (the file's degrees to 17 digits)
ROUNDING_MM = 1e-6
CHUNK = 4096  # rows whose forward kinematics is computed at once


class MeasuredSpaceError(CalibError):
    """A model.json `measured` entry that cannot be read."""


@dataclass(frozen=True)
class MeasuredSpace:
    joints_rad: tuple[tuple[float, float], ...]  # (low, high) per joint
    radius_mm: tuple[float, float]  # the reflectors' distance from the base's z axis
    height_mm: tuple[float, float]  # their height along it

    @staticmethod
    def of(q: np.ndarray, points_base: np.ndarray) -> MeasuredSpace:
        """The space of joint angles q (N, n) rad and measured points (N, 3) mm in the base frame (N >= 1)."""
        r, z = cylinder(points_base)
        joints = tuple((float(lo), float(hi)) for lo, hi in zip(q.min(axis=0), q.max(axis=0), strict=True))
        return MeasuredSpace(joints, (float(r.min()), float(r.max())), (float(z.min()), float(z.max())))

    def joint_excess_deg(self, q: np.ndarray) -> np.ndarray:
        """(N, n) deg: how far each angle of q (N, n) rad lies outside its joint's measured range, 0 inside."""
        lim = np.array(self.joints_rad)
        excess = np.maximum(lim[:, 0] - q, q - lim[:, 1])
        return np.degrees(np.where(excess > ROUNDING_RAD, excess, 0.0))

    def volume_excess_mm(self, points_base: np.ndarray) -> np.ndarray:
        """(N,) mm: how far points (N, 3) in the base frame lie outside the measured volume (module docstring), 0
        inside."""
        r, z = cylinder(points_base)
        dr = np.maximum(np.maximum(self.radius_mm[0] - r, r - self.radius_mm[1]), 0.0)
        dz = np.maximum(np.maximum(self.height_mm[0] - z, z - self.height_mm[1]), 0.0)
        d = np.hypot(dr, dz)
        return np.where(d > ROUNDING_MM, d, 0.0)

    def to_doc(self) -> dict:
        return {
            "joints": {
                f"joint_{j + 1}": {"from_deg": float(np.degrees(lo)), "to_deg": float(np.degrees(hi))}
                for j, (lo, hi) in enumerate(self.joints_rad)
            },
            "volume": {
                "frame": "base cylinder (z: the base's z axis)",
                "radius_mm": list(self.radius_mm),
                "height_mm": list(self.height_mm),
            },
        }


def cylinder(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(radius, height) mm of points (N, 3) in the base frame about its z axis."""
    p = np.atleast_2d(np.asarray(points, dtype=float))
    return np.hypot(p[:, 0], p[:, 1]), p[:, 2]


def _pair(v, where: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in v)
    except (TypeError, ValueError):
        raise MeasuredSpaceError(f"{where}: expected two numbers, low and high") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
        raise MeasuredSpaceError(f"{where}: expected two finite numbers, low <= high, got {[lo, hi]}")
    return lo, hi


def space_of(doc: dict, n: int) -> MeasuredSpace | None:
    """The measured space model.json `doc` records for a robot of `n` joints; None when it records none (written
    before it was); MeasuredSpaceError naming the field when it is malformed."""
    entry = doc.get(KEY)
    if entry is None:
        return None
    where = KEY
    try:
        joints = entry["joints"]
        rows = [joints[f"joint_{j + 1}"] for j in range(n)]
        lims = tuple(_pair((r["from_deg"], r["to_deg"]), f"{where}.joints.joint_{j + 1}") for j, r in enumerate(rows))
        volume = entry["volume"]
        radius, height = volume["radius_mm"], volume["height_mm"]
    except (KeyError, TypeError) as exc:
        raise MeasuredSpaceError(f"{where}: incomplete (missing {exc})") from None
    joints_rad = tuple((float(np.radians(lo)), float(np.radians(hi))) for lo, hi in lims)
    return MeasuredSpace(
        joints_rad, _pair(radius, f"{where}.volume.radius_mm"), _pair(height, f"{where}.volume.height_mm")
    )


def fitted_space(
    kin: Kinematics, dev: np.ndarray, points: dict[str, np.ndarray], q_rad: np.ndarray, point_ids: list[str]
) -> MeasuredSpace:
    """The space of a fit: its table's joints q_rad (N, n) and the reflector centres `point_ids` (N,) of `points`
    (last joint frame, mm) where the fitted chain `kin` with deviations `dev` puts them."""
    rows, ids = label_codes(point_ids)
    tool = np.array([points[p] for p in ids]).reshape(-1, 3)[rows]
    out = np.zeros((len(q_rad), 3))
    for lo in range(0, len(q_rad), CHUNK):  # the chain's frames of a chunk at a time (issue 41: diagnose's memory)
        q = q_rad[lo : lo + CHUNK]
        runs, of_row = row_runs(q)  # the chain walked once for the rows of a pose that follow each other
        out[lo : lo + CHUNK] = kin.points(q[runs], tool[lo : lo + CHUNK], dev, rows=of_row)
    return MeasuredSpace.of(q_rad, out)
