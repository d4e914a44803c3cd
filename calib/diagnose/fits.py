"""The candidate models' fits: the geometric model plus a tuple of causes, fitted on the whole table or on rows.

A model's whole-table fit (`whole_fit`, no covariance: enough to compare residual sums and to cross-validate,
`calib.diagnose.crossval`) starts where the best-fitting of its sub-models stopped (`warm_start`), or from the
geometric solution (a moved station where it was). `context` builds what every fit of one diagnosis shares: each
cause's extension on the whole table, keeping only the parameters the data can see (`visible_extension`), and the
geometric prediction the change point is scanned on. `fit_cause` / `final_fit` identify a chosen model with its
covariance.
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from trackcal.calib.diagnose.changepoint import SHIFT, SHIFT_SUFFIX, relabel_shift, shift_scan
from trackcal.calib.diagnose.extensions import THERMAL_FORMS, build_extension
from trackcal.calib.diagnose.warmup import warmup_candidate
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import (
    Identification,
    IdentificationError,
    Problem,
    Rows,
    State,
    Station,
    identify,
    model_points,
    predict_points,
    solve,
)
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.extension import Extension, combine
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import Param

SINGULAR = 1e-7  # smallest / largest singular value of the column-scaled Jacobian of an identifiable fit
VISIBLE = 1e-6  # an extension column whose part independent of the geometric ones is below this is dropped
LEVER_RATIO = 1e-3  # a joint moving the points less than this fraction of the most moving joint is not seen


def rms(residuals: np.ndarray) -> float:
    return float(np.sqrt(np.mean(residuals**2)))


@dataclass
class Fit:
    """A fitted model (no covariance): enough to predict rows and to compare residual sums."""

    dev: np.ndarray
    stations: dict[str, Station]
    points: dict[str, np.ndarray]
    ext: np.ndarray
    extension: Extension | None
    rss: float  # whitened
    n_cols: int
    gram: np.ndarray  # J^T J of the whitened Jacobian J at the solution (the identifiability check, cross-validation)
    grad: np.ndarray  # J^T r
    problem: Problem  # forms J's rows on demand (`rows`): the fit holds no (3N, n_cols) array (issue 41)
    state: State  # the solution, as `problem` takes it
    shift: dict | None = None  # {"station", "after_t_s"}

    @property
    def r(self) -> np.ndarray:
        """The whitened residual vector (3N,) at the solution, formed when asked for (the structure tests of the chosen
        model ask; the fits of the other candidates are not held with it)."""
        return self.problem.residual(self.state)

    @property
    def residuals(self) -> np.ndarray:
        """(N, 3) measured - predicted, mm, station frames, formed when asked for: a candidate's judgement asks once,
        a fold's fit (a change point that moved) and thermal_drift's rival forms never (issue 41)."""
        return self.problem.xyz - self.problem.predicted(self.state)

    def rows(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The whitened residuals (3n,) and Jacobian rows (3n, n_cols) of `rows` at the solution, in that order."""
        return self.problem.residual_and_jacobian(self.state, rows)


@dataclass
class Context:
    chain: Chain
    table: MeasurementTable
    params: list[Param]
    noise: TrackerNoise | None
    geo: Identification
    features: dict[str, Extension]  # cause -> its extension on the whole table (visible parameters only)
    geo_base: np.ndarray  # (N, 3) geometric prediction in the robot base frame (the change-point scan)
    dropped: dict[str, list[str]] = field(default_factory=dict)  # cause -> parameters the data cannot see
    fits: dict[tuple, Fit] = field(default_factory=dict)  # whole-table fits by sorted causes
    unwhiten: np.ndarray | None = None  # (N, 3, 3) inverse whitening of each row (tracker weighting)
    executor: Executor | None = None  # runs independent pieces (folds) at once when given (threads)
    scans: dict[bytes | None, tuple | None] = field(default_factory=dict)  # change points found, by rows (`scan`)
    combined: dict[tuple, tuple] = field(default_factory=dict)  # extensions combined (`extension_of`)
    rows: Rows | None = None  # the whole table's layout (solver.Rows), shared by its fits whatever their features


def _whole_fit(
    ctx: Context, table: MeasurementTable, ext: Extension | None, max_iter: int, start: Fit | None = None
) -> Fit:
    """Levenberg-Marquardt from `start` (a fit of fewer causes, or of the same causes on more rows; its parameters
    where the model shares them, the others at zero) or from the geometric solution; a moved station starts where
    it was."""
    problem = Problem(ctx.chain, table, ctx.geo.points, ctx.params, ctx.noise, ctx.geo.dev, ext, rows=ctx.rows)
    if table is ctx.table:
        ctx.rows = problem.rows
    at = ctx.geo if start is None else start
    st, values = at.stations, _ext_values(at.extension, at.ext)
    problem.initial = State(
        at.dev.copy(),
        [st.get(s, st[s.removesuffix(SHIFT_SUFFIX)]) for s in problem.station_ids],
        np.array([at.points[p] for p in problem.point_ids]),
        np.array([values.get(key, 0.0) for key in _ext_keys(ext)]),
    )
    sol = solve(problem, problem.initial, max_iter)
    state = sol.state
    # summed over the row chunks: a whole Jacobian (with the joint error map among the causes, 3 x ~900 float64 per
    # row: 22 KB per row of a KR-270 table) was held by every fit kept in ctx.fits (issue 41); the solver's, moved by
    # its last step, when it stopped on one below 1e-9 of the noise (a pass over the rows less per fit, issue 41)
    gram, grad, rss = problem.normal_equations(state) if sol.normal is None else sol.normal
    if not identifiable(gram):
        raise IdentificationError(f"{problem.source}: the model cannot be identified from these rows")
    return Fit(
        state.dev,
        dict(zip(problem.station_ids, state.stations, strict=True)),
        {p: state.points[i] for i, p in enumerate(problem.point_ids)},
        state.ext,
        ext,
        rss,
        problem.n_cols,
        gram=gram,
        grad=grad,
        problem=problem,
        state=state,
    )


