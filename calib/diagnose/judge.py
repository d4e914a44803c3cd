"""How one candidate is judged against the current model: by evidence that survives over-fitting.

- a nested F test (whitened residuals), at the step's level (`calib.diagnose.selection.ALPHA` / causes left);
- the Bayesian information criterion (it must improve);
- cross-validation: the candidate must predict held-out rows better than the current model, significantly: a
  one-sided signed-rank test on the per-pose held-out errors with the held-out RMS lower
  (`calib.diagnose.significance`), on the folds `calib.diagnose.crossval.Validator.compare` chooses. With no held-out
  figure (no fold scheme, or folds whose training sets cannot identify the model) no cause enters (issue 36);
- physical plausibility (`calib.diagnose.plausibility`): a fit outside its physical range is refused and named;
- for the time causes, what the campaign order confounds (`calib.diagnose.confounds`): a station shift between two
  reflector blocks not significant beyond a displacement of the reflectors after it, or a growth not seen within a
  reflector's block, is a reflector's displacement as well.

`judge_cause` judges a cause of few parameters, `judge_map` the joint error map (its order and ridge chosen by its
own cross-validation, its held-out gain held to a stricter level).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.special import fdtrc  # the F survival function (scipy.stats: ~1 s to import)

from trackcal.calib.diagnose.changepoint import SHIFT, relabel_shift
from trackcal.calib.diagnose.confounds import growth_between_blocks, shift_between_blocks
from trackcal.calib.diagnose.crossval import Validator
from trackcal.calib.diagnose.fits import Context, Fit, extension_of, n_extra, rms, whole_fit
from trackcal.calib.diagnose.joint_map import CAUSE as MAP
from trackcal.calib.diagnose.joint_map_fit import ORDERS, ErrorMapFit, fit_error_map, held_out_errors
from trackcal.calib.diagnose.plausibility import implausible
from trackcal.calib.diagnose.significance import LEVEL, MAP_LEVEL, HeldOut, attainable, significant
from trackcal.calib.identify.solver import IdentificationError
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.extension import ExtensionError


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


class Trial(NamedTuple):
    """A candidate judged at one step, with its whole-table fit (an `ErrorMapFit` for the joint error map)."""

    candidate: Candidate
    fit: Fit | ErrorMapFit
    untested: bool = False  # it passed the F test and BIC where no held-out check was possible or could pass


def judge_cause(
    ctx: Context,
    val: Validator,
    fitted: tuple[str, ...],
    current: Fit,
    cause: str,
    n_obs: int,
    free: float,
    alpha: float,
    step: int,
) -> Trial | None:
    """The model `fitted` + `cause` judged against `current` (the fit of `fitted`), `free` the degrees of freedom
    left beside the geometric model and the joint map (if chosen); None when it cannot be fitted."""
    model = (*fitted, cause)
    try:
        fit = whole_fit(ctx, model)
    except IdentificationError:
        return None
    except ExtensionError:  # rival forms of one cause (thermal_warmup about one pivot, thermal_drift about another:
        return None  # the arm grows about one point) cannot both be in a model: the one chosen first stays
    added = n_extra(ctx, model) - n_extra(ctx, fitted)
    dof = free - n_extra(ctx, model)
    if dof <= 0:
        return None
    f = ((current.rss - fit.rss) / added) / (fit.rss / dof) if fit.rss > 0 else 0.0
    p = float(fdtrc(added, dof, f)) if f > 0 else 1.0
    d_bic = float(n_obs * np.log(max(fit.rss, 1e-300) / current.rss) + added * np.log(n_obs))
    passes = p < alpha and d_bic < 0
    scheme, hold_b, hold_m = val.compare(fitted, model) if passes else (None, None, None)
    # the held-out gain must be significant (a paired test per pose, `calib.diagnose.significance`); with
    # no held-out figure (no scheme: the F test and BIC alone; or the folds the campaign supports cannot
    # identify the model: it cannot be told from over-fitting) no cause enters (issue 36)
    gain_ok, p_held = significant(hold_b, hold_m, ctx.table.pose)
    cand = Candidate(
        cause,
        added,
        fit.rss,
        dof,
        p,
        d_bic,
        None if hold_m is None else hold_m.rms_mm,
        rms(fit.residuals),
        {**(fit.shift or {}), "heldout_pvalue": p_held},
        step=step,
        holdout_base_mm=None if hold_b is None else hold_b.rms_mm,
        cv_scheme=scheme,
    )
    if cause in ctx.dropped:
        cand.detail["not_identifiable"] = list(ctx.dropped[cause])
    refused = implausible(fit.extension, fit.ext) if passes else []
    if passes and cause in ("thermal_drift", "thermal_warmup") and not refused:
        refused = growth_between_blocks(ctx, fitted, current, dof, alpha, cause)
    if passes and cause == SHIFT and not refused:
        refused = shift_between_blocks(ctx, fitted, fit, dof, alpha)
    if refused:
        cand.detail["implausible"] = refused
    cand.significant = bool(passes and gain_ok and not refused)
    if hold_m is None:
        cand.cv_note = (
            "not cross-validated: the F test or the BIC already rejects it"
            if not passes
            else f"a training set of the {scheme} folds cannot identify it: this campaign cannot tell "
            "it from over-fitting"
            if scheme is not None
            else "cross-validation not possible on this design: the F test and BIC alone admit no cause"
        )
    elif passes and not attainable(ctx.table.pose):
        cand.cv_note = (
            f"on {len(set(ctx.table.pose))} poses the held-out test cannot reach its level of {LEVEL:g} (its "
            "smallest p-value is 2^-poses): a campaign of more poses can check it"
        )
    # no held-out check, or one that cannot reach its level on so few poses: untested (`significance.attainable`)
    unchecked = scheme is None or not attainable(ctx.table.pose)
    return Trial(cand, fit, bool(passes and unchecked and not refused))


def judge_map(
    ctx: Context,
    val: Validator,
    fitted: tuple[str, ...],
    current: Fit,
    n_obs: int,
    n_base: float,
    alpha: float,
    step: int,
    folds: int,
    seed: int,
    orders: tuple[int, ...] = ORDERS,
) -> Trial | None:
    """The joint error map on top of the model `fitted` (`calib.diagnose.joint_map_fit`: order (of `orders`) and ridge
    by its own cross-validation by pose; the F test and BIC count its effective number of parameters). Its held-out
    gain is judged by the paired test (`calib.diagnose.significance`) on the search's folds and the edge folds
    of `val` (the map clamped to each fold's training arcs, as predict clamps it), and a map beyond the physical
    range of a transmission error is refused (`calib.diagnose.plausibility`)."""
    table = (
        ctx.table
        if current.shift is None
        else relabel_shift(ctx.table, current.shift["station"], current.shift["after_t_s"])
    )
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
        mf = fit_error_map(
            ctx.chain,
            table,
            ctx.geo.points,
            ctx.params,
            ctx.noise,
            base=extension_of(ctx, fitted),
            folds=folds,
            seed=seed,
            orders=orders,
            start=whole_fit(ctx, fitted),
            executor=ctx.executor,
        )
    except IdentificationError:
        return None
    res = mf.identification
    in_current = current.extension is not None and MAP in [c for c, _ in current.extension.parts()]
    low = ctx.features[MAP].size if in_current else 0  # the low-order cyclic_error it would replace
    rss, added = res.variance_factor * res.dof, mf.effective_params - low
    dof = n_obs - n_base - n_extra(ctx, fitted) - mf.effective_params
    if dof <= 0 or added <= 0:
        return None
    f = ((current.rss - rss) / added) / (rss / dof)
    p = float(fdtrc(added, dof, f)) if f > 0 else 1.0
    d_bic = float(n_obs * np.log(rss / current.rss) + added * np.log(n_obs))
    return _map_trial(ctx, val, table, current, mf, (added, rss, dof, p, d_bic), alpha, step)


def _map_trial(
    ctx: Context,
    val: Validator,
    table: MeasurementTable,
    current: Fit,
    mf: ErrorMapFit,
    figures: tuple[float, float, float, float, float],
    alpha: float,
    step: int,
) -> Trial:
    """judge_map's candidate once the map `mf` is fitted; `figures`: its (added parameters, RSS, degrees of
    freedom, F-test p-value, BIC change)."""
    added, rss, dof, p, d_bic = figures
    res = mf.identification
    # the held-out gain judged on the search's folds and the edge folds (extrapolation), by the paired test
    held = (
        held_out_errors(mf, list(val.fold_sets["pose"] or []) + val.edges, len(ctx.params), ctx.executor)
        if (p < alpha and d_bic < 0 and val.fold_sets["pose"])
        else None
    )
    with_map, without = (HeldOut(*held[0]), HeldOut(*held[1])) if held is not None else (None, None)
    gain_ok, p_held = significant(without, with_map, table.pose, MAP_LEVEL)
    cand = Candidate(
        MAP,
        int(round(added)),
        rss,
        int(dof),
        p,
        d_bic,
        mf.cv_rms_mm if with_map is None else with_map.rms_mm,
        rms(res.residuals),
        {"error_map": mf.to_doc(), "heldout_pvalue": p_held, **(current.shift or {})},
        step=step,
        holdout_base_mm=mf.cv_rms_without_mm if without is None else without.rms_mm,
        cv_scheme="pose",
    )
    refused = implausible(res.extension, res.ext)
    if refused:
        cand.detail["implausible"] = refused
    cand.significant = bool(p < alpha and d_bic < 0 and gain_ok and not refused)
    return Trial(cand, mf, bool(p < alpha and d_bic < 0 and not refused and not attainable(table.pose, MAP_LEVEL)))
