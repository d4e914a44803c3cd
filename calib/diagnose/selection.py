"""Model discovery: what the geometric model gets wrong, which physical causes explain it, and the gain.

The geometric model is fitted first. Then causes are added by forward selection: at each step every
remaining candidate (`calib.diagnose.extensions`, plus `station_shift`, a change point in one station's series) is
fitted jointly with the geometric parameters and the causes already chosen, and judged against the
current model by evidence that survives over-fitting:

- a nested F test (whitened residuals), at alpha = 1e-3 / number of candidates left;
- the Bayesian information criterion (it must improve);
- cross-validation: the candidate must predict held-out rows better than the current model, significantly: a
  one-sided signed-rank test on the per-pose held-out errors at 1 % with the held-out RMS lower
  (`calib.diagnose.significance`; issue 36: "any positive gain" let a cause join on 0.2 um). Folds are
  whole poses, with edge folds holding out each joint's extreme poses so that extrapolation is judged
  (`calib.diagnose.crossval.edge_rows`), or (when a time-dependent cause is judged: thermal drift, station
  shift) blocks of time within each station, so a drift is judged by how it extrapolates. When a fold scheme
  leaves a training set that cannot identify the current model (a planned campaign of few configurations), the
  next scheme is used (pose, pass, time); when none works no cause enters on the F test and BIC alone: the
  verdict is `unexplained` with the geometric model, and its note says what measurement would allow the check.
  A candidate the current model's scheme cannot identify is not significant (`Validator.compare`): the campaign
  cannot tell it from over-fitting;
- physical plausibility: a fit whose parameters leave their physical range (`calib.diagnose.plausibility`: an
  encoder scale of percents, a joint error of degrees) is refused as a cause and named in `refused`.

The significant candidate with the largest held-out gain joins the model, until none is left. `cause` is
the one with the largest gain, `causes` the selected set in order. The chosen model is held outside the joint
ranges and times it was fitted on (`calib.diagnose.features.Ranges`).

The joint error map (cyclic_error of any order, `calib.diagnose.joint_map`) is tried once the causes of few
parameters are exhausted. When it joins, every cause chosen before it is judged again with the map in
the model (`Rejudge`: BIC and held-out gain); one whose gain the map now explains leaves, and is not
tried again. On the real UR10 (Series B) an encoder scale and a station shift had joined a two-harmonic
joint error and gained nothing beside the map; kept, they made its prediction of Series D worse.

`none` or `unexplained` is decided by structure, not by the scale of the noise model
(`calib.diagnose.structure`): with no cause selected, residuals that can be predicted are `unexplained`, others
`none`, with the noise scale reported: a tracker 18 % noisier than its model is not a cause. The noise
floor (`calib.diagnose.noise_floor`) comes from comparable repeats or the tracker model, and says which.

The fits (`calib.diagnose.crossval`) skip the covariance, start where the best-fitting of the sub-models already
fitted stopped (else from the geometric solution) and cross-validate by one Gauss-Newton step per fold; the change
point (`calib.diagnose.changepoint`) is an exact scan of every cut (once per set of rows), then one full fit;
candidate parameters the data cannot see are dropped and reported. Given an executor (threads), the folds of the
map's search and of the structure test run at once; the diagnosis is the same bit for bit.
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.special import fdtrc  # the F survival function (scipy.stats: ~1 s to import)

from trackcal.calib.diagnose.changepoint import SHIFT, relabel_shift
from trackcal.calib.diagnose.crossval import (
    TIME_CAUSES,
    Context,
    Fit,
    Validator,
    extension_of,
    fit_model,
    rms,
    scan,
    visible_extension,
    whole_fit,
)
from trackcal.calib.diagnose.extensions import JOINT_CAUSES, THERMAL_FORMS, build_extension
from trackcal.calib.diagnose.features import Extension
from trackcal.calib.diagnose.joint_map import CAUSE as MAP
from trackcal.calib.diagnose.joint_map import ORDERS, ErrorMapFit, MapEvidence, fit_error_map, held_out_errors
from trackcal.calib.diagnose.noise_floor import Floor, floor_test, noise_floor
from trackcal.calib.diagnose.plausibility import implausible
from trackcal.calib.diagnose.point_effects import POINT_CAUSES
from trackcal.calib.diagnose.significance import MAP_LEVEL, HeldOut, significant
from trackcal.calib.diagnose.structure import structure_test
from trackcal.calib.diagnose.warmup import warmup_candidate
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Identification, IdentificationError, identify, model_points
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import Param

ALPHA = 1e-3


@dataclass
class Candidate:
    cause: str  # judged against the model before it (the geometric model at step 1)
    n_params: int
    rss: float  # whitened residual sum of squares
    dof: int
    f_pvalue: float
    delta_bic: float
    holdout_rms_mm: float | None  # None: cross-validation not possible (see Diagnosis.cv_note)
    rms_mm: float
    detail: dict = field(default_factory=dict)
    significant: bool = False
    step: int = 1  # forward-selection step (1: against the geometric model)
    holdout_base_mm: float | None = None  # the model it is compared with, on the same folds
    cv_scheme: str | None = None
    cv_note: str | None = None  # why holdout_rms_mm is None

    @property
    def gain_mm(self) -> float | None:
        if self.holdout_rms_mm is None or self.holdout_base_mm is None:
            return None
        return self.holdout_base_mm - self.holdout_rms_mm

    def score(self) -> float:
        """Sort key: held-out RMS, then (cross-validation not possible) the BIC change."""
        return self.holdout_rms_mm if self.holdout_rms_mm is not None else float(self.delta_bic)


@dataclass
class Diagnosis:
    cause: str
    geometric: Identification
    extended: Identification | None
    candidates: list[Candidate]  # every candidate of every step
    holdout_geometric_mm: float | None
    holdout_extended_mm: float | None
    noise_floor_mm: float
    floor_source: str
    variance_factor_pvalue: float
    extension: Extension | None
    table: MeasurementTable  # as identified (station_shift relabels rows)
    shift: dict | None = None
    causes: list[dict] = field(default_factory=list)  # selected, in order: {cause, gain_mm, f_pvalue, ...}
    noise_scale: float = 1.0  # residual RMS of the final model / noise floor
    structure: dict = field(default_factory=dict)  # the residual-structure test of the final model
    cv_note: str | None = None  # why a held-out figure is missing
    cv_scheme: str | None = None  # folds of the held-out figures: pose, pass or time (blocks within stations)
    not_identifiable: dict = field(default_factory=dict)  # cause -> parameters the data cannot see
    refused: list[dict] = field(default_factory=list)  # {cause, step, why}: fits outside their physical range


class CauseFit(NamedTuple):
    """The geometric model fitted with one cause, or several joined by "+"."""

    result: Identification
    extension: Extension | None
    table: MeasurementTable  # as fitted (station_shift relabels the rows after the change point)
    shift: dict | None  # station_shift: {"station", "after_t_s"}
    n_extra: int  # parameters the causes add


def fit_cause(chain, table, tool, params, noise, cause: str,
              geometric: Identification | None = None) -> CauseFit | None:  # fmt: skip
    """Fit the geometric model extended by `cause` (several joined by "+") with its covariance; None when
    the table cannot reveal the cause (too few rows for a change point, no parameter the data can see).
    `geometric` is the geometric fit of the same table, tool, params and noise if already computed (a
    diagnosis's `geometric`): it is not fitted again."""
    geo = geometric if geometric is not None else identify(chain, table, tool, params, noise=noise)
    if cause == "none":
        return CauseFit(geo, None, table, None, 0)
    causes = tuple(cause.split("+"))
    ctx = context(chain, table, params, noise, geo, causes)
    if any(c != SHIFT and c not in ctx.features for c in causes):
        return None
    return final_fit(ctx, causes)


def final_fit(ctx: Context, causes: tuple[str, ...], main: str | None = None) -> CauseFit | None:
    """The model `causes` identified with its covariance; `main` names the combined extension."""
    table, shift, n_extra = ctx.table, None, 0
    if SHIFT in causes:
        found = scan(ctx)
        if found is None:
            return None
        shift = {"station": found[0], "after_t_s": found[1]}
        table, n_extra = relabel_shift(table, *found), 7
    ext = extension_of(ctx, causes, main=main)
    res = identify(ctx.chain, table, ctx.geo.points, ctx.params, noise=ctx.noise, dev0=ctx.geo.dev, extension=ext)
    return CauseFit(res, ext, table, shift, n_extra + (0 if ext is None else ext.size))


def context(chain, table, params, noise, geo, causes) -> Context:
    tool = np.array([geo.points[p] for p in table.point])
    base = model_points(Kinematics(chain, params), np.radians(table.q_deg), tool, geo.dev, None, None)
    unwhiten = None if noise is None else np.linalg.inv(noise.whitening(table.xyz))
    ctx = Context(chain, table, params, noise, geo, {}, base, unwhiten=unwhiten)
    for c in causes:
        if c == SHIFT:
            continue
        try:
            ext, dropped = (warmup_candidate(chain, table, geo, noise, params) if c == "thermal_warmup" else
                            visible_extension(chain, table, geo, noise, params, c))  # tau profiled (`warmup`)
        except IdentificationError:  # more unknowns with this cause than the table has equations: not revealable
            continue
        if c == "thermal_drift" and ext is not None:
            ext = thermal_form(ctx, ext)
        if dropped:
            ctx.dropped[c] = dropped
        if ext is not None:
            ctx.features[c] = ext
    return ctx


def thermal_form(ctx: Context, arm: Extension) -> Extension:
    """thermal_drift's form chosen by the data (calib.extensions.THERMAL_FORMS): the arm and tool growing
    about the first joint, or the base column too; one parameter each, the lower residual wins."""
    forms = [arm] + [build_extension("thermal_drift", ctx.chain, ctx.table, names=[f]) for f in THERMAL_FORMS
                     if f not in arm.names]  # fmt: skip
    rss = []
    for ext in forms:
        ctx.features["thermal_drift"] = ext
        try:
            rss.append(fit_model(ctx, ("thermal_drift",)).rss)
        except IdentificationError:
            rss.append(np.inf)
    return forms[int(np.argmin(rss))]


def _map_candidate(ctx: Context, val: Validator, fitted: tuple[str, ...], current: Fit, n_obs: int, n_base: float,
                   alpha: float, step: int, folds: int, seed: int,
                   orders: tuple[int, ...] = ORDERS) -> tuple[Candidate, ErrorMapFit] | None:  # fmt: skip
    """The joint error map on top of the model `fitted` (`calib.diagnose.joint_map`: order (of `orders`) and ridge by
    its own cross-validation by pose; the F test and BIC count its effective number of parameters). Its held-out
    gain is judged by the paired test (`calib.diagnose.significance`) on the search's folds and the edge folds
    of `val` (the map clamped to each fold's training arcs, as predict clamps it), and a map beyond the physical
    range of a transmission error is refused (`calib.diagnose.plausibility`)."""
    table = ctx.table if current.shift is None else relabel_shift(ctx.table, current.shift["station"],
                                                                   current.shift["after_t_s"])  # fmt: skip
    # orders whose coefficients (2 per harmonic and joint) leave the problem over-determined even unpenalised
    top = (3 * len(table) - current.n_cols - 1) // (2 * ctx.chain.dof)
    # and orders a joint's angles can resolve: a series of order H has 2 H + 1 coefficients, which the n distinct
    # angles of n poses determine only when n >= 2 (2 H + 1) (each coefficient over-determined twice). Beyond it a
    # harmonic of the pose sample's own aliases is fitted (issue 36: motor-side gear harmonics, at the gear ratio
    # times the angle, aliased by 20 scattered poses, were taken for an order-16 map that made fresh poses worse)
    top = min(top, (len(set(table.pose)) // 2 - 1) // 2)
    orders = tuple(h for h in orders if h <= top)
    if not orders:
        return None
    try:  # from the whole-table fit of `fitted`, which `Rejudge` linearises at too (`Linearised`)
        mf = fit_error_map(ctx.chain, table, ctx.geo.points, ctx.params, ctx.noise, base=extension_of(ctx, fitted),
                           folds=folds, seed=seed, orders=orders, start=whole_fit(ctx, fitted),
                           executor=ctx.executor)  # fmt: skip
    except IdentificationError:
        return None
    res = mf.identification
    in_current = current.extension is not None and MAP in [c for c, _ in current.extension.parts()]
    low = ctx.features[MAP].size if in_current else 0  # the low-order cyclic_error it would replace
    rss, n_extra = res.variance_factor * res.dof, mf.effective_params - low
    dof = n_obs - n_base - _n_extra(ctx, fitted) - mf.effective_params
    if dof <= 0 or n_extra <= 0:
        return None
    f = ((current.rss - rss) / n_extra) / (rss / dof)
    p = float(fdtrc(n_extra, dof, f)) if f > 0 else 1.0
    d_bic = float(n_obs * np.log(rss / current.rss) + n_extra * np.log(n_obs))
    # the held-out gain judged on the search's folds and the edge folds (extrapolation), by the paired test
    held = held_out_errors(mf, list(val.fold_sets["pose"] or []) + val.edges, len(ctx.params), ctx.executor) if (
        p < alpha and d_bic < 0 and val.fold_sets["pose"]) else None  # fmt: skip
    with_map, without = (HeldOut(*held[0]), HeldOut(*held[1])) if held is not None else (None, None)
    gain_ok, p_held = significant(without, with_map, table.pose, MAP_LEVEL)
    cand = Candidate(MAP, int(round(n_extra)), rss, int(dof), p, d_bic,
                     mf.cv_rms_mm if with_map is None else with_map.rms_mm, rms(res.residuals),
                     {"error_map": mf.to_doc(), "heldout_pvalue": p_held, **(current.shift or {})}, step=step,
                     holdout_base_mm=mf.cv_rms_without_mm if without is None else without.rms_mm,
                     cv_scheme="pose")  # fmt: skip
    refused = implausible(res.extension, res.ext)
    if refused:
        cand.detail["implausible"] = refused
    cand.significant = bool(p < alpha and d_bic < 0 and gain_ok and not refused)
    return cand, mf


class Rejudge:
    """The causes chosen before the map judged again with the map in the model: a cause stays only while the
    BIC and a held-out gain on its folds (by pose; by time block for a time-dependent cause) still agree, the
    map at its order and ridge on both sides. A cause that is a function of each joint's own angle
    (encoder_scale) or shares much of the map's signal otherwise got its gain from what the map now
    explains; kept, it only extrapolates beyond the angles the table covers. The F test is reported, not
    decisive here: against a ridge-penalised map the parameters a cause adds are a difference of effective
    parameter counts (below one when the map takes its signal over), which no F distribution calibrates;
    the BIC takes effective counts as they are.

    Every model is one linearised problem (`calib.diagnose.joint_map.MapEvidence`) with some causes held at zero: one
    problem with the station shift and one without, for the causes `chosen` (before the map) and every
    subset of them; each figure is computed once."""

    def __init__(self, ctx: Context, val: Validator, chosen: tuple[str, ...], mf: ErrorMapFit, n_obs: int):
        self.ctx, self.val, self.mf, self.n_obs = ctx, val, mf, n_obs
        self.causes = tuple(c for c in chosen if c != SHIFT)
        self.base = extension_of(ctx, self.causes)
        at, self.spans = 0, {}
        for c, (_, names) in zip(self.causes, [] if self.base is None else self.base.parts(), strict=True):
            self.spans[c] = tuple(range(at, at + len(names)))
            at += len(names)
        self.roots: dict[bool, MapEvidence] = {}
        self.figures: dict[tuple, object] = {}

    def scheme_of(self, cause: str) -> str | None:
        order = ("time", "pose", "pass") if cause in TIME_CAUSES else ("pose", "pass", "time")
        return next((sc for sc in order if self.val.fold_sets[sc] is not None), None)

    def root(self, shifted: bool) -> MapEvidence:
        if shifted not in self.roots:
            ctx = self.ctx
            start = whole_fit(ctx, (*self.causes, SHIFT) if shifted else self.causes)
            table = ctx.table if start.shift is None else relabel_shift(ctx.table, start.shift["station"],
                                                                         start.shift["after_t_s"])  # fmt: skip
            self.roots[shifted] = MapEvidence(ctx.chain, table, ctx.params, ctx.noise, self.base, start, self.mf)
        return self.roots[shifted]

    def figure(self, causes: tuple[str, ...], scheme: str | None = None):
        """(rss, number of parameters) of the model `causes`, or its held-out RMS on `scheme`'s folds."""
        key = (tuple(sorted(causes)), scheme)
        if key not in self.figures:
            drop = tuple(i for c in self.causes if c not in causes for i in self.spans[c])
            ev = self.root(SHIFT in causes)
            if scheme is None:
                self.figures[key] = ev.whole(drop)
            else:
                ids = np.zeros(len(self.ctx.table), dtype=int)
                for k, g in enumerate(self.val.fold_sets[scheme]):
                    ids[g] = k
                self.figures[key] = ev.cv_rms_mm(ids, drop)
        return self.figures[key]

    def judge(self, fitted: tuple[str, ...]) -> dict[str, dict]:
        """cause -> {f_pvalue, delta_bic, n_params, cv_scheme, holdout_rms_mm, holdout_without_mm, significant}
        for every cause of `fitted` (a subset of those chosen before the map) against `fitted` without it."""
        rss_full, n_full = self.figure(fitted)
        n_obs = self.n_obs
        out = {}
        for c in fitted:
            scheme = self.scheme_of(c)
            rest = tuple(x for x in fitted if x != c)
            rss_rest, n_rest = self.figure(rest)
            k, dof = n_full - n_rest, n_obs - n_full
            f = ((rss_rest - rss_full) / k) / (rss_full / dof) if k > 0 and dof > 0 and rss_full > 0 else 0.0
            p = float(fdtrc(k, dof, f)) if f > 0 else 1.0
            d_bic = float(n_obs * np.log(rss_full / rss_rest) + max(k, 0.0) * np.log(n_obs))
            passes = d_bic < 0
            hold, without = (self.figure(fitted, scheme), self.figure(rest, scheme)) if passes and scheme else (
                None, None)  # fmt: skip
            out[c] = {"f_pvalue": p, "delta_bic": d_bic, "n_params": k, "cv_scheme": scheme, "holdout_rms_mm": hold,
                      "holdout_without_mm": without, "significant": bool(passes and (hold is None or hold < without))}
        return out


def corrected_by_map(table: MeasurementTable, mf: ErrorMapFit) -> MeasurementTable:
    """The table with every joint angle moved by the fitted map (q_true = q_read + e_j(q_read))."""
    ext, theta = mf.extension, mf.identification.ext
    offsets = np.einsum("rje,e->rj", ext.joint_features[:, :, mf.n_base :], theta[mf.n_base :])
    out = table.subset(np.arange(len(table)))
    out.q_deg = table.q_deg + np.degrees(offsets)
    return out


def _final_map_fit(ctx: Context, table: MeasurementTable, fitted: tuple[str, ...], mf: ErrorMapFit, folds: int,
                   seed: int, refit: bool):  # fmt: skip
    """The chosen model with the map, identified jointly (the map's order and ridge as chosen); `mf` itself
    unless `refit` (causes joined after the map)."""
    ctx.table = table  # the rows as measured
    shift = None
    if SHIFT in fitted:
        found = scan(ctx)
        shift = {"station": found[0], "after_t_s": found[1]}
        table = relabel_shift(table, *found)
    if not refit:
        return mf.identification, mf.extension, table, shift
    order = max(mf.orders.values())
    final = fit_error_map(ctx.chain, table, ctx.geo.points, ctx.params, ctx.noise, base=extension_of(ctx, fitted),
                          folds=folds, seed=seed, orders=(order,), taus_rad=(mf.tau_rad,))  # fmt: skip
    return final.identification, final.extension, table, shift


def _n_extra(ctx: Context, causes: tuple[str, ...]) -> int:
    return sum(7 if c == SHIFT else ctx.features[c].size for c in causes)


def diagnose(
    chain: Chain,
    table: MeasurementTable,
    tool_points: dict[str, np.ndarray],
    params: list[Param],
    noise: TrackerNoise | None = None,
    folds: int = 5,
    seed: int = 0,
    causes: tuple[str, ...] = (*JOINT_CAUSES, *POINT_CAUSES, "thermal_drift", SHIFT, "thermal_warmup",
                               "payload_compliance"),
    geometric: Identification | None = None,
    tracker: TrackerNoise | None = None,
    executor: Executor | None = None,
) -> Diagnosis:
    """What the geometric model misses and which causes explain it (the module's docstring). `geometric` is the
    geometric fit of the same table, tool points, params and noise if already computed (`fit_cause(..., "none")`,
    identify's): it is not fitted again, and the diagnosis is the same. `tracker`: the cell's instrument, the noise
    floor's model under i.i.d. weighting (default the AT901's). `executor` (threads) runs independent pieces at once:
    the same diagnosis, in less time on several cores."""
    geo = geometric if geometric is not None else identify(chain, table, tool_points, params, noise=noise)
    n_obs = 3 * len(table)
    n_geo = n_obs - geo.dof
    floor = noise_floor(table, noise, tracker)
    p_floor = floor_test(geo, floor)
    ctx = context(chain, table, params, noise, geo, causes)
    ctx.executor = executor
    val = Validator(ctx, folds, seed)
    open_causes = [c for c in causes if c == SHIFT or c in ctx.features]
    chosen: tuple[str, ...] = ()  # the selected causes
    fitted: tuple[str, ...] = ()  # those fitted by crossval (the joint error map is held at its own fit)
    map_fit, map_edf, map_base, hold_first = None, 0.0, (), None
    current = whole_fit(ctx, ())
    candidates: list[Candidate] = []
    selected: list[Candidate] = []
    step = 0
    untested = False  # a candidate passed the F test and BIC where no held-out check was possible
    map_open = MAP in open_causes  # the full joint error map: tried once the low-order causes are exhausted
    while open_causes or map_open:
        step += 1
        alpha = ALPHA / max(len(open_causes), 1)
        trial = []
        for cause in open_causes:
            model = (*fitted, cause)
            try:
                fit = whole_fit(ctx, model)
            except IdentificationError:
                continue
            n_extra = _n_extra(ctx, model) - _n_extra(ctx, fitted)
            dof = n_obs - n_geo - map_edf - _n_extra(ctx, model)
            if dof <= 0:
                continue
            f = ((current.rss - fit.rss) / n_extra) / (fit.rss / dof) if fit.rss > 0 else 0.0
            p = float(fdtrc(n_extra, dof, f)) if f > 0 else 1.0
            d_bic = float(n_obs * np.log(max(fit.rss, 1e-300) / current.rss) + n_extra * np.log(n_obs))
            passes = p < alpha and d_bic < 0
            scheme, hold_b, hold_m = val.compare(fitted, model) if passes else (None, None, None)
            # the held-out gain must be significant (a paired test per pose, `calib.diagnose.significance`); with
            # no held-out figure (no scheme: the F test and BIC alone; or the folds the campaign supports cannot
            # identify the model: it cannot be told from over-fitting) no cause enters (issue 36)
            gain_ok, p_held = significant(hold_b, hold_m, ctx.table.pose)
            cand = Candidate(cause, n_extra, fit.rss, dof, p, d_bic, None if hold_m is None else hold_m.rms_mm,
                             rms(fit.residuals), {**(fit.shift or {}), "heldout_pvalue": p_held}, step=step,
                             holdout_base_mm=None if hold_b is None else hold_b.rms_mm, cv_scheme=scheme)  # fmt: skip
            if cause in ctx.dropped:
                cand.detail["not_identifiable"] = list(ctx.dropped[cause])
            refused = implausible(fit.extension, fit.ext) if passes else []
            if passes and cause in ("thermal_drift", "thermal_warmup") and not refused:
                refused = _growth_between_stations(ctx, fitted, current, dof, alpha, cause)
            if refused:
                cand.detail["implausible"] = refused
            cand.significant = bool(passes and gain_ok and not refused)
            untested |= bool(passes and scheme is None and not refused)
            if hold_m is None:
                cand.cv_note = ("not cross-validated: the F test or the BIC already rejects it" if not passes else
                                f"a training set of the {scheme} folds cannot identify it: this campaign cannot tell "
                                "it from over-fitting" if scheme is not None else
                                "cross-validation not possible on this design: the F test and BIC alone admit no "
                                "cause")  # fmt: skip
            trial.append((cand, fit))
        if map_open and not any(c.significant for c, _ in trial):
            # cyclic_error's low-order form (if chosen) gives way to the map of any order; judged last, since a
            # generic map would absorb a compliance or an encoder scale of few parameters
            map_open = False
            base = tuple(c for c in fitted if c != MAP)
            cand = _map_candidate(ctx, val, base, current, n_obs, n_geo, alpha, step, folds, seed)
            trial += [] if cand is None else [cand]
        candidates.extend(c for c, _ in trial)
        winners = [t for t in trial if t[0].significant]
        if not winners:
            break
        best, fit = max(winners, key=lambda t: (t[0].gain_mm if t[0].gain_mm is not None else -t[0].delta_bic))
        hold_first = best.holdout_base_mm if step == 1 else hold_first  # the geometric model, step 1's folds
        if isinstance(fit, ErrorMapFit):  # later steps hold the map at this fit: the rows' angles corrected by it
            low = next((c for c in selected if c.cause == MAP), None)
            selected = [c for c in selected if c is not low]
            chosen = tuple(c for c in chosen if c != MAP)
            fitted = tuple(c for c in fitted if c != MAP)
            # causes chosen before the map that it makes redundant leave, one at a time (of those that no longer
            # pass, the one whose BIC gains most by leaving), and are not tried again; the map is then judged
            # again on what remains, at its order, with its ridge chosen again (if it would not pass, nothing
            # leaves)
            removed, rejudge, kept, judged = [], Rejudge(ctx, val, fitted, fit, n_obs), fitted, {}
            while fitted:
                judged = rejudge.judge(fitted)
                weak = [c for c in fitted if not judged[c]["significant"]]
                if not weak:
                    break
                gone = max(weak, key=lambda c: judged[c]["delta_bic"])
                fitted = tuple(c for c in fitted if c != gone)
                removed.append({"cause": gone, **judged.pop(gone)})
            again = _map_candidate(ctx, val, fitted, whole_fit(ctx, fitted), n_obs, n_geo, alpha, step, folds, seed,
                                   (max(fit.orders.values()),)) if removed else None
            if removed and (again is None or not again[0].significant):
                fitted, removed, judged = kept, [], {}
            if removed:
                candidates[candidates.index(best)] = again[0]
                best, fit = again
                best.detail["removed"] = removed
                selected = [c for c in selected if c.cause in fitted]
                chosen = tuple(c for c in chosen if c in fitted)
            for c in selected:
                if SHIFT not in fitted:  # their fits had the station shift that left
                    c.detail = {k: v for k, v in c.detail.items() if k not in ("station", "after_t_s")}
                if c.cause in judged:
                    c.detail["with_map"] = judged[c.cause]
            if low is not None:  # the map replaces the low-order cyclic_error
                best.detail["replaces"] = {"n_params": low.n_params, "holdout_rms_mm": low.holdout_rms_mm}
            selected.append(best)
            chosen = (*chosen, MAP)
            map_fit, map_edf, map_base = fit, fit.effective_params, fitted
            ctx.table = corrected_by_map(ctx.table, fit)
            ctx.fits.clear()
            val.cache.clear()
            current = whole_fit(ctx, fitted)
        else:
            selected.append(best)
            chosen = (*chosen, best.cause)
            open_causes.remove(best.cause)
            fitted = (*fitted, best.cause)
            current = fit

    refused = [{"cause": c.cause, "step": c.step, "why": "; ".join(c.detail["implausible"])} for c in candidates
               if "implausible" in c.detail]  # fmt: skip
    structure = structure_test(ctx, current, ctx.table if current.shift is None else relabel_shift(
        ctx.table, current.shift["station"], current.shift["after_t_s"]), val.fold_sets["pose"], seed,
        ALPHA)  # fmt: skip
    # the held-out figures of the verdict: the chosen model against the geometric one, on the same folds
    if map_fit is not None:  # the geometric model on the first step's folds, the chosen one on the last's
        scheme, hold_g, hold_e = "per step", hold_first, selected[-1].holdout_rms_mm
    else:
        scheme, hold_g, hold_e = val.compare((), chosen) if selected else next(
            ((s, val.cv((), s), val.cv((), s)) for s in ("pose", "pass", "time") if val.cv((), s) is not None),
            (None, None, None))  # fmt: skip
        hold_g, hold_e = (None if h is None else h.rms_mm for h in (hold_g, hold_e))
    cv_note = None if hold_g is not None else (
        "cross-validation is not possible on this design: every fold scheme (pose, pass, time block) leaves a "
        "training set that cannot be identified, and the F test and BIC alone admit no cause (the geometric model is "
        f"kept); {_measurement_needed(table)}")  # fmt: skip
    doc = dict(geometric=geo, candidates=candidates, holdout_geometric_mm=hold_g, holdout_extended_mm=hold_e,
               noise_floor_mm=floor.sigma_mm, floor_source=floor.source, variance_factor_pvalue=p_floor,
               structure=structure, cv_note=cv_note, cv_scheme=scheme, not_identifiable=dict(ctx.dropped),
               refused=refused)  # fmt: skip
    if not selected:
        # residuals with structure, a cause the data could not check (no held-out poses), or one refused as
        # unphysical: what the geometric model misses is not explained
        found = structure["structure"] or untested or bool(refused)
        return Diagnosis("unexplained" if found else "none", extended=None, extension=None,
                         table=table, noise_scale=_scale(geo.residuals, geo, floor), **doc)  # fmt: skip
    by_gain = sorted(selected, key=lambda c: c.gain_mm if c.gain_mm is not None else -c.delta_bic, reverse=True)
    main = by_gain[0]
    # model.json names its extension after the main cause that carries parameters
    if map_fit is None:
        res, ext, tab, shift, _ = final_fit(ctx, chosen, next((c.cause for c in by_gain if c.cause != SHIFT), None))
    else:
        res, ext, tab, shift = _final_map_fit(ctx, table, fitted, map_fit, folds, seed,
                                                      refit=fitted != map_base)
    causes = [{"cause": c.cause, "gain_mm": c.gain_mm, "holdout_rms_mm": c.holdout_rms_mm, "f_pvalue": c.f_pvalue,
               "delta_bic": c.delta_bic, "n_params": c.n_params, "cv_scheme": c.cv_scheme, **c.detail}
              for c in selected]  # fmt: skip
    return Diagnosis(main.cause, extended=res, extension=ext, table=tab, shift=shift, causes=causes,
                     noise_scale=_scale(res.residuals, res, floor), **doc)  # fmt: skip


WITHIN = " within stations"  # ctx.features key (after the cause's name) of the growth's part within each station's time


def _growth_between_stations(ctx: Context, fitted: tuple[str, ...], current: Fit, dof: int, alpha: float,
                             cause: str = "thermal_drift") -> list[str]:  # fmt: skip
    """[] when the arm's growth is significant within each station's own time, else one phrase: a growth constant
    over one station's rows is exactly that station's range scale (about its origin) and a translation of it, so
    between stations measured one after the other (the campaign order) a growth cannot be told from one station's
    wrong air data (issue 36: a station's ranges 30 ppm off were named thermal_drift, and poses measured after
    the campaign were predicted with the growth at every station). The part within stations (each station's mean
    growth removed) must pass the same F test."""
    ext = ctx.features[cause]
    stations = np.array(ctx.table.station)
    if len(set(stations)) < 2:
        return []
    g = ext.growth.copy()
    for sid in set(stations):
        g[stations == sid] -= g[stations == sid].mean(axis=0)
    within = cause + WITHIN
    ctx.features[within] = Extension(ext.cause, ext.names, ext.units, ext.to_boundary, growth=g, pivot=ext.pivot)
    try:
        fit = whole_fit(ctx, (*fitted, within))
    except IdentificationError:
        return [f"{cause}: its growth within each station's own time cannot be identified"]
    finally:
        del ctx.features[within]
    f = (current.rss - fit.rss) / (fit.rss / dof) if fit.rss > 0 else 0.0
    p = float(fdtrc(1, dof, f)) if f > 0 else 1.0
    if p < alpha:
        return []
    return [f"{cause}: within each station's own time the growth is not significant (F test p = {p:.2g}); "
            "between stations measured one after the other it is one station's range scale (its air data) as well"]


def _measurement_needed(table: MeasurementTable) -> str:
    """What measurement would let held-out poses check a cause on a campaign where none can."""
    poses_of: dict[str, set] = {}
    for pose, point in zip(table.pose, table.point, strict=True):
        poses_of.setdefault(point, set()).add(pose)
    alone = sorted(p for p, poses in poses_of.items() if len(poses) < 2)
    if alone:
        named = ", ".join(alone[:3]) + (f" and {len(alone) - 3} more" if len(alone) > 3 else "")
        return (f"reference point(s) {named} are measured at one pose only: measure every reference point at two "
                "or more poses (better: every point at every pose) so that a pose can be held out")
    return ("measure more poses (the poses left when one is held out must identify the geometric model), or repeat "
            "the poses in a second pass, so that a pose or a pass can be held out")


def _scale(residuals: np.ndarray, res: Identification, floor: Floor) -> float:
    """Residual RMS of a fit relative to the noise floor (1.18: the tracker is 18 % noisier than its model)."""
    if floor.dof is None and res.noise is not None:
        return float(np.sqrt(res.variance_factor))
    return float(np.sqrt(np.sum(residuals**2) / res.dof) / floor.sigma_mm)
