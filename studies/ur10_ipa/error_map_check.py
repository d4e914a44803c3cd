"""The joint error map on the real UR10 data: fitted on B and on D, B's model on D, B's random held-out poses.

The chosen model is the geometric one plus gravity compliance (unpenalised) plus the joint error map
(`calib.diagnose.joint_map_fit.fit_error_map`: order and ridge by cross-validation by pose on the fitted series only).
B -> D: the model fitted on all of B predicts D with only D's station re-estimated. B held out: a random fifth
of B's poses, the order and ridge chosen on the other four fifths (the nominal, geometric and map models fitted
on those four fifths are kept, for the orientation check). Agreement: where both series measured a
joint (within 1 deg of a measured angle of each), the correlation of the two fitted curves.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from trackcal.calib.diagnose.extensions import build_extension, rebuild
from trackcal.calib.diagnose.joint_map import outside_arcs
from trackcal.calib.diagnose.joint_map_fit import ErrorMapFit, fit_error_map
from trackcal.calib.identify.solver import Identification, identify, predict_points
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.params import Param

STATION_ONLY = ("robot", "points")


@dataclass
class MapCheck:
    fit_b: ErrorMapFit  # geometry + gravity compliance + map on all of B
    fit_d: ErrorMapFit  # the same on D alone
    after_d: Identification  # fit_b's model on D, D's station alone re-estimated
    compliance_d: Identification  # geometry + compliance fitted on B (no map) on D, the same way
    fit_seconds: float  # wall time of fit_b: one map fit with its order and ridge search
    holdout_b: dict = field(default_factory=dict)  # random fifth of B's poses held out
    agreement: list[dict] = field(default_factory=list)  # per joint both series map
    holdout_tables: tuple[MeasurementTable, MeasurementTable] | None = None  # (training four fifths, held fifth)
    holdout_fits: dict[str, Identification] = field(default_factory=dict)  # nominal, geometric, map on the training


def on_other_series(chain: Chain, fit: Identification, table: MeasurementTable) -> Identification:
    """`fit`'s robot model, tool points and extension on another table: its station alone re-estimated."""
    ext = None if fit.extension is None else rebuild(fit.extension, chain, table)
    return identify(chain, table, fit.points, fit.params, dev0=fit.dev, extension=ext, ext0=fit.ext, fixed=STATION_ONLY)


def curve_agreement(
    fit_b: ErrorMapFit,
    fit_d: ErrorMapFit,
    b: MeasurementTable,
    d: MeasurementTable,
    step_deg: float = 0.25,
    near_deg: float = 1.0,
) -> list[dict]:
    """Per joint both maps cover: the angles both series measured (within `near_deg`) and the correlation of
    the two fitted curves there (None below 8 grid angles)."""
    grid = np.radians(np.arange(0.0, 360.0, step_deg))
    out = []
    for j in sorted(set(fit_b.arcs) & set(fit_d.arcs)):

        def measured(t: MeasurementTable, j: int = j) -> np.ndarray:
            qj = np.radians(t.q_deg[:, j])
            return np.abs(np.angle(np.exp(1j * (grid[:, None] - qj[None])))).min(axis=1) < np.radians(near_deg)

        both = measured(b) & measured(d)
        row = {"joint": j + 1, "overlap_deg": float(both.sum() * step_deg), "correlation": None}
        if both.sum() >= 8:
            vb, _ = fit_b.curve(j, grid[both])
            vd, _ = fit_d.curve(j, grid[both])
            row["correlation"] = float(np.corrcoef(vb, vd)[0, 1])
        out.append(row)
    return out


def _rms3(res: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(res**2, axis=1))))


def error_map_check(
    chain: Chain,
    b: MeasurementTable,
    d: MeasurementTable,
    tool: dict[str, np.ndarray],
    params_b: list[Param],
    params_d: list[Param],
    seed: int = 1,
) -> MapCheck:
    t0 = time.perf_counter()
    fit_b = fit_error_map(chain, b, tool, params_b, base=build_extension("joint_compliance", chain, b))
    seconds = time.perf_counter() - t0
    comp_b = identify(chain, b, tool, params_b, extension=build_extension("joint_compliance", chain, b))
    fit_d = fit_error_map(chain, d, tool, params_d, base=build_extension("joint_compliance", chain, d))
    poses = np.array(sorted(set(b.pose)))
    held = set(np.random.default_rng(seed).choice(poses, len(poses) // 5, replace=False))
    test = np.array([p in held for p in b.pose])
    train, hold = b.subset(np.flatnonzero(~test)), b.subset(np.flatnonzero(test))
    nominal = identify(chain, train, tool, [], fixed=STATION_ONLY)
    geo = identify(chain, train, tool, params_b)
    fit = fit_error_map(chain, train, tool, params_b, base=build_extension("joint_compliance", chain, train))

    def held_error(res: Identification) -> float:
        ext = None if res.extension is None else rebuild(res.extension, chain, hold)
        return _rms3(
            hold.xyz - predict_points(chain, res.params, res.dev, res.stations, res.points, hold, ext, res.ext)
        )

    holdout = {
        "poses": len(held),
        "geometric_mm": held_error(geo),
        "map_mm": held_error(fit.identification),
        "outside_rows": int(outside_arcs(np.radians(hold.q_deg), fit.arcs).any(axis=1).sum()),
        "order": max(fit.orders.values()),
        "tau_deg": float(np.degrees(fit.tau_rad)),
    }
    return MapCheck(
        fit_b,
        fit_d,
        on_other_series(chain, fit_b.identification, d),
        on_other_series(chain, comp_b, d),
        seconds,
        holdout,
        curve_agreement(fit_b, fit_d, b, d),
        (train, hold),
        {"nominal": nominal, "geometric": geo, "map": fit.identification},
    )
