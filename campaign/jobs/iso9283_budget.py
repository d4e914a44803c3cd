"""The uncertainty budget of a session's ISO 9283 figures (calib.uncertainty_budget) from what the session and the
model know: the model's station estimate and tool point with their 95 % intervals, the commanded orientation, the
tool file's reflector centring, the meteo record of the test's measurements."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.iso9283 import Figure
from trackcal.calib.model_file import Model
from trackcal.calib.uncertainty_budget import (
    CI95_TO_SIGMA,
    Budget,
    PoseSetting,
    ad_budget,
    ap_budget,
    pose_inputs,
    rp_budget,
    tracker_budget,
)
from trackcal.campaign.errors import InputError


def _ci(doc: dict, section: str, key: str, field: str) -> np.ndarray:
    """A model.json 95 % half-width vector, three non-negative numbers as the model's reader checked them
    (`calib.model_file.model_from_doc`); zeros when the model states none (a model written by hand)."""
    v = ((doc.get(section) or {}).get(key) or {}).get(field)
    return np.zeros(3) if v is None else np.asarray(v, dtype=float)


def centring_mm(tool_doc: dict | None) -> float | None:
    """The tool file's `reflector: {centring_um: X}` (the largest offset of the reflector's optical centre from its
    nest's, as its datasheet states it) in mm; None when the tool file states none."""
    ref = (tool_doc or {}).get("reflector")
    if not isinstance(ref, dict) or ref.get("centring_um") is None:
        return None
    v = ref["centring_um"]
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v) or v < 0:
        raise InputError(f"tool file reflector.centring_um: expected a non-negative number of micrometres, got {v!r}")
    return float(v) / 1000.0


def temperature_halfrange(temps: list[str] | None) -> float | None:
    """Half the range of the temperatures (degC) recorded at the test's measurements; None when none was."""
    v = np.array([float(t) for t in temps or []], dtype=float)
    v = v[np.isfinite(v)]
    return float(v.max() - v.min()) / 2.0 if len(v) else None


@dataclass(frozen=True)
class BudgetContext:
    """What every pose's budget of one test shares: the model, the test's station and point, the commanded
    orientations (5, 3, 3), the tracker's name, the reflector's centring (mm) and the temperature's half-range (K)."""

    model: Model
    station: str
    point: str
    rotations: np.ndarray
    tracker: str
    centring: float | None
    halfrange: float | None

    def setting(self, i: int, y: np.ndarray) -> PoseSetting:
        """Pose i's, with its measurements y (n, 3) in the station's frame."""
        doc = self.model.doc or {}
        su = (
            np.concatenate(
                [
                    _ci(doc, "stations", self.station, "ci95_translation_mm"),
                    np.radians(_ci(doc, "stations", self.station, "ci95_rotation_deg")),
                ]
            )
            * CI95_TO_SIGMA
        )
        pu = _ci(doc, "tool_points", self.point, "ci95_mm") * CI95_TO_SIGMA
        return PoseSetting(
            y,
            self.model.stations[self.station].rotation,
            su,
            self.rotations[i],
            np.asarray(self.model.points[self.point], float),
            pu,
            self.tracker,
            self.centring,
            self.halfrange,
        )


def pose_budgets(
    x: np.ndarray, covs: np.ndarray, offset: np.ndarray, rp: Figure, setting: PoseSetting
) -> dict[str, Budget]:
    """AP_P's and RP_l's budgets of one pose (x, covs: its attained positions in the base frame and their tracker
    covariances; rp: RP_l with its tracker-only U from calib.iso9283)."""
    return {
        "AP_P": ap_budget(offset, pose_inputs(x, covs, setting)),
        "RP_l": rp_budget(x, covs, rp.u95 / 2.0, setting.tracker),
    }


def ad_budget_of(ad: Figure, c1: np.ndarray, c2: np.ndarray, context: BudgetContext) -> Budget:
    """AD_P's budget (ad: with its tracker-only U from calib.iso9283), over the commanded distance |c1 - c2|."""
    return ad_budget(
        ad.value, ad.u95, float(np.linalg.norm(np.asarray(c1) - np.asarray(c2))), context.halfrange, context.tracker
    )


def other_budgets(rd: Figure | None, vap: dict[str, Figure], tracker: str) -> dict[str, Budget]:
    """The budgets of RD and of each pose's vAP_P: the tracker's line (their U, k = 2), the inputs that move both poses
    of a cycle (RD) or every approach of a pose (vAP_P) alike listed with none."""
    common = "moves both poses of a cycle (RD) or every approach of a pose (vAP_P) alike: cancels"
    out = {} if rd is None else {"RD": tracker_budget("RD", rd.value, rd.u95, tracker, common)}
    out.update(
        {f"vAP_P {name}": tracker_budget(f"vAP_P {name}", f.value, f.u95, tracker, common) for name, f in vap.items()}
    )
    return out
