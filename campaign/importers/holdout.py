"""A seeded train/test split of a measurement table by pose: every row of a pose (each station, each point) goes to
the same side, so no test pose was seen in training (a pose measured in both would make the test judge the fit's
memory of that pose, not its prediction)."""

from __future__ import annotations

import numpy as np

from trackcal.calib.io.table import MeasurementTable, TableError


class HoldoutError(TableError):
    """A split that cannot be made; the message says why."""


def holdout_split(table: MeasurementTable, fraction: float, seed: int) -> tuple[MeasurementTable, MeasurementTable]:
    """(train, test): round(fraction x poses) poses, drawn by numpy's default generator seeded with `seed`, are the
    test; at least one pose on each side. Rows keep their order and seq."""
    if not 0.0 < fraction < 1.0:  # NaN fails it too
        raise HoldoutError(f"--holdout: a fraction of the poses strictly between 0 and 1, got {fraction}")
    poses = list(dict.fromkeys(table.pose))
    if len(poses) < 2:
        raise HoldoutError(f"{table.source}: {len(poses)} pose, a split needs at least 2")
    n_test = min(max(round(fraction * len(poses)), 1), len(poses) - 1)
    test = {poses[i] for i in np.random.default_rng(seed).permutation(len(poses))[:n_test]}
    is_test = np.array([p in test for p in table.pose])
    return table.subset(np.flatnonzero(~is_test)), table.subset(np.flatnonzero(is_test))
