"""The robot client's checks from the cell config and the cell PLC, the same for the real cell and the twin's."""

from __future__ import annotations

import numpy as np

from trackcal.calib.doe.poses import points_in_box
from trackcal.calib.model.cell import Cell, usable_limits_deg
from trackcal.drivers.errors import DeviceError
from trackcal.drivers.plc.client import ModbusCellIO


def cell_box_check(cell: Cell):
    """The robot client's pre-send check: every reference point of the target pose inside the cell box."""

    def check(q_deg) -> str | None:
        if points_in_box(cell, np.radians(np.asarray(q_deg, dtype=float))[None])[0]:
            return None
        return "a reference point of the target pose leaves the cell box"

    return check


def joint_limits_deg(cell: Cell) -> list[tuple[float, float]]:
    """The robot client's pre-send check: the joint limits less the cell's margin, as the whole-plan check."""
    return [(float(lo), float(hi)) for lo, hi in usable_limits_deg(cell)]


def robot_limits_deg(cell: Cell) -> list[tuple[float, float]]:
    """The robot's own joint limits (deg, no margin): the software limit switches of the twin's controller."""
    return [(float(lo), float(hi)) for lo, hi in np.degrees(cell.chain.limits_array())]


def motion_guard(cellio: ModbusCellIO):
    """The robot client's guard during moves and settling (drivers.kuka.client polls it at 25 Hz): why the robot
    must stop now, or None. The door and the PLC's emergency-stop input; a PLC that cannot be read stops the robot
    too, named as what it is (an unreadable door reads as open in drivers.plc.client, but it is not an open door)."""

    def guard() -> str | None:
        if not cellio.door_closed():
            if cellio.last_door_error is not None:
                return f"the cell PLC does not answer ({cellio.last_door_error})"
            return "the cell door opened"
        try:
            if not cellio.read_status().estop_ok:
                return "the cell's emergency stop is pressed"
        except DeviceError as exc:
            return f"the cell PLC cannot be read ({exc})"
        return None

    return guard