def _ext_keys(ext: Extension | None) -> list[tuple[str, str]]:
    """(cause, parameter name) of every parameter of an extension, in order."""
    return [] if ext is None else [(cause, nm) for cause, names in ext.parts() for nm in names]


def _ext_values(ext: Extension | None, values) -> dict[tuple[str, str], float]:
    return dict(zip(_ext_keys(ext), np.asarray(values, dtype=float).tolist(), strict=True))


def warm_start(ctx: Context, causes: tuple[str, ...]) -> Fit | None:
    """The whole-table fit closest to the data (least residual) among the sub-models of `causes` already fitted
    (None: none): a model with one cause more starts where the best model without it stopped. Both stop at the same
    minimum (to 1e-9 of the noise, the solver's step test), and a fit of a hard pair (cyclic_error with
    encoder_scale, 25 iterations from the geometric solution on the UR10's Series B) is not walked again for every
    cause tried beside it (issue 26). Of two sub-models of as many causes, the one that already walked the pair's
    valley fits better: from it, cyclic_error + encoder_scale + backlash takes 6 iterations, from cyclic_error +
    backlash 22 (the first of the largest, as chosen before, was either)."""
    inside = [ctx.fits[key] for key in list(ctx.fits) if set(key) < set(causes)]
    return min(inside, key=lambda fit: fit.rss) if inside else None


def identifiable(gram: np.ndarray) -> bool:
    """Whether a Gram matrix J^T J is regular (smallest / largest singular value of the column-scaled J
    above SINGULAR)."""
    diag = np.diag(gram)
    if np.any(diag <= 0):  # a column without information (a training set's downdate can leave rounding below 0)
        return False
    d = np.sqrt(diag)
    ev = np.linalg.eigvalsh(gram / np.outer(d, d))
    return bool(ev[0] >= SINGULAR**2 * ev[-1])


def scan(ctx: Context, rows: np.ndarray | None = None) -> tuple[str, float] | None:
    """The change point of `rows` (all by default), `shift_scan`'s, found once per set of rows: the scan sees the
    geometric prediction, the stations, times and measured points, which neither the models tried nor the joint
    map's correction of the angles change (issue 26: the same training rows were scanned for every model)."""
    key = None if rows is None else np.asarray(rows).tobytes()
    if key not in ctx.scans:
        table = ctx.table if rows is None else ctx.table.subset(rows)
        ctx.scans[key] = shift_scan(ctx.geo_base if rows is None else ctx.geo_base[rows], table)
    return ctx.scans[key]


def fit_model(ctx: Context, causes: tuple[str, ...], rows: np.ndarray | None = None, max_iter: int = 100) -> Fit:
    """Fit the geometric model plus `causes` on `rows` of the table (all by default), the whole table from
    `warm_start`, rows from the geometric solution; station_shift is found by the scan on those rows, then fitted
    with the rest."""
    table = ctx.table if rows is None else ctx.table.subset(rows)
    shift = None
    if SHIFT in causes:
        found = scan(ctx, rows)
        if found is None:
            raise IdentificationError(f"{table.source}: too few rows for a change point")
        shift = {"station": found[0], "after_t_s": found[1]}
        table = relabel_shift(table, *found)
    ext = extension_of(ctx, causes, rows)
    # a fold's own fit (a change point that moved) starts from the geometric solution, as before issue 26: its
    # training rows can leave the shifted station's pose weakly determined, and its held-out rows then depend
    # on where in that valley the fit stops (3e-6 mm of a 0.23 mm held-out RMS when started elsewhere)
    fit = _whole_fit(ctx, table, ext, max_iter, warm_start(ctx, causes) if rows is None else None)
    fit.shift = shift
    return fit


def whole_fit(ctx: Context, causes: tuple[str, ...]) -> Fit:
    key = tuple(sorted(causes))
    if key not in ctx.fits:
        ctx.fits[key] = fit_model(ctx, causes)
    return ctx.fits[key]


