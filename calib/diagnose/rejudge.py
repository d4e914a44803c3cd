"""The causes chosen before the joint error map, judged again once the map joins the model.

When the map (cyclic_error of any order, `calib.diagnose.joint_map`) joins, every cause chosen before it is judged
again with the map in the model (`Rejudge`: BIC and held-out gain); one whose gain the map now explains leaves
(`redundant_causes`), and is not tried again. On the real UR10 (Series B) an encoder scale and a station shift had
joined a two-harmonic joint error and gained nothing beside the map; kept, they made its prediction of Series D
worse. Later steps see the rows' angles corrected by the map (`corrected_by_map`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import fdtrc  # the F survival function (scipy.stats: ~1 s to import)

from trackcal.calib.diagnose.changepoint import SHIFT, relabel_shift
from trackcal.calib.diagnose.crossval import TIME_CAUSES, Validator
from trackcal.calib.diagnose.fits import Context, extension_of, whole_fit
from trackcal.calib.diagnose.joint_map_fit import ErrorMapFit, MapEvidence
from trackcal.calib.io.table import MeasurementTable


class Rejudge:
    """The causes chosen before the map judged again with the map in the model: a cause stays only while the
    BIC and a held-out gain on its folds (by pose; by time block for a time-dependent cause) still agree, the
    map at its order and ridge on both sides. A cause that is a function of each joint's own angle
    (encoder_scale) or shares much of the map's signal otherwise got its gain from what the map now
    explains; kept, it only extrapolates beyond the angles the table covers. The F test is reported, not
    decisive here: against a ridge-penalised map the parameters a cause adds are a difference of effective
    parameter counts (below one when the map takes its signal over), which no F distribution calibrates;
    the BIC takes effective counts as they are.

    Every model is one linearised problem (`joint_map_fit.MapEvidence`) with some causes held at zero: one
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
            table = (
                ctx.table
                if start.shift is None
                else relabel_shift(ctx.table, start.shift["station"], start.shift["after_t_s"])
            )
            self.roots[shifted] = MapEvidence(
                ctx.chain, table, ctx.params, ctx.noise, self.base, start, self.mf, ctx.executor
            )
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
            hold, without = (
                (self.figure(fitted, scheme), self.figure(rest, scheme)) if passes and scheme else (None, None)
            )
            out[c] = {
                "f_pvalue": p,
                "delta_bic": d_bic,
                "n_params": k,
                "cv_scheme": scheme,
                "holdout_rms_mm": hold,
                "holdout_without_mm": without,
                "significant": bool(passes and (hold is None or hold < without)),
            }
        return out


def corrected_by_map(table: MeasurementTable, mf: ErrorMapFit) -> MeasurementTable:
    """The table with every joint angle moved by the fitted map (q_true = q_read + e_j(q_read))."""
    ext, theta = mf.extension, mf.identification.ext
    offsets = ext.joint_features.columns(slice(mf.n_base, None)).offsets(theta[mf.n_base :])
    out = table.subset(np.arange(len(table)))
    out.q_deg = table.q_deg + np.degrees(offsets)
    return out


def redundant_causes(
    ctx: Context, val: Validator, fitted: tuple[str, ...], mf: ErrorMapFit, n_obs: int
) -> tuple[tuple[str, ...], list[dict], dict[str, dict]]:
    """(the causes of `fitted` that stay beside the map `mf`, those that left with their figures, the figures of
    those that stay): the causes the map makes redundant leave one at a time (of those that no longer pass, the one
    whose BIC gains most by leaving)."""
    removed, rejudge, judged = [], Rejudge(ctx, val, fitted, mf, n_obs), {}
    while fitted:
        judged = rejudge.judge(fitted)
        weak = [c for c in fitted if not judged[c]["significant"]]
        if not weak:
            break
        gone = max(weak, key=lambda c: judged[c]["delta_bic"])
        fitted = tuple(c for c in fitted if c != gone)
        removed.append({"cause": gone, **judged.pop(gone)})
    return fitted, removed, judged
