"""The largest identifiable subset of a parameter set for given poses and reference points.

The irreducible set of `calib.model.params` assumes enough reference points per pose to see the end frame's
orientation (three non-collinear points, paper section 3). With fewer points some parameters can no
longer be told apart from the tool points or from each other: with one point, position only, the
orientation of the last link is invisible. This module finds, by the numerical rank of the
identification Jacobian (stations and points free, columns scaled to unit norm, as in
`calib.model.identifiability`), the largest subset that is identifiable, preferring parameters in the given
order: a parameter is kept when its column raises the rank of [stations, points, kept parameters].
Every maximal independent set of columns has the same size, so this greedy choice is the largest.
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.identifiability import identification_jacobian
from trackcal.calib.model.params import Param


class SubsetError(CalibError):
    """Poses and points too few to place the station and the points: no subset of parameters is identifiable."""


def _scaled(j: np.ndarray) -> np.ndarray:
    s = np.linalg.norm(j, axis=0)
    s[s == 0] = 1.0
    return j / s


def _rank(j: np.ndarray, rtol: float) -> tuple[int, np.ndarray, np.ndarray]:
    _, sv, vt = np.linalg.svd(_scaled(j), full_matrices=False)
    return int(np.sum(sv > rtol * sv[0])), sv, vt


def identifiable_subset(
    chain: Chain,
    params: list[Param],
    q_rad: np.ndarray,
    tool_points: dict[str, np.ndarray] | np.ndarray,
    rtol: float = 1e-8,
) -> tuple[list[Param], list[tuple[Param, str]]]:
    """(kept, dropped with reason): the largest identifiable subset of `params`, in their order.

    q_rad (m, n) poses; tool_points: id -> point in the last joint frame (mm), or a (P, 3) array. One
    station, free (6 dof); every reference point free (3 dof). A parameter whose column is (numerically,
    relative singular value below `rtol`) a combination of the station, point and kept columns is dropped;
    the reason names the unknowns it cannot be separated from.
    """
    if isinstance(tool_points, dict):
        point_ids = list(tool_points)
        tool = np.array([np.asarray(tool_points[p], dtype=float) for p in point_ids])
    else:
        tool = np.atleast_2d(np.asarray(tool_points, dtype=float))
        point_ids = [f"P{i + 1}" for i in range(len(tool))]
    q = np.atleast_2d(np.asarray(q_rad, dtype=float))
    params = list(params)
    jm = identification_jacobian(chain, params, q, tool)
    k = len(params)
    nuis = jm[:, k:]
    nuis_names = [f"station {c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")]
    nuis_names += [f"point {p} {c}" for p in point_ids for c in "xyz"]
    base_rank, _, _ = _rank(nuis, rtol)
    if base_rank < nuis.shape[1]:
        raise SubsetError(
            f"{len(q)} pose(s) with {len(tool)} point(s) cannot even place the station and the points; add poses"
        )
    kept: list[int] = []
    dropped: list[tuple[Param, str]] = []
    for i, p in enumerate(params):
        cols = np.concatenate([nuis, jm[:, kept], jm[:, [i]]], axis=1)
        rank, _, vt = _rank(cols, rtol)
        if rank == cols.shape[1]:
            kept.append(i)
            continue
        null = vt[-1]  # combination of scaled columns that vanishes: p moves like these unknowns
        names = nuis_names + [params[c].name for c in kept]
        weights = np.abs(null[:-1])
        partners = [names[c] for c in np.argsort(weights)[::-1] if weights[c] > 0.1 * np.abs(null[-1])][:4]
        dropped.append(
            (
                p,
                "not separable from "
                + (", ".join(partners) if partners else "the other unknowns")
                + f" with {len(tool)} reference point(s) per pose",
            )
        )
    return [params[i] for i in kept], dropped
