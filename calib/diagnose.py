"""Model discovery: what the geometric model gets wrong, which physical cause explains it, and the gain.

For a measurement table the geometric model is fitted first; its residuals are compared with the noise
floor (the tracker noise model, or the scatter of repeated measurements when the campaign has them).
Then every candidate cause (`calib.extensions`, plus `station_shift` as a change point in a station's
time series) is fitted jointly with the geometric parameters and judged by evidence that survives
over-fitting:

- a nested F test against the geometric model (whitened residuals), at alpha = 1e-3 / number of causes;
- the Bayesian information criterion (it must improve);
- cross-validation by pose: K folds of whole poses held out, predicted from a fit on the others; the
  candidate must predict held-out poses better than the geometric model.

The winner is the significant candidate with the lowest held-out RMS; `none` when nothing is significant
and the geometric residuals sit at the noise floor; `unexplained` when structure remains (residuals
above the floor) that no candidate explains, or the best one removes less than half of the excess.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.special import chdtrc, fdtrc  # survival functions of F and chi2 (scipy.stats: ~1 s to import)

from .chain import Chain
from .extensions import JOINT_CAUSES, Extension, build_extension
from .identify import Identification, IdentificationError, identify, predict_points
from .noise import TrackerNoise
from .params import Param
from .table import MeasurementTable

ALPHA = 1e-3
SHIFT_SUFFIX = "~shift"


@dataclass
class Candidate:
    cause: str
    n_params: int
    rss: float  # whitened residual sum of squares
    dof: int
    f_pvalue: float
    delta_bic: float
    holdout_rms_mm: float
    rms_mm: float
    detail: dict = field(default_factory=dict)
    significant: bool = False

    def score(self) -> float:
        return self.holdout_rms_mm


@dataclass
class Diagnosis:
    cause: str
    geometric: Identification
    extended: Identification | None
    candidates: list[Candidate]
    holdout_geometric_mm: float
    holdout_extended_mm: float
    noise_floor_mm: float
    floor_source: str
    variance_factor_pvalue: float
    extension: Extension | None
    table: MeasurementTable  # as identified (station_shift relabels rows)
    shift: dict | None = None


def rms(residuals: np.ndarray) -> float:
    return float(np.sqrt(np.mean(residuals**2)))


def noise_floor(table: MeasurementTable, noise: TrackerNoise | None) -> tuple[float, str]:
    """Expected RMS of one coordinate from the tracker alone: pooled scatter of repeated measurements of
    the same (pose, station, point) when the campaign has them, else the tracker noise model."""
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(zip(table.pose, table.station, table.point, strict=True)):
        groups.setdefault(key, []).append(i)
    reps = [g for g in groups.values() if len(g) > 1]
    n_dof = sum(len(g) - 1 for g in reps)
    if n_dof >= 10:
        ss = sum(float(np.sum((table.xyz[g] - table.xyz[g].mean(axis=0)) ** 2)) for g in reps)
        return float(np.sqrt(ss / (3 * n_dof))), f"repeated measurements ({n_dof} degrees of freedom)"
    model = noise or TrackerNoise()
    return float(np.sqrt(np.mean(np.trace(model.covariance(table.xyz), axis1=1, axis2=2) / 3))), "tracker noise model"


def relabel_shift(table: MeasurementTable, station: str, t_star: float) -> MeasurementTable:
    out = table.subset(np.arange(len(table)))
    out.station = [s + SHIFT_SUFFIX if (s == station and t > t_star) else s for s, t in zip(table.station, table.t_s,
                                                                                           strict=True)]  # fmt: skip
    return out


def _fit(chain, table, tool, params, noise, ext) -> Identification:
    return identify(chain, table, tool, params, noise=noise, extension=ext)


def _rss(res: Identification) -> float:
    return res.variance_factor * res.dof


def best_shift(chain, table, tool, params, noise, min_rows: int = 6, grid: int = 16):
    """Change point search: for each station, candidate times between its rows; the best by RSS."""
    best = None
    for sid in sorted(set(table.station)):
        times = np.sort(table.t_s[np.array(table.station) == sid])
        if len(times) < 2 * min_rows:
            continue
        cuts = times[min_rows - 1 : len(times) - min_rows]
        for t_star in np.unique(cuts[np.linspace(0, len(cuts) - 1, min(grid, len(cuts))).astype(int)]):
            relabelled = relabel_shift(table, sid, float(t_star))
            try:
                res = _fit(chain, relabelled, tool, params, noise, None)
            except IdentificationError:
                continue
            if best is None or _rss(res) < best[0]:
                best = (_rss(res), sid, float(t_star), res, relabelled)
    return best


class CauseFit(NamedTuple):
    """The geometric model fitted with one cause."""

    result: Identification
    extension: Extension | None
    table: MeasurementTable  # as fitted (station_shift relabels the rows after the change point)
    shift: dict | None  # station_shift: {"station", "after_t_s"}
    n_extra: int  # parameters the cause adds


def fit_cause(chain, table, tool, params, noise, cause: str) -> CauseFit | None:
    """Fit the geometric model extended by `cause`; None when the cause cannot be fitted to this table (e.g. too
    few rows for a change point)."""
    if cause == "none":
        return CauseFit(_fit(chain, table, tool, params, noise, None), None, table, None, 0)
    if cause == "station_shift":
        found = best_shift(chain, table, tool, params, noise)
        if found is None:
            return None
        _, sid, t_star, res, relabelled = found
        return CauseFit(res, None, relabelled, {"station": sid, "after_t_s": t_star}, 7)
    ext = build_extension(cause, chain, table)
    if ext.size == 0:
        return None
    return CauseFit(_fit(chain, table, tool, params, noise, ext), ext, table, None, ext.size)


def _holdout(chain, table, tool, params, noise, cause, folds, rng, full_ext) -> float:
    """RMS (mm, per coordinate) of held-out poses predicted from fits on the other poses."""
    poses = np.array(sorted(set(table.pose)))
    rng.shuffle(poses)
    groups = np.array_split(poses, min(folds, len(poses)))
    pose_arr = np.array(table.pose)
    errs = []
    for g in groups:
        test = np.isin(pose_arr, g)
        train_rows, test_rows = np.flatnonzero(~test), np.flatnonzero(test)
        train = table.subset(train_rows)
        ext = None if full_ext is None else full_ext.subset(train_rows)
        try:
            if cause == "station_shift":
                found = best_shift(chain, train, tool, params, noise)
                if found is None:
                    return float("inf")
                _, sid, t_star, res, _ = found
                held = relabel_shift(table, sid, t_star).subset(test_rows)
            else:
                res = _fit(chain, train, tool, params, noise, ext)
                held = table.subset(test_rows)
        except IdentificationError:
            return float("inf")
        pred = predict_with(res, held, None if full_ext is None else full_ext.subset(test_rows))
        if pred is None:
            return float("inf")
        errs.append(held.xyz - pred)
    return rms(np.concatenate(errs))


def predict_with(res: Identification, table: MeasurementTable, ext: Extension | None) -> np.ndarray | None:
    """Predicted positions of `table`'s rows with a fitted result (None if a station is unknown)."""
    if any(s not in res.stations for s in table.station):
        return None
    return predict_points(res.chain, res.params, res.dev, res.stations, res.points, table, ext, res.ext)


