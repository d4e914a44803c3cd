"""What the geometric model gets wrong, which physical causes explain it, and the gain: `diagnose`.

The causes are chosen by forward selection (`calib.diagnose.selection`), each judged by evidence that survives
over-fitting (`calib.diagnose.judge`): a nested F test, the BIC, a significant gain on held-out poses (folds of whole
poses with edge folds that judge extrapolation, passes, or blocks of time within each station:
`calib.diagnose.crossval`), physical plausibility. When no fold scheme works no cause enters on the F test and BIC
alone: the verdict is `unexplained` with the geometric model, and its note says what measurement would allow the
check. `cause` is the selected cause with the largest gain, `causes` the selected set in order. The chosen model is
held outside the joint ranges and times it was fitted on (`calib.model.extension.Ranges`).

`none` or `unexplained` is decided by structure, not by the scale of the noise model
(`calib.diagnose.structure`): with no cause selected, residuals that can be predicted are `unexplained`, others
`none`, with the noise scale reported: a tracker 18 % noisier than its model is not a cause. The noise
floor (`calib.diagnose.noise_floor`) comes from comparable repeats or the tracker model, and says which.

The fits (`calib.diagnose.fits`) skip the covariance, start where the best-fitting of the sub-models already fitted
stopped (else from the geometric solution) and cross-validate by one Gauss-Newton step per fold; the change point
(`calib.diagnose.changepoint`) is an exact scan of every cut (once per set of rows), then one full fit; candidate
parameters the data cannot see are dropped and reported. Given an executor (threads), the folds of the map's
search and of the structure test run at once; the diagnosis is the same bit for bit.
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc, fdtrc

from trackcal.calib.diagnose.changepoint import SHIFT, relabel_shift
from trackcal.calib.diagnose.extensions import JOINT_CAUSES
from trackcal.calib.diagnose.fits import Context, context, extension_of, final_fit, scan
from trackcal.calib.diagnose.joint_map_fit import ErrorMapFit, fit_error_map
from trackcal.calib.diagnose.judge import Candidate
from trackcal.calib.diagnose.noise_floor import Floor, noise_floor
from trackcal.calib.diagnose.point_effects import POINT_CAUSES
from trackcal.calib.diagnose.selection import ALPHA, Selection
from trackcal.calib.diagnose.structure import structure_test
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Identification, identify
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.extension import Extension
from trackcal.calib.model.params import Param


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


def diagnose(
    chain: Chain,
    table: MeasurementTable,
    tool_points: dict[str, np.ndarray],
    params: list[Param],
    noise: TrackerNoise | None = None,
    folds: int = 5,
    seed: int = 0,
    causes: tuple[str, ...] = (
        *JOINT_CAUSES,
        *POINT_CAUSES,
        "thermal_drift",
        SHIFT,
        "thermal_warmup",
        "payload_compliance",
    ),
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
    floor = noise_floor(table, noise, tracker)
    p_floor = floor_test(geo, floor)
    ctx = context(chain, table, params, noise, geo, causes)
    ctx.executor = executor
    sel = Selection.start(ctx, folds, seed, causes)
    stepping = True
    while stepping:  # one forward-selection step at a time, until a step admits no cause
        stepping = sel.step()
    return _verdict(sel, table, floor, p_floor)


def floor_test(geo: Identification, floor: Floor) -> float:
    """p-value that the geometric residuals are at the floor: an F test against a floor from repeats
    (itself estimated with floor.dof degrees of freedom), chi-square against the noise model."""
    if floor.dof is None and geo.noise is not None:
        return float(chdtrc(geo.dof, geo.variance_factor * geo.dof))
    ratio = float(np.sum(geo.residuals**2)) / geo.dof / floor.sigma_mm**2
    if floor.dof is None:
        return float(chdtrc(geo.dof, ratio * geo.dof))
    return float(fdtrc(geo.dof, floor.dof, ratio))


def _verdict(sel: Selection, table: MeasurementTable, floor: Floor, p_floor: float) -> Diagnosis:
    """The diagnosis once selection stopped: the chosen model identified with its covariance, its held-out figures
    against the geometric model's, the structure left in its residuals."""
    ctx, geo = sel.ctx, sel.ctx.geo
    refused = [
        {"cause": c.cause, "step": c.step, "why": "; ".join(c.detail["implausible"])}
        for c in sel.candidates
        if "implausible" in c.detail
    ]
    structure = structure_test(
        ctx,
        sel.current,
        ctx.table
        if sel.current.shift is None
        else relabel_shift(ctx.table, sel.current.shift["station"], sel.current.shift["after_t_s"]),
        sel.val.fold_sets["pose"],
        sel.seed,
        ALPHA,
    )
    scheme, hold_g, hold_e = _held_out(sel)
    cv_note = (
        None
        if hold_g is not None
        else (
            "cross-validation is not possible on this design: every fold scheme (pose, pass, time block) leaves a "
            "training set that cannot be identified, and the F test and BIC alone admit no cause (the geometric model "
            f"is kept); {_measurement_needed(table)}"
        )
    )
    doc = dict(
        geometric=geo,
        candidates=sel.candidates,
        holdout_geometric_mm=hold_g,
        holdout_extended_mm=hold_e,
        noise_floor_mm=floor.sigma_mm,
        floor_source=floor.source,
        variance_factor_pvalue=p_floor,
        structure=structure,
        cv_note=cv_note,
        cv_scheme=scheme,
        not_identifiable=dict(ctx.dropped),
        refused=refused,
    )
    if not sel.selected:
        # residuals with structure, a cause the data could not check (no held-out poses), or one refused as
        # unphysical: what the geometric model misses is not explained
        found = structure["structure"] or sel.untested or bool(refused)
        return Diagnosis(
            "unexplained" if found else "none",
            extended=None,
            extension=None,
            table=table,
            noise_scale=_scale(geo.residuals, geo, floor),
            **doc,
        )
    return _chosen_verdict(sel, table, floor, doc)