def extension_of(
    ctx: Context, causes: tuple[str, ...], rows: np.ndarray | None = None, main: str | None = None
) -> Extension | None:
    """The causes' extensions combined (station_shift has none), `main` naming it (default: the first); combined once
    per set of extensions (thermal_form tries several under one name: they are told apart by identity, and the
    cache holds them so that identity is not reused)."""
    parts = [ctx.features[c] for c in causes if c != SHIFT]
    if not parts:
        return None
    name = main if main in causes and main != SHIFT else None
    key = (tuple(id(x) for x in parts), name)
    if key not in ctx.combined:
        ctx.combined[key] = (parts, combine(parts, name))
    ext = ctx.combined[key][1]
    return ext if rows is None else ext.subset(rows)


def predict_rows(ctx: Context, fit: Fit, rows: np.ndarray, ext: Extension | None) -> np.ndarray | None:
    """Predictions of `rows` (station frames) with a fit; None when a row's station is unknown to it."""
    table = ctx.table.subset(rows)
    if fit.shift is not None:
        table = relabel_shift(table, fit.shift["station"], fit.shift["after_t_s"])
    if any(s not in fit.stations for s in table.station) or any(p not in fit.points for p in table.point):
        return None
    return predict_points(ctx.chain, ctx.params, fit.dev, fit.stations, fit.points, table, ext, fit.ext)


def visible_extension(chain, table, geo: Identification, noise, params, cause: str) -> tuple[Extension | None, list]:
    """The extension `cause` keeping only parameters the data can see: acting on a joint whose rotation
    moves the measured points (lever above LEVER_RATIO of the largest joint's), with Jacobian columns (at
    the geometric fit) that have a part independent of the geometric, station and point columns and of
    each other. Returns it and the dropped names."""
    ext = build_extension(cause, chain, table)
    if ext.size == 0:
        return None, []
    seen = np.ones(ext.size, dtype=bool)
    if ext.joint_features is not None:
        tool = np.array([geo.points[p] for p in table.point])
        d_q = Kinematics(chain, params).jacobian(np.radians(table.q_deg), tool, geo.dev).d_q
        lever = np.sqrt(np.mean(np.sum(d_q**2, axis=1), axis=0))  # (n,) mm per rad
        acts = ext.joint_features.moves()  # (n, e): which joints each parameter moves
        seen = acts[lever >= LEVER_RATIO * lever.max()].any(axis=0)
    problem = Problem(chain, table, geo.points, params, noise, geo.dev, ext)
    state = State(
        geo.dev,
        [geo.stations[s] for s in problem.station_ids],
        np.array([geo.points[p] for p in problem.point_ids]),
        np.zeros(ext.size),
    )
    _, jm = problem.residual_and_jacobian(state)
    k, e = len(params), ext.size
    cols = np.r_[np.arange(k), np.arange(k + e, jm.shape[1])]
    base = jm[:, cols]
    base = base / np.where(np.linalg.norm(base, axis=0) > 0, np.linalg.norm(base, axis=0), 1.0)
    q, _ = np.linalg.qr(base)
    je = jm[:, k : k + e]
    norms = np.linalg.norm(je, axis=0)
    free = je - q @ (q.T @ je)
    keep: list[int] = []
    basis = np.zeros((jm.shape[0], 0))
    for i in np.argsort(-np.linalg.norm(free, axis=0) / np.where(norms > 0, norms, 1.0)):
        v = free[:, i] - basis @ (basis.T @ free[:, i])
        if seen[i] and norms[i] > 0 and np.linalg.norm(v) > VISIBLE * norms[i]:
            keep.append(int(i))
            basis = np.column_stack([basis, v / np.linalg.norm(v)])
    keep.sort()
    dropped = [n for i, n in enumerate(ext.names) if i not in keep]
    if not keep:
        return None, dropped
    if not dropped:
        return ext, []
    return build_extension(cause, chain, table, names=[ext.names[i] for i in keep]), dropped


def n_extra(ctx: Context, causes: tuple[str, ...]) -> int:
    """Parameters the causes add to the geometric model (station_shift: a station's 7)."""
    return sum(7 if c == SHIFT else ctx.features[c].size for c in causes)


class CauseFit(NamedTuple):
    """The geometric model fitted with one cause, or several joined by "+"."""

    result: Identification
    extension: Extension | None
    table: MeasurementTable  # as fitted (station_shift relabels the rows after the change point)
    shift: dict | None  # station_shift: {"station", "after_t_s"}
    n_extra: int  # parameters the causes add


def fit_cause(
    chain, table, tool, params, noise, cause: str, geometric: Identification | None = None
) -> CauseFit | None:
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
            ext, dropped = (
                warmup_candidate(chain, table, geo, noise, params)
                if c == "thermal_warmup"
                else visible_extension(chain, table, geo, noise, params, c)
            )  # tau profiled (`warmup`)
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
    forms = [arm] + [
        build_extension("thermal_drift", ctx.chain, ctx.table, names=[f]) for f in THERMAL_FORMS if f not in arm.names
    ]
    rss = []
    for ext in forms:
        ctx.features["thermal_drift"] = ext
        try:
            rss.append(fit_model(ctx, ("thermal_drift",)).rss)
        except IdentificationError:
            rss.append(np.inf)
    return forms[int(np.argmin(rss))]
