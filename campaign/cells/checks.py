"""The robot client's checks from the cell config, the same for the real cell and the twin's."""

from __future__ import annotations

import numpy as np

from calib.cell import Cell, usable_limits_deg
from calib.poses import points_in_box


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
