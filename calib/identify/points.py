"""Where the reference points sit on the flange, from the measurements alone: a starting point for identification
when no tool file says where the nests are.

A measured point is  x = R_s (R_f(q) p + o_f(q)) + t_s  with the station (R_s, t_s) and the point p in the last joint
frame unknown. It is linear in (p, t_s) once R_s is known, and R_s follows from a rigid (Kabsch) fit once p is known;
alternating the two is a block-coordinate descent of the same least-squares cost, so the cost never rises. The first
station fit uses the flange origins (p = 0): the nests are a few centimetres from the flange while the poses span
a metre, so that fit is already close. The nominal chain is used throughout; identification then refines everything.
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.rigid import RigidError, kabsch

# Alternations: each costs two small least-squares solves; the fit settles to ~1e-9 mm in a handful on the tests'
# chains (the rotation error after the first fit is of order nest offset / workspace size, and shrinks by that
# ratio per sweep).
MAX_SWEEPS = 50
SETTLED_MM = 1e-9


class PointsError(CalibError):
    """Reference points that the table cannot place."""


def _station_fits(
    x_model: np.ndarray, xyz: np.ndarray, st_idx: np.ndarray, station_ids: list[str], source: str
) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for s, sid in enumerate(station_ids):
        rows = np.flatnonzero(st_idx == s)
        try:
            out.append(kabsch(x_model[rows], xyz[rows]))
        except RigidError as exc:
            raise PointsError(f"{source}: station {sid!r}: {exc}") from None
    return out


def points_from_table(chain: Chain, table: MeasurementTable) -> dict[str, np.ndarray]:
    """Every reference point of the table, in the last joint frame (mm), fitted with the stations on the nominal chain:
    a start for identification, not a result."""
    if table.xyz is None:
        raise PointsError(f"{table.source}: the table has no measured positions to place its points with")
    r_f, o_f = Kinematics(chain, []).end_frames(np.radians(table.q_deg))
    point_ids = sorted(set(table.point))
    station_ids = sorted(set(table.station))
    pt_idx = np.array([point_ids.index(p) for p in table.point])
    st_idx = np.array([station_ids.index(s) for s in table.station])
    n_pts, n_st, n = len(point_ids), len(station_ids), len(table)
    if 3 * n < 3 * n_pts + 6 * n_st:
        raise PointsError(f"{table.source}: {n} measurements cannot place {n_pts} point(s) and {n_st} station(s)")
    p = np.zeros((n_pts, 3))
    for _ in range(MAX_SWEEPS):
        x_model = o_f + np.einsum("nij,nj->ni", r_f, p[pt_idx])
        rot = np.array([r for r, _ in _station_fits(x_model, table.xyz, st_idx, station_ids, table.source)])
        # (p, t_s) linear: R_s R_f p + t_s = x - R_s o_f, one 3-row block per measurement
        a = np.zeros((n, 3, 3 * n_pts + 3 * n_st))
        rs_rf = np.einsum("nij,njk->nik", rot[st_idx], r_f)
        every = np.arange(n)
        for k in range(3):
            a[every, :, 3 * pt_idx + k] = rs_rf[:, :, k]
            a[every, k, 3 * n_pts + 3 * st_idx + k] = 1.0
        a = a.reshape(3 * n, -1)
        b = (table.xyz - np.einsum("nij,nj->ni", rot[st_idx], o_f)).ravel()
        sol, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
        if rank < a.shape[1]:
            raise PointsError(
                f"{table.source}: the poses do not turn the flange enough to place the reference "
                "points: give a tool file with their nominal positions"
            )
        step = float(np.max(np.abs(sol[: 3 * n_pts].reshape(n_pts, 3) - p)))
        p = sol[: 3 * n_pts].reshape(n_pts, 3)
        if step < SETTLED_MM:
            break
    return {pid: p[i] for i, pid in enumerate(point_ids)}
