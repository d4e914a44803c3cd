"""How far the extended model's TCP at the cell's test pose is from the geometric one's, and whether this campaign
determines that figure at all.

The TCP is the reference points' centroid as each model places it (its own fitted points, not the tool drawing's:
with stations and points free, a shift of the points along a link trades against that link's lengths, so a TCP
fixed in the flange frame would compare two different physical points), in the frame of the table's first
station: what `trackcal predict` gives for rows at the test pose, one per reference point, the extension at its
neutral context (no approach history, the campaign's start). Its uncertainty comes from each model's own
covariance (robot parameters, that station, the points), propagated to the centroid (first order), each at the
noise the extended model leaves (its variance factor: the geometric model's own one also holds the misfit the cause
explains, which is what the difference measures, not noise). A plan optimised for a few parameters leaves the
others of an 18-parameter fit barely determined: the geometric model then spreads the cause's systematic error
over them, and the two models can differ at the test pose by far more than the cause's own size (on the twin, a
0.05 mm backlash on the README's 6-configuration plan: 1.3 mm, the geometric model 1.3-1.5 mm from the truth there,
the extended one 0.2 mm). The difference is determined when it exceeds twice the combined 1-sigma uncertainty.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from trackcal.calib.diagnose.extensions import rebuild
from trackcal.calib.identify.solver import Identification, model_points
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import Cell
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model_file import model_from_doc, predict_table

# a difference is determined when it exceeds this many combined 1-sigma (3-D) uncertainties: about the 95 %
# one-sided bound of the length of a difference that is noise alone
DETERMINED_SIGMAS = 2.0


@dataclass(frozen=True)
class TcpDifference:
    station: str  # the frame the positions are in
    geometric_mm: np.ndarray  # (3,) the geometric model's TCP (centroid of its points), station frame
    extended_mm: np.ndarray  # (3,) the extended model's
    difference_mm: float  # |extended - geometric|
    sigma_geometric_mm: float | None  # 1-sigma 3-D uncertainty of each prediction at the extended model's noise
    sigma_extended_mm: float | None

    @property
    def sigma_mm(self) -> float | None:
        """The combined 1-sigma 3-D uncertainty of the difference (the two taken as independent)."""
        if self.sigma_geometric_mm is None or self.sigma_extended_mm is None:
            return None
        return float(np.hypot(self.sigma_geometric_mm, self.sigma_extended_mm))

    @property
    def determined(self) -> bool:
        return self.sigma_mm is not None and self.difference_mm > DETERMINED_SIGMAS * self.sigma_mm


def tcp_rows(cell: Cell, points: list[str], station: str) -> MeasurementTable:
    """One row per reference point at the cell's test pose, seen from `station`, at the campaign's start."""
    n = len(points)
    q = np.repeat(np.degrees(cell.test_pose)[None], n, axis=0)
    return MeasurementTable(np.arange(1, n + 1), np.zeros(n), ["test"] * n, [station] * n, list(points), q, None,
                            source="test pose")  # fmt: skip


def predicted_tcp(cell: Cell, model_doc: dict, station: str) -> np.ndarray:
    """A model file's TCP (centroid of its reference points) at the test pose in `station`'s frame: `trackcal
    predict` of one row per point."""
    model = model_from_doc(model_doc)
    return predict_table(model, tcp_rows(cell, sorted(model.points), station)).xyz.mean(axis=0)


def _centroid_base(cell: Cell, res: Identification) -> Callable[[np.ndarray, dict[str, np.ndarray]], np.ndarray]:
    """centroid(dev, points): the identification's reference points' centroid at the test pose, robot base frame,
    extension at its neutral context, for deviations `dev` and reference points `points` (the rows, the extension's
    features and the kinematics made once: `tcp_sigma` asks for twenty of them)."""
    rows = tcp_rows(cell, res.point_ids, res.station_ids[0])
    ext = rebuild(res.extension, cell.chain, rows) if res.extension is not None and len(res.ext) else None
    kin, q = Kinematics(res.chain, res.params), np.radians(rows.q_deg)

    def centroid(dev: np.ndarray, points: dict[str, np.ndarray]) -> np.ndarray:
        tool = np.array([points[p] for p in res.point_ids])
        return model_points(kin, q, tool, dev, ext, res.ext).mean(axis=0)

    return centroid


def identified_tcp(cell: Cell, res: Identification, station: str) -> np.ndarray:
    """The identification's TCP at the test pose in `station`'s frame (what `predicted_tcp` gives of its model
    file)."""
    return res.stations[station].apply(_centroid_base(cell, res)(res.dev, res.points))


def _skew(y: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -y[2], y[1]], [y[2], 0.0, -y[0]], [-y[1], y[0], 0.0]])


def tcp_sigma(cell: Cell, res: Identification, station: str, variance_factor: float | None = None,
              step: float = 1e-6) -> float:  # fmt: skip
    """1-sigma 3-D uncertainty (sqrt of the trace of the covariance) of the identification's TCP at the test pose in
    `station`'s frame, from its covariance of the robot parameters, the station and the points (the extension's
    parameters, whose effect at the neutral context is small or nil, are left out). Numerical first-order
    propagation: forward differences of `step` (mm, rad) on the centroid, the station's perturbation as the solver
    defines it (x' = Exp(w) x + v in the station frame, calib.identify.solver). `variance_factor`: the noise level
    to scale the covariance to (default the identification's own)."""
    k, c_st = len(res.params), len(res.params) + len(res.ext)
    c_pt = c_st + 6 * len(res.station_ids)
    rot = res.stations[station].rotation
    centroid = _centroid_base(cell, res)
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
    jac = np.hstack([np.array(cols).T, np.eye(3), -_skew(y)])
    idx += list(range(s0, s0 + 6))
    cov = res.cov[np.ix_(idx, idx)]
    if variance_factor is not None and res.variance_factor > 0:
        cov = cov * (variance_factor / res.variance_factor)
    return float(np.sqrt(max(np.trace(jac @ cov @ jac.T), 0.0)))


def tcp_difference(cell: Cell, geometric: Identification, extended: Identification | None) -> TcpDifference | None:
    """The two models' TCPs at the test pose, in the frame of the table's first station, and their uncertainty
    (None without a test pose or an extended model)."""
    if cell.test_pose is None or extended is None:
        return None
    station = geometric.station_ids[0]
    geo, ext = identified_tcp(cell, geometric, station), identified_tcp(cell, extended, station)
    noise = extended.variance_factor
    return TcpDifference(station, geo, ext, float(np.linalg.norm(ext - geo)),
                         tcp_sigma(cell, geometric, station, noise), tcp_sigma(cell, extended, station))  # fmt: skip


def tcp_doc(tcp: TcpDifference) -> dict:
    """verdict.json's test_pose: the difference, its uncertainty and whether this campaign determines it."""
    return {
        "tcp_difference_mm": tcp.difference_mm, "sigma_mm": tcp.sigma_mm, "determined": tcp.determined,
        "sigma_geometric_mm": tcp.sigma_geometric_mm, "sigma_extended_mm": tcp.sigma_extended_mm,
        "station": tcp.station, "geometric_tcp_mm": tcp.geometric_mm.tolist(),
        "extended_tcp_mm": tcp.extended_mm.tolist(),
        "note": "how far the geometric model's TCP (the centroid of its reference points) at the test pose is from "
                f"the extended model's, in station {tcp.station}'s frame; determined when over {DETERMINED_SIGMAS:.0f} "
                "times its 1-sigma 3-D uncertainty (sigma_mm, from the two models' covariances at the noise the "
                "extended model leaves)",
    }  # fmt: skip
