"""Candidate models fitted fast: whole-table fits without covariance, and their cross-validation.

A model is the geometric one plus a tuple of causes. Its whole-table fit starts where the best-fitting of its
sub-models stopped (`warm_start`), or from the geometric solution (a moved station where it was), and skips the
covariance.
A fold's fit is one Gauss-Newton step
from the whole-table fit on the training rows (the Gram matrix of the whole table minus the fold's
rows): the fold's solution is about a standard deviation away, where the model is linear to far below
the noise. Folds are whole poses (with edge folds: each joint's extreme poses held out, so that extrapolation is
judged), passes of the plan, or blocks of time within each station; a scheme whose training sets cannot identify
the model gives None, and the comparison moves to the next.
Candidate parameters the data cannot see are dropped before any fit.
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np

from trackcal.calib.diagnose.changepoint import SHIFT, SHIFT_SUFFIX, relabel_shift, shift_scan
from trackcal.calib.diagnose.extensions import build_extension
from trackcal.calib.diagnose.features import Extension, combine
from trackcal.calib.diagnose.significance import HeldOut
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import (
    Identification,
    IdentificationError,
    Problem,
    State,
    Station,
    predict_points,
    solve,
)
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.params import Param

TIME_CAUSES = ("thermal_drift", SHIFT, "thermal_warmup")
SINGULAR = 1e-7  # smallest / largest singular value of the column-scaled Jacobian of an identifiable fit
VISIBLE = 1e-6  # an extension column whose part independent of the geometric ones is below this is dropped
LEVER_RATIO = 1e-3  # a joint moving the points less than this fraction of the most moving joint is not seen
FOLD_ITERATIONS = 30
EDGE_SHARE = 0.1  # the share of each joint's poses, at either end of its range, an edge fold holds out


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
    residuals: np.ndarray
    r: np.ndarray  # whitened residual vector (3N,) at the solution
    jm: np.ndarray  # whitened Jacobian of the prediction (3N, n_cols) at the solution
    shift: dict | None = None  # {"station", "after_t_s"}


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


def _whole_fit(ctx: Context, table: MeasurementTable, ext: Extension | None, max_iter: int,
               start: Fit | None = None) -> Fit:  # fmt: skip
    """Levenberg-Marquardt from `start` (a fit of fewer causes, or of the same causes on more rows; its parameters
    where the model shares them, the others at zero) or from the geometric solution; a moved station starts where
    it was."""
    problem = Problem(ctx.chain, table, ctx.geo.points, ctx.params, ctx.noise, ctx.geo.dev, ext)
    at = ctx.geo if start is None else start
    st, values = at.stations, _ext_values(at.extension, at.ext)
    problem.initial = State(at.dev.copy(), [st.get(s, st[s.removesuffix(SHIFT_SUFFIX)]) for s in problem.station_ids],
                            np.array([at.points[p] for p in problem.point_ids]),
                            np.array([values.get(key, 0.0) for key in _ext_keys(ext)]))  # fmt: skip
    state = solve(problem, problem.initial, max_iter).state
    r, jm = problem.residual_and_jacobian(state)  # one pass for both (the solution's r and jm would be two)
    if not _identifiable(jm.T @ jm):
        raise IdentificationError(f"{problem.source}: the model cannot be identified from these rows")
    return Fit(state.dev, dict(zip(problem.station_ids, state.stations, strict=True)),
               {p: state.points[i] for i, p in enumerate(problem.point_ids)}, state.ext, ext, float(r @ r),
               problem.n_cols, problem.xyz - problem.predicted(state), r=r, jm=jm)  # fmt: skip


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


def _identifiable(gram: np.ndarray) -> bool:
    """Whether a Gram matrix J^T J is regular (smallest / largest singular value of the column-scaled J
    above SINGULAR)."""
    d = np.sqrt(np.diag(gram))
    if np.any(d == 0):
        return False
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


def extension_of(ctx: Context, causes: tuple[str, ...], rows: np.ndarray | None = None,
                 main: str | None = None) -> Extension | None:  # fmt: skip
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


def fold_rows(table: MeasurementTable, scheme: str, folds: int, seed: int,
              cut: tuple[str, float] | None = None) -> list[np.ndarray] | None:  # fmt: skip
    """Held-out rows of each fold: whole poses ("pose"), passes of the plan ("pass": the k-th measurement
    of each pose, station and point) or blocks of time within each station ("time"); None when the
    table has fewer than two groups.

    `cut` (station, after_t_s): a change point of that station. Its time blocks are then cut within each side
    of the change, block k of either side in fold k, so that every fold trains on rows before and after it: a
    station that moved in the last fifth of its block would otherwise have all its rows after the move in one
    fold, whose training rows then cannot know where the station went (leave-block-out cross-validation of a
    change point needs both segments in every training set)."""
    n = len(table)
    if scheme == "pose":
        poses = np.array(sorted(set(table.pose)))
        if len(poses) < 2:
            return None
        np.random.default_rng(seed).shuffle(poses)
        pose_arr = np.array(table.pose)
        return [np.flatnonzero(np.isin(pose_arr, g)) for g in np.array_split(poses, min(folds, len(poses)))]
    if scheme == "pass":
        seen: dict[tuple, int] = {}
        passes = np.zeros(n, dtype=int)
        for i in np.argsort(table.t_s, kind="stable"):
            key = (table.pose[i], table.station[i], table.point[i])
            passes[i] = seen.get(key, 0)
            seen[key] = passes[i] + 1
        labels = np.unique(passes)
        if len(labels) < 2:
            return None
        return [np.flatnonzero(np.isin(passes, g)) for g in np.array_split(labels, min(folds, len(labels)))]
    block = np.zeros(n, dtype=int)
    stations = np.array(table.station)
    for sid in set(table.station):
        rows = np.flatnonzero(stations == sid)
        rows = rows[np.argsort(table.t_s[rows], kind="stable")]
        sides = [rows] if cut is None or cut[0] != sid else [rows[table.t_s[rows] <= cut[1]],
                                                             rows[table.t_s[rows] > cut[1]]]  # fmt: skip
        for side in sides:
            for k, part in enumerate(np.array_split(side, folds)):
                block[part] = k
    groups = [np.flatnonzero(block == k) for k in range(folds)]
    groups = [g for g in groups if len(g)]
    return groups if len(groups) > 1 else None


def cross_validate(ctx: Context, causes: tuple[str, ...], folds: list[np.ndarray]) -> HeldOut | None:
    """Held-out errors of the model `causes` over the folds (`HeldOut`: per row, its squared error summed over
    every fold that held it out; `.rms_mm` the RMS of one coordinate); None when a training set cannot be
    identified or a held-out row cannot be predicted. The folds need not partition the rows (edge folds,
    `edge_rows`, hold out again rows a partition held out).

    Each fold's fit is one Gauss-Newton step from the whole-table solution on the training rows (the
    Gram matrix of the whole table minus the fold's rows): the fold's solution differs from the whole
    one by about a standard deviation, where the model is linear to far below the noise. A change point
    is searched again on the training rows; when it moves, that fold is fitted in full."""
    try:
        full = whole_fit(ctx, causes)
    except IdentificationError:
        return None
    n = len(ctx.table)
    gram, grad = full.jm.T @ full.jm, full.jm.T @ full.r
    sq, count = np.zeros(n), np.zeros(n, dtype=int)
    for test in folds:
        train = np.setdiff1d(np.arange(n), test)
        if full.shift is not None and scan(ctx, train) != (
                full.shift["station"], full.shift["after_t_s"]):  # fmt: skip
            try:
                fit = fit_model(ctx, causes, train, FOLD_ITERATIONS)
            except IdentificationError:
                return None
            pred = predict_rows(ctx, fit, test, extension_of(ctx, causes, test))
            if pred is None:
                return None
            e = ctx.table.xyz[test] - pred
        else:
            te3 = (3 * test[:, None] + np.arange(3)).ravel()
            jt, rt = full.jm[te3], full.r[te3]
            g = gram - jt.T @ jt
            if not _identifiable(g):
                return None
            d = np.sqrt(np.diag(g))
            step = np.linalg.solve(g / np.outer(d, d), (grad - jt.T @ rt) / d) / d
            e = (rt - jt @ step).reshape(-1, 3)
            e = e if ctx.unwhiten is None else np.einsum("nij,nj->ni", ctx.unwhiten[test], e)
        np.add.at(sq, test, np.sum(e**2, axis=1))
        np.add.at(count, test, 1)
    return HeldOut(sq, count)


def trainable(ctx: Context, causes: tuple[str, ...], test: np.ndarray) -> bool:
    """Whether the rows other than `test` identify the model `causes` (its whole-table fit's Gram matrix less
    the held-out rows')."""
    try:
        full = whole_fit(ctx, causes)
    except IdentificationError:
        return False
    jt = full.jm[(3 * np.asarray(test)[:, None] + np.arange(3)).ravel()]
    return _identifiable(full.jm.T @ full.jm - jt.T @ jt)


def edge_rows(table: MeasurementTable, share: float = EDGE_SHARE) -> list[np.ndarray]:
    """Folds that judge extrapolation: for every joint that moves, the poses in the lowest `share` of its range and,
    apart, those in the highest (by the joint's angle at the pose; at least one pose each), whole poses held out.
    A model fitted without a joint's extreme poses then predicts them as it will predict a pose beyond the
    campaign's range (issue 36: an encoder scale and a joint map that cancelled inside the fitted range made an
    unseen ABB IRB 120 7x worse just outside it). Folds holding out the same poses are kept once."""
    pose_arr = np.array(table.pose)
    poses, first = np.unique(pose_arr, return_index=True)
    if len(poses) < 3:
        return []
    q = table.q_deg[first]
    k = max(1, int(round(share * len(poses))))
    out, seen = [], set()
    for j in range(q.shape[1]):
        if np.ptp(q[:, j]) <= 0:
            continue
        order = np.argsort(q[:, j], kind="stable")
        for group in (order[:k], order[-k:]):
            key = tuple(sorted(group.tolist()))
            if key not in seen:
                seen.add(key)
                out.append(np.flatnonzero(np.isin(pose_arr, poses[group])))
    return out


class Validator:
    """Held-out comparisons of two models on the same folds, the scheme chosen per comparison. The pose scheme's
    folds are its partition and the edge folds (`edge_rows`) whose training rows identify the geometric model."""

    def __init__(self, ctx: Context, folds: int, seed: int):
        self.ctx, self.folds, self.seed = ctx, folds, seed
        self.cache: dict[tuple, HeldOut | None] = {}
        self.fold_sets = {s: fold_rows(ctx.table, s, folds, seed) for s in ("pose", "pass", "time")}
        self.edges = [g for g in edge_rows(ctx.table) if trainable(ctx, (), g)] if self.fold_sets["pose"] else []

    def cv(self, causes: tuple[str, ...], scheme: str, cut: tuple[str, float] | None = None) -> HeldOut | None:
        key = (tuple(sorted(causes)), scheme, cut)
        if key not in self.cache:
            folds = self.fold_sets[scheme] if cut is None else fold_rows(self.ctx.table, scheme, self.folds,
                                                                         self.seed, cut)  # fmt: skip
            if folds is not None and scheme == "pose":
                folds = folds + self.edges
            self.cache[key] = None if folds is None else cross_validate(self.ctx, causes, folds)
        return self.cache[key]

    def change_point(self, causes: tuple[str, ...]) -> tuple[str, float] | None:
        """The station and time of the model's station shift (from its whole-table fit), if it has one."""
        if SHIFT not in causes:
            return None
        try:
            shift = whole_fit(self.ctx, causes).shift
        except IdentificationError:
            return None
        return None if shift is None else (shift["station"], float(shift["after_t_s"]))

    def compare(self, base: tuple[str, ...], model: tuple[str, ...]) -> tuple[str | None, HeldOut | None,
                                                                          HeldOut | None]:
        """(scheme, held-out errors of base, of model) on the same folds: time blocks first for a time-dependent
        cause, cut on both sides of the model's change point when it has one (`fold_rows`).

        The scheme is the first on which the base model can be cross-validated: the campaign supports it. When the
        model cannot be on that scheme (a training set of its folds does not identify it), its held-out errors are None
        and no other scheme is tried: the campaign cannot support the model. Before issue 25 the next scheme was
        tried, and a joint cause judged by time blocks was judged on poses its training rows had seen (the same
        pose measured with the other points and stations), so a model that over-fitted the joint angles of 30 poses
        won on held-out rows and predicted unseen poses 17x worse than the geometric model."""
        order = ("time", "pose", "pass") if set(model) & set(TIME_CAUSES) else ("pose", "pass", "time")
        cut = self.change_point(model) or self.change_point(base)
        for scheme in order:
            at = cut if scheme == "time" else None
            hb = self.cv(base, scheme, at)
            if hb is not None:
                return scheme, hb, self.cv(model, scheme, at)
        return None, None, None


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
        acts = np.abs(ext.joint_features).max(axis=0) > 0  # (n, e): which joints each parameter moves
        seen = acts[lever >= LEVER_RATIO * lever.max()].any(axis=0)
    problem = Problem(chain, table, geo.points, params, noise, geo.dev, ext)
    state = State(geo.dev, [geo.stations[s] for s in problem.station_ids],
                  np.array([geo.points[p] for p in problem.point_ids]), np.zeros(ext.size))  # fmt: skip
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
