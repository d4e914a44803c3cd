"""The one figure at the cell's test pose: where an identification puts the TCP there, and how well.

The TCP is the reference points' centroid as the model places it (its own fitted points, not the tool drawing's:
with stations and points free, a shift of the points along a link trades against that link's lengths, so a TCP
fixed in the flange frame would compare two different physical points), in the frame of the table's first station:
what `trackcal predict` gives for rows at the test pose, one per reference point, the extension at its neutral
context (no approach history, the campaign's start). Its standard uncertainty comes from the identification's full
covariance: the robot parameters, that station's 6-dof transform and the points, propagated to the centroid (first
order); the extension's parameters, whose effect at the neutral context is small or nil, are left out. It is the
1-sigma 3-D figure (the square root of the trace of the centroid's covariance): the RMS distance at which the model
puts the TCP from where the robot really has it, if the model describes the robot. identify prints it and writes it
in model.json (`test_pose`), the report and `history` show it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from trackcal.calib.diagnose.extensions import rebuild
from trackcal.calib.identify.solver import Identification, model_points
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.rigid import skew

NOTE = (
    "the TCP (centroid of the model's reference points) at the cell's test pose, in station {station}'s frame, "
    "and its standard uncertainty sigma_mm (1-sigma 3-D: sqrt of the trace of its covariance) from the model's "
    "full covariance (robot parameters, the station, the points); correction_mm: how far the calibration moves "
    "it from where the nominal robot puts it"
)


@dataclass(frozen=True)
class TcpFigure:
    station: str  # the frame tcp_mm is in: the table's first station
    joints_deg: np.ndarray  # the test pose
    tcp_mm: np.ndarray  # (3,) the model's TCP, station frame
    cov_mm2: np.ndarray  # (3, 3) its covariance
    correction_mm: float  # |TCP(model) - TCP(nominal robot, same station and points)|

    @property
    def sigma_mm(self) -> float:
        """1-sigma 3-D uncertainty: sqrt of the trace of the covariance."""
        return float(np.sqrt(max(np.trace(self.cov_mm2), 0.0)))

    def to_doc(self) -> dict:
        """model.json's and identify's summary's `test_pose`."""
        return {
            "joints_deg": self.joints_deg.tolist(),
            "station": self.station,
            "tcp_mm": self.tcp_mm.tolist(),
            "sigma_mm": self.sigma_mm,
            "sigma_xyz_mm": np.sqrt(np.maximum(np.diag(self.cov_mm2), 0.0)).tolist(),
            "correction_mm": self.correction_mm,
            "note": NOTE.format(station=self.station),
        }


def tcp_rows(q0: np.ndarray, points: list[str], station: str) -> MeasurementTable:
    """One row per reference point at the test pose q0 (rad), seen from `station`, at the campaign's start."""
    n = len(points)
    q = np.repeat(np.degrees(np.asarray(q0, dtype=float))[None], n, axis=0)
    return MeasurementTable(
        np.arange(1, n + 1), np.zeros(n), ["test"] * n, [station] * n, list(points), q, None, source="test pose"
    )


def _centroid_base(res: Identification, q0: np.ndarray) -> Callable[[np.ndarray, dict[str, np.ndarray]], np.ndarray]:
    """centroid(dev, points): the identification's reference points' centroid at the test pose q0 (rad), robot base
    frame, extension at its neutral context, for deviations `dev` and reference points `points` (the rows, the
    extension's features and the kinematics made once: `tcp_covariance` asks for twenty of them)."""
    rows = tcp_rows(q0, res.point_ids, res.station_ids[0])
    ext = rebuild(res.extension, res.chain, rows) if res.extension is not None and len(res.ext) else None
    kin, q = Kinematics(res.chain, res.params), np.radians(rows.q_deg)

    def centroid(dev: np.ndarray, points: dict[str, np.ndarray]) -> np.ndarray:
        tool = np.array([points[p] for p in res.point_ids])
        return model_points(kin, q, tool, dev, ext, res.ext).mean(axis=0)

    return centroid


def identified_tcp(res: Identification, q0: np.ndarray, station: str) -> np.ndarray:
    """The identification's TCP at the test pose q0 (rad) in `station`'s frame (what `trackcal predict` gives of its
    model file, averaged over the points)."""
    return res.stations[station].apply(_centroid_base(res, q0)(res.dev, res.points))


def tcp_covariance(
    res: Identification, q0: np.ndarray, station: str, variance_factor: float | None = None, step: float = 1e-6
) -> np.ndarray:
    """(3, 3) covariance of the identification's TCP at the test pose q0 (rad) in `station`'s frame, from its
    covariance of the robot parameters, the station and the points. Numerical first-order propagation: forward
    differences of `step` (mm, rad) on the centroid, the station's perturbation as the solver defines it
    (x' = Exp(w) x + v in the station frame, calib.identify.solver). `variance_factor`: the noise level to scale the
    covariance to (default the identification's own)."""
    k, c_st = len(res.params), len(res.params) + len(res.ext)
    c_pt = c_st + 6 * len(res.station_ids)
    rot = res.stations[station].rotation
    centroid = _centroid_base(res, q0)
    base = centroid(res.dev, res.points)
    cols, idx = [], []
    for i in range(k):
        dev = res.dev.copy()
        dev[i] += step
        cols.append(rot @ (centroid(dev, res.points) - base) / step)
        idx.append(i)
    for n, pid in enumerate(res.point_ids):
        for a in range(3):
            pts = dict(res.points)
            pts[pid] = pts[pid] + step * np.eye(3)[a]
            cols.append(rot @ (centroid(res.dev, pts) - base) / step)
            idx.append(c_pt + 3 * n + a)
    y = res.stations[station].apply(base)
    s0 = c_st + 6 * res.station_ids.index(station)
    jac = np.hstack([np.array(cols).reshape(-1, 3).T, np.eye(3), -skew(y)])
    idx += list(range(s0, s0 + 6))
    cov = res.cov[np.ix_(idx, idx)]
    if variance_factor is not None and res.variance_factor > 0:
        cov = cov * (variance_factor / res.variance_factor)
    return jac @ cov @ jac.T


def tcp_sigma(res: Identification, q0: np.ndarray, station: str, variance_factor: float | None = None) -> float:
    """1-sigma 3-D uncertainty (sqrt of the trace of `tcp_covariance`)."""
    return float(np.sqrt(max(np.trace(tcp_covariance(res, q0, station, variance_factor)), 0.0)))


def figure_at_test_pose(res: Identification, q0: np.ndarray) -> TcpFigure:
    """The figure at the test pose q0 (rad), in the frame of the table's first station."""
    station = res.station_ids[0]
    centroid = _centroid_base(res, q0)
    model, nominal = centroid(res.dev, res.points), centroid(np.zeros_like(res.dev), res.points)
    return TcpFigure(
        station,
        np.degrees(np.asarray(q0, dtype=float)),
        res.stations[station].apply(model),
        tcp_covariance(res, q0, station),
        float(np.linalg.norm(model - nominal)),
    )