def diagnose(
    chain: Chain,
    table: MeasurementTable,
    tool_points: dict[str, np.ndarray],
    params: list[Param],
    noise: TrackerNoise | None = None,
    folds: int = 5,
    seed: int = 0,
    causes: tuple[str, ...] = (*JOINT_CAUSES, "thermal_drift", "station_shift"),
) -> Diagnosis:
    geo = _fit(chain, table, tool_points, params, noise, None)
    n_obs = 3 * len(table)
    rss_g = _rss(geo)
    floor, floor_source = noise_floor(table, noise)
    hold_g = _holdout(chain, table, tool_points, params, noise, "none", folds, np.random.default_rng(seed), None)
    candidates: list[Candidate] = []
    fitted: dict[str, tuple[Identification, Extension | None, MeasurementTable, dict | None]] = {}
    alpha = ALPHA / len(causes)
    for cause in causes:
        try:
            fit = fit_cause(chain, table, tool_points, params, noise, cause)
        except IdentificationError:
            continue
        if fit is None:
            continue
        res, ext, tab, shift, n_extra = fit
        rss_e = _rss(res)
        dof_e = n_obs - (geo.cov.shape[0] + n_extra)
        f = ((rss_g - rss_e) / n_extra) / (rss_e / dof_e) if rss_e > 0 else np.inf
        p = float(fdtrc(n_extra, dof_e, f)) if np.isfinite(f) else 0.0
        d_bic = n_obs * np.log(rss_e / rss_g) + n_extra * np.log(n_obs)
        hold = _holdout(chain, table, tool_points, params, noise, cause, folds, np.random.default_rng(seed), ext)
        cand = Candidate(cause, n_extra, rss_e, dof_e, p, float(d_bic), hold, rms(res.residuals),
                         detail=shift or {})  # fmt: skip
        cand.significant = bool(p < alpha and d_bic < 0 and hold < hold_g)
        candidates.append(cand)
        fitted[cause] = (res, ext, tab, shift)

    # is the geometric model at the noise floor?  variance factor against chi2 (tracker model weighting),
    # or the residual RMS against the floor from repeated measurements / the noise model
    if noise is not None and floor_source == "tracker noise model":
        p_floor = float(chdtrc(geo.dof, rss_g))
    else:
        p_floor = float(chdtrc(geo.dof, geo.dof * rms(geo.residuals) ** 2 / floor**2))
    significant = sorted((c for c in candidates if c.significant), key=Candidate.score)
    if not significant:
        cause = "none" if p_floor >= ALPHA else "unexplained"
        chosen = None
    else:
        chosen = significant[0]
        res = fitted[chosen.cause][0]
        excess_g = rms(geo.residuals) ** 2 - floor**2
        excess_e = rms(res.residuals) ** 2 - floor**2
        cause = chosen.cause if excess_e <= 0.5 * excess_g else "unexplained"
    if chosen is not None and cause != "unexplained":
        res, ext, tab, shift = fitted[chosen.cause]
        return Diagnosis(cause, geo, res, candidates, hold_g, chosen.holdout_rms_mm, floor, floor_source, p_floor,
                         ext, tab, shift)  # fmt: skip
    return Diagnosis(cause, geo, None, candidates, hold_g, hold_g, floor, floor_source, p_floor, None, table)
