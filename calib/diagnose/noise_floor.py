"""The noise floor of a campaign: the tracker's own scatter, against which residuals are judged.

Repeated measurements set the floor only when they are comparable for every cause: the same pose,
station and point, the same approach direction of every joint (a backlash is then the same in each),
within CLOSE_IN_TIME of the campaign's span (a drift has not moved them apart); otherwise the tracker
noise model. A floor from repeats is itself estimated with finite degrees of freedom, so residuals are
compared with it by an F test; with the noise model, by chi-square (`calib.diagnose.diagnosis.floor_test`:
diagnose's, which identify does not need).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.diagnose.extensions import approach_signs
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import unique_rows
from trackcal.calib.io.table import MeasurementTable, label_codes

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
    tracker alone, whichever cause is present. Listed by key in the order of its first row, then in time
    order; rows in time order (ties in row order).

    Whole arrays, no loop over rows (issue 41: the loop was a quarter of `identify` at 100k rows). Within a key,
    in time order, a cluster holds the rows within CLOSE_IN_TIME * span of its first row, and the next row starts
    the next cluster: each pass of the loop below settles one cluster of every key, and a key has at most about
    1 / CLOSE_IN_TIME + 1 of them (each starts more than CLOSE_IN_TIME * span after the one before)."""
    n = len(table)
    if n < 2:
        return []
    (pose, _), (station, sids), (point, pids) = (label_codes(c) for c in (table.pose, table.station, table.point))
    measures = (pose * len(sids) + station) * len(pids) + point  # one code per (pose, station, point)
    ranked = np.sort(measures)
    if (ranked[1:] != ranked[:-1]).all():  # nothing measured twice: no repeats, whatever the approach directions
        return []
    t = np.asarray(table.t_s, dtype=float)
    signs = approach_signs(np.radians(table.q_deg))
    key = np.column_stack([measures, signs.astype(np.int8)])
    first, of_row = unique_rows(key)
    rank = np.empty(len(first), dtype=int)
    rank[np.argsort(first)] = np.arange(len(first))  # keys in the order of their first row
    g = rank[of_row]
    order = np.lexsort((t, g))  # by key, then time; stable: ties in row order
    gs, ts = g[order], t[order]
    limit = CLOSE_IN_TIME * float(np.ptp(t))
    pos = np.arange(n)
    anchor = np.maximum.accumulate(np.where(np.r_[True, gs[1:] != gs[:-1]], pos, 0))  # each key's first row
    cluster = np.empty(n, dtype=int)  # the first row of each row's cluster (positions in `order`)
    todo = pos
    while todo.size:
        inside = (ts[todo] - ts[anchor[todo]] <= limit) | (todo == anchor[todo])
        cluster[todo[inside]] = anchor[todo[inside]]
        todo = todo[~inside]  # of each key, a suffix in time order: its first row anchors the next cluster
        if todo.size:
            new_key = np.r_[True, gs[todo][1:] != gs[todo][:-1]]
            anchor[todo] = todo[np.maximum.accumulate(np.where(new_key, np.arange(todo.size), 0))]
    starts = np.flatnonzero(np.r_[True, cluster[1:] != cluster[:-1]])
    ends = np.r_[starts[1:], n]
    kept = ends - starts > 1
    return [order[a:b] for a, b in zip(starts[kept], ends[kept], strict=True)]


def noise_floor(table: MeasurementTable, noise: TrackerNoise | None, tracker: TrackerNoise | None = None) -> Floor:
    """The tracker's own scatter: pooled from comparable repeats when they give MIN_FLOOR_DOF degrees of
    freedom, else the tracker noise model: the weighting's (`noise`), else `tracker` (the cell's instrument under
    i.i.d. weighting), else the AT901's."""
    reps = comparable_repeats(table)
    n_dof = sum(len(g) - 1 for g in reps)
    if n_dof >= MIN_FLOOR_DOF:
        rows, sizes = np.concatenate(reps), np.array([len(g) for g in reps])
        xyz = table.xyz[rows]
        means = np.add.reduceat(xyz, np.r_[0, np.cumsum(sizes)[:-1]], axis=0) / sizes[:, None]
        ss = float(np.sum((xyz - np.repeat(means, sizes, axis=0)) ** 2))
        return Floor(
            float(np.sqrt(ss / (3 * n_dof))), f"comparable repeats ({3 * n_dof} degrees of freedom)", 3 * n_dof
        )
    model = noise or tracker or TrackerNoise()
    sigma = float(np.sqrt(np.mean(np.trace(model.covariance(table.xyz), axis1=1, axis2=2) / 3)))
    why = "no repeats" if not reps else f"only {3 * n_dof} degrees of freedom of comparable repeats"
    return Floor(sigma, f"{model.name} noise model; {why}", None)