def _chosen_verdict(sel: Selection, table: MeasurementTable, floor: Floor, doc: dict) -> Diagnosis:
    """_verdict once selection chose causes: the chosen model identified (with the map, jointly), its causes by
    gain; `doc`: the figures every diagnosis carries."""
    ctx = sel.ctx
    by_gain = sorted(sel.selected, key=lambda c: c.gain_mm if c.gain_mm is not None else -c.delta_bic, reverse=True)
    # model.json names its extension after the main cause that carries parameters
    if sel.map_fit is None:
        res, ext, tab, shift, _ = final_fit(ctx, sel.chosen, next((c.cause for c in by_gain if c.cause != SHIFT), None))
    else:
        res, ext, tab, shift = _final_map_fit(
            ctx, table, sel.fitted, sel.map_fit, sel.folds, sel.seed, refit=sel.fitted != sel.map_base
        )
    causes = [
        {
            "cause": c.cause,
            "gain_mm": c.gain_mm,
            "holdout_rms_mm": c.holdout_rms_mm,
            "f_pvalue": c.f_pvalue,
            "delta_bic": c.delta_bic,
            "n_params": c.n_params,
            "cv_scheme": c.cv_scheme,
            **c.detail,
        }
        for c in sel.selected
    ]
    return Diagnosis(
        by_gain[0].cause,
        extended=res,
        extension=ext,
        table=tab,
        shift=shift,
        causes=causes,
        noise_scale=_scale(res.residuals, res, floor),
        **doc,
    )


def _held_out(sel: Selection) -> tuple[str | None, float | None, float | None]:
    """(scheme, held-out RMS of the geometric model, of the chosen one) on the same folds; with the map, the
    geometric model on the first step's folds and the chosen one on the last's."""
    if sel.map_fit is not None:
        return "per step", sel.hold_first, sel.selected[-1].holdout_rms_mm
    val = sel.val
    scheme, hold_g, hold_e = (
        val.compare((), sel.chosen)
        if sel.selected
        else next(
            ((s, val.cv((), s), val.cv((), s)) for s in ("pose", "pass", "time") if val.cv((), s) is not None),
            (None, None, None),
        )
    )
    return scheme, *(None if h is None else h.rms_mm for h in (hold_g, hold_e))


def _final_map_fit(
    ctx: Context, table: MeasurementTable, fitted: tuple[str, ...], mf: ErrorMapFit, folds: int, seed: int, refit: bool
):
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
    final = fit_error_map(
        ctx.chain,
        table,
        ctx.geo.points,
        ctx.params,
        ctx.noise,
        base=extension_of(ctx, fitted),
        folds=folds,
        seed=seed,
        orders=(order,),
        taus_rad=(mf.tau_rad,),
    )
    return final.identification, final.extension, table, shift


def _measurement_needed(table: MeasurementTable) -> str:
    """What measurement would let held-out poses check a cause on a campaign where none can."""
    poses_of: dict[str, set] = {}
    for pose, point in zip(table.pose, table.point, strict=True):
        poses_of.setdefault(point, set()).add(pose)
    alone = sorted(p for p, poses in poses_of.items() if len(poses) < 2)
    if alone:
        named = ", ".join(alone[:3]) + (f" and {len(alone) - 3} more" if len(alone) > 3 else "")
        return (
            f"reference point(s) {named} are measured at one pose only: measure every reference point at two "
            "or more poses (better: every point at every pose) so that a pose can be held out"
        )
    return (
        "measure more poses (the poses left when one is held out must identify the geometric model), or repeat "
        "the poses in a second pass, so that a pose or a pass can be held out"
    )


def _scale(residuals: np.ndarray, res: Identification, floor: Floor) -> float:
    """Residual RMS of a fit relative to the noise floor (1.18: the tracker is 18 % noisier than its model)."""
    if floor.dof is None and res.noise is not None:
        return float(np.sqrt(res.variance_factor))
    return float(np.sqrt(np.sum(residuals**2) / res.dof) / floor.sigma_mm)
