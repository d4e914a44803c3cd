"""How far the extended model's TCP at the cell's test pose is from the geometric one's, and whether this campaign
determines that figure at all.

The TCP and its uncertainty are those of calib.tcp_figure (the reference points' centroid as each model places it,
in the frame of the table's first station; each model's own covariance of the robot parameters, that station and
the points, propagated to the centroid), each at the noise the extended model leaves (its variance factor: the
geometric model's own one also holds the misfit the cause explains, which is what the difference measures, not
noise). A plan optimised for a few parameters leaves the
others of an 18-parameter fit barely determined: the geometric model then spreads the cause's systematic error
over them, and the two models can differ at the test pose by far more than the cause's own size (on the twin, a
0.05 mm backlash on the README's 6-configuration plan: 1.3 mm, the geometric model 1.3-1.5 mm from the truth there,
the extended one 0.2 mm). The difference is determined when it exceeds twice the combined 1-sigma uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.identify.solver import Identification
from trackcal.calib.model.cell import Cell
from trackcal.calib.model_file import model_from_doc, predict_table
from trackcal.calib.tcp_figure import identified_tcp, tcp_rows, tcp_sigma

# a difference is determined when it exceeds this many combined 1-sigma (3-D) uncertainties: about the 95 %
# one-sided bound of the length of a difference that is noise alone
DETERMINED_SIGMAS = 2.0


class NotDerived:
    """The default of a `tcp` argument the caller did not derive (tcp_difference is then called once, there)."""


NOT_DERIVED = NotDerived()


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


def predicted_tcp(cell: Cell, model_doc: dict, station: str) -> np.ndarray:
    """A model file's TCP (centroid of its reference points) at the test pose in `station`'s frame: `trackcal
    predict` of one row per point."""
    model = model_from_doc(model_doc)
    return predict_table(model, tcp_rows(cell.test_pose, sorted(model.points), station)).xyz.mean(axis=0)


def tcp_difference(cell: Cell, geometric: Identification, extended: Identification | None) -> TcpDifference | None:
    """The two models' TCPs at the test pose, in the frame of the table's first station, and their uncertainty
    (None without a test pose or an extended model)."""
    if cell.test_pose is None or extended is None:
        return None
    station = geometric.station_ids[0]
    q0 = cell.test_pose
    geo, ext = identified_tcp(geometric, q0, station), identified_tcp(extended, q0, station)
    noise = extended.variance_factor
    return TcpDifference(
        station,
        geo,
        ext,
        float(np.linalg.norm(ext - geo)),
        tcp_sigma(geometric, q0, station, noise),
        tcp_sigma(extended, q0, station),
    )


def tcp_doc(tcp: TcpDifference) -> dict:
    """verdict.json's test_pose: the difference, its uncertainty and whether this campaign determines it."""
    return {
        "tcp_difference_mm": tcp.difference_mm,
        "sigma_mm": tcp.sigma_mm,
        "determined": tcp.determined,
        "sigma_geometric_mm": tcp.sigma_geometric_mm,
        "sigma_extended_mm": tcp.sigma_extended_mm,
        "station": tcp.station,
        "geometric_tcp_mm": tcp.geometric_mm.tolist(),
        "extended_tcp_mm": tcp.extended_mm.tolist(),
        "note": "how far the geometric model's TCP (the centroid of its reference points) at the test pose is from "
        f"the extended model's, in station {tcp.station}'s frame; determined when over {DETERMINED_SIGMAS:.0f} "
        "times its 1-sigma 3-D uncertainty (sigma_mm, from the two models' covariances at the noise the "
        "extended model leaves)",
    }
