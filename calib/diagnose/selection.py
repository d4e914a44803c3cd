"""Forward selection of causes: a state (`Selection`) and its one step.

The geometric model is fitted first. Then causes are added by forward selection: at each step every remaining
candidate (`calib.diagnose.extensions`, plus `station_shift`, a change point in one station's series) is fitted
jointly with the geometric parameters and the causes already chosen, and judged against the current model
(`calib.diagnose.judge`: F test, BIC, a significant held-out gain, physical plausibility). The significant
candidate with the largest held-out gain joins the model, until none is left. A significant candidate must also pass
its F test beside each candidate of its step refused as unphysical that fits better, fitted as a nuisance
(`Selection._beyond_refused`): else it only absorbs part of an effect beyond the candidates' physics.

thermal_warmup's time constant is profiled against the model's other causes (`calib.diagnose.warmup`): again at a
step whose model changed since, for the candidate while it is open (its curvature must still be significant) and for
the warm-up once chosen (`Selection.profile_warmup`).

The joint error map (cyclic_error of any order, `calib.diagnose.joint_map`) is tried once the causes of few
parameters are exhausted. When it joins, every cause chosen before it is judged again with the map in the model
(`calib.diagnose.rejudge`); one whose gain the map now explains leaves, and is not tried again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from scipy.special import fdtrc  # the F survival function (scipy.stats: ~1 s to import)

from trackcal.calib.diagnose.changepoint import SHIFT, relabel_shift
from trackcal.calib.diagnose.crossval import Validator
from trackcal.calib.diagnose.fits import Context, Fit, n_extra, whole_fit
from trackcal.calib.diagnose.joint_map import CAUSE as MAP
from trackcal.calib.diagnose.joint_map_fit import ErrorMapFit
from trackcal.calib.diagnose.judge import Candidate, Trial, judge_cause, judge_map
from trackcal.calib.diagnose.plausibility import implausible
from trackcal.calib.diagnose.rejudge import corrected_by_map, redundant_causes
from trackcal.calib.diagnose.warmup import warmup_candidate
from trackcal.calib.identify.solver import IdentificationError
from trackcal.calib.model.extension import ExtensionError

ALPHA = 1e-3  # the F test's level, divided among the causes left at each step
WARMUP = "thermal_warmup"


@dataclass
class Selection:
    """Where forward selection stands: the causes chosen and those still open, the current model's fit, every
    candidate judged so far. `start` sets it up, `step` takes one step."""

    ctx: Context
    val: Validator
    folds: int
    seed: int
    open_causes: list[str]  # causes of few parameters not yet chosen
    current: Fit  # the whole-table fit of `fitted`
    map_open: bool  # the full joint error map: tried once the low-order causes are exhausted
    chosen: tuple[str, ...] = ()  # the selected causes, in order
    fitted: tuple[str, ...] = ()  # those fitted by `calib.diagnose.fits` (the joint error map is held at its own fit)
    map_fit: ErrorMapFit | None = None
    map_edf: float = 0.0  # the map's effective number of parameters
    map_base: tuple[str, ...] = ()  # the causes the map was fitted with
    hold_first: float | None = None  # the geometric model's held-out RMS on the first step's folds
    candidates: list[Candidate] = field(default_factory=list)  # every candidate of every step
    selected: list[Candidate] = field(default_factory=list)  # the chosen ones, in order
    steps: int = 0
    untested: bool = False  # a candidate passed the F test and BIC where no held-out check was possible or could pass
    warm_rest: tuple[str, ...] = ()  # the causes thermal_warmup's tau was last profiled against (`profile_warmup`)

    @classmethod
    def start(cls, ctx: Context, folds: int, seed: int, causes: tuple[str, ...]) -> Selection:
        val = Validator(ctx, folds, seed)
        open_causes = [c for c in causes if c == SHIFT or c in ctx.features]
        return cls(ctx, val, folds, seed, open_causes, whole_fit(ctx, ()), MAP in open_causes)

    @property
    def n_obs(self) -> int:
        return 3 * len(self.ctx.table)

    @property
    def n_geo(self) -> int:
        """The geometric model's parameters (stations and points included)."""
        return self.n_obs - self.ctx.geo.dof

    def step(self) -> bool:
        """One forward-selection step: every open candidate judged against the current model (the joint error map
        when none of the others is significant), the best significant one accepted. False when none is (or none
        is left): the selection stops."""
        self.profile_warmup()
        if not (self.open_causes or self.map_open):
            return False
        self.steps += 1
        alpha = ALPHA / max(len(self.open_causes), 1)
        free = self.n_obs - self.n_geo - self.map_edf
        judged = (
            judge_cause(self.ctx, self.val, self.fitted, self.current, cause, self.n_obs, free, alpha, self.steps)
            for cause in self.open_causes
        )
        trial = [t for t in judged if t is not None]
        self.untested |= any(t.untested for t in trial)
        if self.map_open and not any(t.candidate.significant for t in trial):
            # cyclic_error's low-order form (if chosen) gives way to the map of any order; judged last, since a
            # generic map would absorb a compliance or an encoder scale of few parameters
            self.map_open = False
            base = tuple(c for c in self.fitted if c != MAP)
            found = judge_map(
                self.ctx, self.val, base, self.current, self.n_obs, self.n_geo, alpha, self.steps, self.folds, self.seed
            )
            trial += [] if found is None else [found]
        self.candidates.extend(t.candidate for t in trial)
        # refused for their physical range (not for a confound of the campaign order: `calib.diagnose.confounds`)
        refused = [
            t
            for t in trial
            if "implausible" in t.candidate.detail
            and not isinstance(t.fit, ErrorMapFit)
            and implausible(t.fit.extension, t.fit.ext)
        ]
        for t in trial:
            why = self._beyond_refused(t, refused, free, alpha) if t.candidate.significant else None
            if why is not None:
                t.candidate.significant = False
                t.candidate.detail["implausible"] = [why]
        winners = [t for t in trial if t.candidate.significant]
        if not winners:
            return False
        best = max(
            winners, key=lambda t: t.candidate.gain_mm if t.candidate.gain_mm is not None else -t.candidate.delta_bic
        )
        self.hold_first = best.candidate.holdout_base_mm if self.steps == 1 else self.hold_first
        if isinstance(best.fit, ErrorMapFit):
            self._join_map(best.candidate, best.fit, alpha)
        else:
            self.selected.append(best.candidate)
            self.chosen = (*self.chosen, best.candidate.cause)
            self.open_causes.remove(best.candidate.cause)
            self.fitted = (*self.fitted, best.candidate.cause)
            self.current = best.fit
        return True

    def _beyond_refused(self, win: Trial, refused: list[Trial], free: float, alpha: float) -> str | None:
        """None, or why the winner `win` is refused: a candidate refused as unphysical (outside its physical range,
        `calib.diagnose.plausibility`) that fits the table better is put in the model as a nuisance (its parameters
        free), and the winner must still pass the F test on top of it.
        An effect beyond every candidate's physical range (a warm-up of 3000 ppm on a narrow UR10 campaign of 15 poses)
        leaves a residual that a cause of other physics absorbs in part, with a held-out gain of its own (a nest's sag:
        the reflectors are measured one block of time after the other) and a model worse on poses measured later."""
        if isinstance(win.fit, ErrorMapFit):
            return None
        ctx, cause = self.ctx, win.candidate.cause
        for r in (r for r in refused if r.fit.rss < win.fit.rss and r.candidate.cause != cause):
            base = (*self.fitted, r.candidate.cause)
            try:
                nuisance, both = whole_fit(ctx, base), whole_fit(ctx, (*base, cause))
            except (IdentificationError, ExtensionError):
                continue
            added, dof = n_extra(ctx, (cause,)), free - n_extra(ctx, (*base, cause))
            if dof <= 0 or both.rss <= 0:
                continue
            f = ((nuisance.rss - both.rss) / added) / (both.rss / dof)
            p = float(fdtrc(added, dof, f)) if f > 0 else 1.0
            if p >= alpha:
                return (
                    f"{cause}: beside {r.candidate.cause} fitted as a nuisance (refused as unphysical, it fits "
                    f"better) its F test gives p = {p:.2g}: it absorbs part of an effect beyond the candidates' "
                    "physical ranges"
                )
        return None

    def profile_warmup(self) -> None:
        """thermal_warmup's tau and pivot form profiled again at the fit of the model's other causes when they changed
        since it was last (the module's docstring). An open candidate whose curvature is no longer significant there
        is not judged again (thermal_drift describes the growth); a chosen one takes its new tau, and the fits of its
        old one are let go. Once the joint error map joined, the map holds the warm-up it was fitted with."""
        ctx = self.ctx
        rest = tuple(c for c in self.fitted if c != WARMUP)
        chosen = WARMUP in self.fitted
        if (
            WARMUP not in ctx.features
            or rest == self.warm_rest
            or self.map_fit is not None
            or "thermal_drift" in rest
            or not (chosen or WARMUP in self.open_causes)
        ):
            return
        self.warm_rest = rest
        old = ctx.features[WARMUP]
        try:
            at = whole_fit(ctx, rest)
            table = (
                ctx.table if at.shift is None else relabel_shift(ctx.table, at.shift["station"], at.shift["after_t_s"])
            )
            ext, _ = warmup_candidate(ctx.chain, table, at, ctx.noise, ctx.params, curvature=not chosen)
        except (IdentificationError, ExtensionError):
            return
        if ext is None:
            self.open_causes.remove(WARMUP)
            return
        ctx.features[WARMUP] = ext
        for key in [k for k in ctx.fits if WARMUP in k]:
            del ctx.fits[key]
        for key in [k for k in self.val.cache if WARMUP in k[0]]:
            del self.val.cache[key]
        for key in [k for k, (parts, _) in ctx.combined.items() if any(x is old for x in parts)]:
            del ctx.combined[key]
        if chosen:
            try:
                self.current = whole_fit(ctx, self.fitted)
            except IdentificationError:  # the model at its new tau cannot be fitted: it stays at the old one
                ctx.features[WARMUP] = old
                ctx.fits[tuple(sorted(self.fitted))] = self.current

    def _join_map(self, best: Candidate, mf: ErrorMapFit, alpha: float) -> None:
        """The map joins: it replaces a low-order cyclic_error; causes chosen before it that it makes redundant
        leave (`calib.diagnose.rejudge`) and the map is judged again on what remains, at its order, with its ridge
        chosen again (if it would not pass, nothing leaves); later steps hold the map at this fit, the rows' angles
        corrected by it."""
        ctx = self.ctx
        low = next((c for c in self.selected if c.cause == MAP), None)
        self.selected = [c for c in self.selected if c is not low]
        self.chosen = tuple(c for c in self.chosen if c != MAP)
        kept = tuple(c for c in self.fitted if c != MAP)
        fitted, removed, judged = redundant_causes(ctx, self.val, kept, mf, self.n_obs)
        # the search's linearised problem (its Problem with the map's features, 6 KB per row of Series B, and its Gram
        # matrix) served the held-out test and `Rejudge`, both done: not held while the map is judged again (issue 41)
        mf.linearised = None
        again = None
        if removed:
            start = whole_fit(ctx, fitted)
            # the other whole-table fits (each with its Jacobian) are cleared after the join whatever it decides, and
            # judging the map again needs none of them: not held meanwhile (issue 41)
            for key in [k for k, fit in ctx.fits.items() if fit is not start]:
                del ctx.fits[key]
            again = judge_map(
                ctx,
                self.val,
                fitted,
                start,
                self.n_obs,
                self.n_geo,
                alpha,
                self.steps,
                self.folds,
                self.seed,
                (max(mf.orders.values()),),
            )
        if removed and (again is None or not again.candidate.significant):
            fitted, removed, judged = kept, [], {}
        if removed:
            self.candidates[self.candidates.index(best)] = again.candidate
            best, mf = again.candidate, again.fit
            best.detail["removed"] = removed
            self.selected = [c for c in self.selected if c.cause in fitted]
            self.chosen = tuple(c for c in self.chosen if c in fitted)
        for c in self.selected:
            if SHIFT not in fitted:  # their fits had the station shift that left
                c.detail = {k: v for k, v in c.detail.items() if k not in ("station", "after_t_s")}
            if c.cause in judged:
                c.detail["with_map"] = judged[c.cause]
        if low is not None:  # the map replaces the low-order cyclic_error
            best.detail["replaces"] = {"n_params": low.n_params, "holdout_rms_mm": low.holdout_rms_mm}
        self.selected.append(best)
        self.chosen = (*self.chosen, MAP)
        self.fitted = fitted
        mf.linearised = None  # the map is held at this fit from here on
        self.map_fit, self.map_edf, self.map_base = mf, mf.effective_params, fitted
        ctx.table = corrected_by_map(ctx.table, mf)
        ctx.fits.clear()
        self.val.cache.clear()
        self.current = whole_fit(ctx, fitted)
