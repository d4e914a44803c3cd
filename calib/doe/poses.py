"""Feasible measurement poses: joint limits, every reference point inside the cell box."""

from __future__ import annotations

import numpy as np

from trackcal.calib.doe.design import DesignError
from trackcal.calib.model.cell import Cell
from trackcal.calib.model.kinematics import Kinematics


def points_in_box(cell: Cell, q: np.ndarray) -> np.ndarray:
    """(m,) bool: every reference point of the tool inside the cell box at each pose q (m, n) rad."""
    q = np.atleast_2d(q)
    if cell.box_min is None:
        return np.ones(len(q), dtype=bool)
    kin = Kinematics(cell.chain, [])
    r, o = kin.end_frames(q)
    ok = np.ones(len(q), dtype=bool)
    for p in cell.tool_points.values():
        x = o + r @ p
        ok &= np.all((x >= cell.box_min) & (x <= cell.box_max), axis=1)
    return ok


def random_poses(cell: Cell, m: int, rng: np.random.Generator, max_tries: int = 1000) -> np.ndarray:
    """m poses (rad) drawn uniformly within the joint limits, kept when every point is in the box."""
    lim = cell.chain.limits_array()
    lim = np.where(np.isfinite(lim), lim, np.array([-np.pi, np.pi]))
    out: list[np.ndarray] = []
    for _ in range(max_tries):
        cand = rng.uniform(lim[:, 0], lim[:, 1], size=(4 * m, cell.chain.dof))
        out.extend(cand[points_in_box(cell, cand)])
        if len(out) >= m:
            return np.array(out[:m])
    raise DesignError(f"cell {cell.name}: found only {len(out)} of {m} poses with every point in the box")
