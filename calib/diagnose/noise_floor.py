"""The noise floor of a campaign: the tracker's own scatter, against which residuals are judged.

Repeated measurements set the floor only when they are comparable for every cause: the same pose,
station and point, the same approach direction of every joint (a backlash is then the same in each),
within CLOSE_IN_TIME of the campaign's span (a drift has not moved them apart); otherwise the tracker
noise model. A floor from repeats is itself estimated with finite degrees of freedom, so residuals are
compared with it by an F test; with the noise model, by chi-square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc, fdtrc  # F and chi2 tails (scipy.stats: ~1 s to import)

from trackcal.calib.diagnose.extensions import approach_signs
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Identification
from trackcal.calib.io.table import MeasurementTable

CLOSE_IN_TIME = 0.1  # repeats closer than this fraction of the campaign's span are comparable
MIN_FLOOR_DOF = 10  # repeats needed before they replace the tracker noise model


@dataclass
class Floor:
    sigma_mm: float  # RMS of one coordinate from the tracker alone
    source: str
    dof: int | None  # degrees of freedom of a floor from repeats; None for the noise model


def comparable_repeats(table: MeasurementTable) -> list[np.ndarray]:
    """Groups of rows (>= 2) measuring the same pose, station and point with the same approach direction
    of every joint, each within CLOSE_IN_TIME of the campaign's span: what differs between them is the
    tracker alone, whichever cause is present."""
    signs = approach_signs(np.radians(table.q_deg))
    span = float(np.ptp(table.t_s)) if len(table) else 0.0
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(zip(table.pose, table.station, table.point, map(tuple, signs), strict=True)):
        groups.setdefault(key, []).append(i)
    out = []
    for rows in groups.values():
        rows = sorted(rows, key=lambda r: table.t_s[r])
        cluster = [rows[0]]
        for r in rows[1:]:
            if table.t_s[r] - table.t_s[cluster[0]] <= CLOSE_IN_TIME * span:
                cluster.append(r)
                continue
            if len(cluster) > 1:
                out.append(np.array(cluster))
            cluster = [r]
        if len(cluster) > 1:
            out.append(np.array(cluster))
    return out


def noise_floor(table: MeasurementTable, noise: TrackerNoise | None, tracker: TrackerNoise | None = None) -> Floor:
    """The tracker's own scatter: pooled from comparable repeats when they give MIN_FLOOR_DOF degrees of
    freedom, else the tracker noise model: the weighting's (`noise`), else `tracker` (the cell's instrument under
    i.i.d. weighting), else the AT901's."""
    reps = comparable_repeats(table)
    n_dof = sum(len(g) - 1 for g in reps)
    if n_dof >= MIN_FLOOR_DOF:
        ss = sum(float(np.sum((table.xyz[g] - table.xyz[g].mean(axis=0)) ** 2)) for g in reps)
        return Floor(float(np.sqrt(ss / (3 * n_dof))), f"comparable repeats ({3 * n_dof} degrees of freedom)",
                     3 * n_dof)  # fmt: skip
    model = noise or tracker or TrackerNoise()
    sigma = float(np.sqrt(np.mean(np.trace(model.covariance(table.xyz), axis1=1, axis2=2) / 3)))
    why = "no repeats" if not reps else f"only {3 * n_dof} degrees of freedom of comparable repeats"
    return Floor(sigma, f"{model.name} noise model; {why}", None)


def floor_test(geo: Identification, floor: Floor) -> float:
    """p-value that the geometric residuals are at the floor: an F test against a floor from repeats
    (itself estimated with floor.dof degrees of freedom), chi-square against the noise model."""
    if floor.dof is None and geo.noise is not None:
        return float(chdtrc(geo.dof, geo.variance_factor * geo.dof))
    ratio = float(np.sum(geo.residuals**2)) / geo.dof / floor.sigma_mm**2
    if floor.dof is None:
        return float(chdtrc(geo.dof, ratio * geo.dof))
    return float(fdtrc(geo.dof, floor.dof, ratio))
