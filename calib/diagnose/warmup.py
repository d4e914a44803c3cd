"""The warm-up's time constant: thermal_warmup's growth e_inf (1 - exp(-(t - t0) / tau)) is linear in e_inf at a
given tau, so tau is profiled: at each tau of a grid over the physical range (`calib.diagnose.plausibility`: 5 min
to 8 h) e_inf is fitted linearly, and the tau of least residual is kept (refined by finer grids between its grid
neighbours).

The profile is taken at the solution of the model without the warm-up, linearised: the residual r and the Jacobian of
the geometric, station and point columns (and those of the model's other causes) B are those of that fit; the growth
column of a tau is the reflector's lever about the
pivot (the Jacobian column of a unit growth) times the row's warm-up shape. The residual sum left by a tau is
|r_perp|^2 - (c_perp . r_perp)^2 / |c_perp|^2, `_perp` the part orthogonal to B: one Jacobian per pivot form, then
matrix products over a grid's taus at once. The effect is small (micrometres against metres), where the model is
linear to far below the noise (as `calib.diagnose.crossval`'s one-step folds).

The linear drift (thermal_drift, g = e t) is the warm-up's limit of a tau long against the campaign. The warm-up is a
candidate only when its curvature is significant: the residual sum at its tau against the linear drift's, an F test
of one degree of freedom (tau) at ALPHA; else the campaign cannot tell a warm-up from a drift, and the linear drift
(the candidate of fewer assumptions) is left to describe it. tau's 95 % interval is the profile's: the taus whose
residual sum is within chi2(1, 0.95) of the least, in units of the residual variance (Venzon and Moolgavkar's
profile likelihood interval, 1988).

At the first step of diagnose that model is the geometric one. Once other causes are in the model, tau is profiled
again against them (`calib.diagnose.selection`): a cause still in the residual of the geometric fit (an encoder scale
over a campaign measured station by station is partly a function of time) biases the tau profiled there, and the
warm-up of the wrong tau leaves a time signature that another cause then takes up (issue 36, the hidden generator's
seed 5002, encoder scale + warm-up: a range scale of one station joined on 0.3 um).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from trackcal.calib.diagnose.extensions import WARMUP_FORMS, build_extension, warmup_growth
from trackcal.calib.diagnose.plausibility import WARMUP_TAU_MAX_S, WARMUP_TAU_MIN_S
from trackcal.calib.identify.solver import Problem, State, Station
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.extension import Extension, combine

ALPHA = 1e-3  # the curvature's F test (selection's level for one candidate)
GRID = 60  # taus of the profile, log-spaced over the physical range
# taus of each finer grid between the least's neighbours, and how many: the last step is the grid's times
# (2 / (FINE - 1)) ** REFINE, 7.6e-5 of log tau (scipy's bounded Brent search to 1e-4 took the import of
# scipy.optimize, 0.12 s of CPU of a diagnosis of the UR10's Series B, issue 41)
FINE, REFINE = 65, 2
CI_GRID = 400  # taus of the interval's grid over the physical range
BLOCK = 2**20  # values of the growth columns formed at once (8 MB)
CHI2_1_95 = 3.841458820694124  # chi-square quantile, 1 degree of freedom, 0.95 (tables: 3.841)


class Solution(Protocol):
    """A fitted model the profile is taken at: an `Identification` (the geometric one) or a diagnosis's `Fit`."""

    dev: np.ndarray
    stations: dict[str, Station]
    points: dict[str, np.ndarray]
    extension: Extension | None
    ext: np.ndarray


def _orthogonal(chain: Chain, table: MeasurementTable, at: Solution, noise, params, form: str):
    """(r_perp, lever, basis Q, residual dof): the whitened residual of the fit `at` (the geometric one, or a fit with
    other causes: its `extension` and `ext`) and a unit growth's column about the form's pivot, both before removing
    the geometric, station and point columns and those of the other causes (orthonormal basis Q)."""
    ext = build_extension("thermal_warmup", chain, table, names=[form])
    ext = Extension(ext.cause, ext.names, ext.units, ext.to_boundary, growth=np.ones((len(table), 1)), pivot=ext.pivot)
    others = at.extension
    problem = Problem(chain, table, at.points, params, noise, at.dev, ext if others is None else combine([others, ext]))
    state = State(
        at.dev,
        [at.stations[s] for s in problem.station_ids],
        np.array([at.points[p] for p in problem.point_ids]),
        np.zeros(1) if others is None else np.r_[np.asarray(at.ext, dtype=float), 0.0],
    )
    r, jm = problem.residual_and_jacobian(state)
    k = len(params) + (0 if others is None else others.size)
    base = np.delete(jm, k, axis=1)
    norms = np.linalg.norm(base, axis=0)
    q, _ = np.linalg.qr(base[:, norms > 0] / norms[norms > 0])
    r_perp = r - q @ (q.T @ r)
    return r_perp, jm[:, k], q, len(r) - base.shape[1] - 1


