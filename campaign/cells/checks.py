"""The robot client's checks from the cell config and the cell PLC, the same for the real cell and the twin's."""

from __future__ import annotations

import numpy as np

from trackcal.calib.doe.poses import points_in_box
from trackcal.calib.model.cell import Cell, CellError, usable_limits_deg
from trackcal.drivers.errors import DeviceError
from trackcal.drivers.interfaces import StopCause
from trackcal.drivers.plc.client import ModbusCellIO
from trackcal.drivers.plc.codec import REQUEST_TARGET_CHARS, hmi_text


def cell_box_check(cell: Cell):
    """The robot client's pre-send check: every reference point of the target pose inside the cell box."""

    def check(q_deg) -> str | None:
        if points_in_box(cell, np.radians(np.asarray(q_deg, dtype=float))[None])[0]:
            return None
        return "a reference point of the target pose leaves the cell box"

    return check


def names_told_apart(cell: Cell) -> None:
    """Refuse (CellError, one line) a cell two of whose points, or two of whose stations, the cell HMI shows alike
    (drivers.plc.codec.hmi_text: the first 16 characters, ASCII): the operator could not tell which one a request
    asks for."""
    for what, names in (("points", cell.tool_points), ("stations", cell.stations)):
        seen: dict[str, str] = {}
        for name in names:
            shown = hmi_text(name)
            if shown in seen:
                raise CellError(
                    f"{cell.source}: {what} {seen[shown]!r} and {name!r} both show as {shown!r} on "
                    f"the cell display (first {REQUEST_TARGET_CHARS} characters, ASCII): rename one"
                )
            seen[shown] = name


def joint_limits_deg(cell: Cell) -> list[tuple[float, float]]:
    """The robot client's pre-send check: the joint limits less the cell's margin, as the whole-plan check."""
    return [(float(lo), float(hi)) for lo, hi in usable_limits_deg(cell)]


def robot_limits_deg(cell: Cell) -> list[tuple[float, float]]:
    """The robot's own joint limits (deg, no margin): the software limit switches of the twin's controller."""
    return [(float(lo), float(hi)) for lo, hi in np.degrees(cell.chain.limits_array())]


# The motion guard's stop codes (the stop's DeviceFault code, recorded in the session's error event)
DOOR_OPEN = "door_open"  # the PLC answered: the cell door is open
PLC_SILENT = "plc_silent"  # the PLC does not answer: the door cannot be known, so the robot stops as if it were open
ESTOP_PRESSED = "estop_pressed"  # the PLC's emergency-stop input


def motion_guard(cellio: ModbusCellIO):
    """The robot client's guard during moves and settling (drivers.kuka.client polls it at 25 Hz): why the robot
    must stop now (a StopCause: one line and its code), or None. The door and the PLC's emergency-stop input; a PLC
    that cannot be read stops the robot too, named as what it is (an unreadable door reads as open in
    drivers.plc.client, but it is not an open door)."""

    def guard() -> StopCause | None:
        if not cellio.door_closed():
            if cellio.last_door_error is not None:
                return StopCause(f"the cell PLC does not answer ({cellio.last_door_error})", PLC_SILENT)
            return StopCause("the cell door opened", DOOR_OPEN)
        try:
            if not cellio.read_status().estop_ok:
                return StopCause("the cell's emergency stop is pressed", ESTOP_PRESSED)
        except DeviceError as exc:
            return StopCause(f"the cell PLC cannot be read ({exc})", PLC_SILENT)
        return None

    return guard