def _rss(r_perp: np.ndarray, lever: np.ndarray, q: np.ndarray, shapes: np.ndarray) -> np.ndarray:
    """(g,) the residual sum left by each of g growth shapes (N, g): their growth columns (3 N, g) made orthogonal to
    Q at once."""
    c = lever[:, None] * np.repeat(shapes, 3, axis=0)
    c -= q @ (q.T @ c)
    cc, cr = np.einsum("ig,ig->g", c, c), r_perp @ c
    return float(r_perp @ r_perp) - np.divide(cr**2, cc, out=np.zeros_like(cc), where=cc > 0)


def profile(chain: Chain, table: MeasurementTable, geo: Solution, noise, params) -> dict:
    """The profile of tau over the physical range at the fit `geo` (`_orthogonal`): {"form", "tau_s", "tau_ci95_s":
    [lo, hi], "rss", "rss_linear", "dof", "pvalue"} (the curvature's F test against the linear drift of the same
    pivot)."""
    from scipy.special import fdtrc  # lazy: identify imports this module, not this test (scipy: its start-up)

    t = np.asarray(table.t_s, dtype=float)
    t0 = float(t.min()) if len(t) else 0.0
    grid = np.log(np.geomspace(WARMUP_TAU_MIN_S, WARMUP_TAU_MAX_S, GRID))
    fine = np.linspace(grid[0], grid[-1], CI_GRID)
    best = None
    for form in WARMUP_FORMS:
        r_perp, lever, q, dof = _orthogonal(chain, table, geo, noise, params, form)

        def rss(log_taus, r_perp=r_perp, lever=lever, q=q):
            """(len(log_taus),) the residual sums at the taus exp(log_taus), BLOCK values of their columns at once."""
            step = max(1, BLOCK // len(r_perp))
            return np.concatenate(
                [
                    _rss(r_perp, lever, q, warmup_growth(t[:, None], np.exp(log_taus[a : a + step])[None, :], t0))
                    for a in range(0, len(log_taus), step)
                ]
            )

        # the grid's least, then REFINE times a finer grid between the neighbours of the least so far (the profile
        # between them has one minimum)
        xs, values = grid, rss(grid)
        for _ in range(REFINE):
            i = int(np.argmin(values))
            xs = np.linspace(xs[max(i - 1, 0)], xs[min(i + 1, len(xs) - 1)], FINE)
            values = rss(xs)
        i = int(np.argmin(values))
        log_tau, least = float(xs[i]), float(values[i])
        linear = float(_rss(r_perp, lever, q, (t - t0)[:, None])[0])
        if best is None or least < best["rss"]:
            s2 = least / max(dof, 1)
            inside = fine[rss(fine) <= least + CHI2_1_95 * s2]
            ci = [float(np.exp(min(inside.min(), log_tau))), float(np.exp(max(inside.max(), log_tau)))]
            f = (linear - least) / s2 if s2 > 0 else 0.0
            best = {
                "form": form,
                "tau_s": float(np.exp(log_tau)),
                "tau_ci95_s": ci,
                "rss": least,
                "rss_linear": linear,
                "dof": int(dof),
                "pvalue": float(fdtrc(1, dof, f)) if f > 0 else 1.0,
            }
    return best


def warmup_candidate(
    chain: Chain, table: MeasurementTable, geo: Solution, noise, params, curvature: bool = True
) -> tuple[Extension | None, list[str]]:
    """thermal_warmup at its tau and pivot form profiled at the fit `geo` (the model without it), with its profile in
    `meta[FORMS]`; (None, [why]) when its curvature is not significant against the linear drift (the module's
    docstring), unless `curvature` is False (a warm-up already chosen, profiled again)."""
    if len(table) < 2 or np.ptp(table.t_s) <= 0:
        return None, ["tau: the rows span no time"]
    prof = profile(chain, table, geo, noise, params)
    if curvature and prof["pvalue"] >= ALPHA:
        return None, [
            f"tau: the growth's curvature is not significant against a linear drift (F test p = "
            f"{prof['pvalue']:.2g}): thermal_drift describes it"
        ]
    form = {"tau_s": prof["tau_s"], "tau_ci95_s": prof["tau_ci95_s"], "profile_pvalue": prof["pvalue"]}
    ext = build_extension("thermal_warmup", chain, table, names=[prof["form"]], form=form)
    return ext, []
