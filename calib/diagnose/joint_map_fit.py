"""The joint error map's search and ridge fit (form and features: `calib.diagnose.joint_map`).

Fit: the map is the signature of an output-side encoder or a transmission error (a gear mesh gives harmonics at its
tooth counts per joint revolution). On real arms the spectrum is broad, tens of harmonics, so H is
chosen from the data, and the coefficients are ridge regularised: the prior says each coefficient is a
draw of RMS tau (rad), the penalty is lambda |c|^2 with lambda = s^2 / tau^2, s^2 the residual variance
of the model without the map. One order H for every joint (harmonics a joint does not need are held near
zero by the ridge) and tau are chosen by K-fold cross-validation by pose over the grids ORDERS x TAUS_RAD,
on the table being fitted alone; the geometric parameters, the stations, the reference points and an
optional unpenalised extension (e.g. joint_compliance) are fitted jointly and are not penalised. The
uncertainty of the map is the posterior covariance s^2 (J^T J + lambda P)^-1, and `effective_params` (the
trace of the hat matrix over the map's columns) is what it costs in degrees of freedom.

Design notes (UR10 Series B, calib on B, D's station alone refitted): per-joint orders chosen greedily by
the same cross-validation moved B -> D from 0.250 to 0.229 mm for ~4x the time; orders 96 and 128
cross-validate worse than 64 on B.

Identifiability: a joint whose rotation hardly moves the measured points (the wrist_3 axis through a
single reference point) cannot be mapped; its lever (RMS of |d p / d q_j| over the rows) below
LEVER_RATIO times the largest joint's drops it, and the fit reports it.

Speed: cross-validation works on the problem linearised at the fit without the map: the Gram matrix of
the Jacobian is formed once, each fold's is the whole minus the fold's rows, the unpenalised block is
eliminated (Schur complement) and one tridiagonal reduction per fold and order serves every ridge value
(`calib.diagnose.ridge`).
The final fit is Gauss-Newton on the penalised non-linear problem from there (a few iterations).
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular

from trackcal.calib.diagnose.joint_map import (
    CAUSE,
    Arc,
    harmonic_names,
    harmonics_by_joint,
    map_curve,
    map_extension,
    parse_name,
)
from trackcal.calib.diagnose.ridge import ridge_path
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import (
    Identification,
    IdentificationError,
    Problem,
    State,
    identification_of,
    identify,
)
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.extension import (
    Extension,
    combine,
)
from trackcal.calib.model.params import Param

ORDERS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)  # candidate harmonic orders H
TAUS_RAD = tuple(np.geomspace(1e-6, 1e-2, 17))  # candidate prior RMS of one coefficient: 1 urad .. 10 mrad
LEVER_RATIO = 1e-3  # a joint whose lever is below this fraction of the largest one is not mapped
GN_ITERATIONS = 6


class Linearised(NamedTuple):
    """The map search's problem linearised at `start` (the fit without the map) with the map's coefficients of the
    largest order searched at zero: what `MapEvidence` forms again for the same start, base and coefficients."""

    start: object
    base: Extension | None
    table: MeasurementTable
    names: list[str]
    r: np.ndarray
    jm: np.ndarray
    gram: np.ndarray
    rhs: np.ndarray
    held: HeldOutMap
    unwhiten: np.ndarray | None

    def serves(self, start, base: Extension | None, table: MeasurementTable, names: list[str]) -> bool:
        """Whether it is the problem of that start, base, table (its rows as labelled) and map coefficients."""
        t = self.table
        return (
            self.start is start
            and self.base is base
            and self.names == names
            and t.station == table.station
            and np.array_equal(t.q_deg, table.q_deg)
            and np.array_equal(t.xyz, table.xyz)
        )


@dataclass
class ErrorMapFit:
    identification: Identification  # geometry + optional base extension + map, jointly; ext ordered base, map
    names: list[str]  # map coefficient names (after the base extension's in identification.ext)
    arcs: dict[int, Arc]  # mapped joint (0-based) -> fitted arc
    orders: dict[int, int]  # mapped joint -> harmonic order
    tau_rad: float  # chosen prior RMS of a coefficient
    ridge: float  # lambda, in the units of the whitened residuals squared per rad^2
    effective_params: float  # trace of the hat matrix of the map columns (what the F test and BIC should count)
    cv_rms_mm: float | None  # cross-validated RMS of one coordinate (mm) at the chosen (H, tau); None: no search
    cv_rms_without_mm: float | None  # the same without the map (geometry + base)
    not_identifiable: dict[int, str]  # joint -> why it is not mapped
    cv_table: list[dict] = field(default_factory=list)  # every (order, tau) tried with its CV RMS
    n_base: int = 0  # how many of identification.ext belong to the base extension
    linearised: Linearised | None = field(default=None, repr=False, compare=False)  # the search's problem

    @property
    def coefficients(self) -> np.ndarray:
        return self.identification.ext[self.n_base :]

    @property
    def extension(self) -> Extension:
        return self.identification.extension

    def to_doc(self) -> dict:
        """Summary in boundary units (deg, mm), strict JSON."""
        return {
            "joints": {f"joint_{j + 1}": {"order": self.orders[j], **self.arcs[j].to_doc()} for j in sorted(self.arcs)},
            "not_identifiable": {f"joint_{j + 1}": why for j, why in sorted(self.not_identifiable.items())},
            "tau_deg": float(np.degrees(self.tau_rad)),
            "effective_params": self.effective_params,
            "cv_rms_mm": self.cv_rms_mm,
            "cv_rms_without_mm": self.cv_rms_without_mm,
        }

    def curve(self, joint: int, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return map_curve(self.identification, joint, q)


def _levers(problem: Problem, state: State) -> np.ndarray:
    """(n,) RMS over rows of |d p / d q_j| (mm/rad) at the state."""
    jac = problem.kin.jacobian(problem.q, state.points[problem.pt_idx], state.dev)
    return np.sqrt(np.mean(np.sum(jac.d_q**2, axis=1), axis=0))


def _state_from(problem: Problem, res: Identification, ext: np.ndarray) -> State:
    return State(
        res.dev.copy(),
        [res.stations[s] for s in problem.station_ids],
        np.array([res.points[p] for p in problem.point_ids]),
        ext,
    )


def _fold_ids(table: MeasurementTable, folds: int, seed: int) -> np.ndarray:
    """(N,) fold of every row: whole poses held out together."""
    poses = np.array(sorted(set(table.pose)))
    np.random.default_rng(seed).shuffle(poses)
    fold_of = {p: i % folds for i, p in enumerate(poses)}
    return np.array([fold_of[p] for p in table.pose])


class HeldOutMap:
    """The map's Jacobian columns of held-out rows as `predict` sees an unseen pose: each joint's angle clamped to the
    arc the fold's *training* rows cover (`Arc.covering`), not the whole table's. A pose held out beyond the training
    rows' range of a joint is then predicted with the map's value at the nearest end of that range, the constant
    continuation predict and compensate use, and cross-validation judges that, not a Fourier series carried past its
    data (issue 25: an encoder scale and a map that cancel each other over a joint's arc agree beyond it only while
    neither is clamped; predicted with the clamped map, unseen poses were 17x worse than with the geometric model).

    The column of coefficient e of joint j at row r is lever_j(r) * phi_e(q_j(r)), lever_j the whitened derivative
    of the reflector position in the station frame by joint j (as `Problem` forms it), phi_e the harmonic."""

    def __init__(self, problem: Problem, state: State, names: list[str]):
        q = problem.q
        if problem.ext is not None and problem.ext.joint_features is not None:
            q = q + problem.ext.joint_offsets(state.ext)
        d_q = problem.kin.jacobian(q, state.points[problem.pt_idx], state.dev).d_q  # (N, 3, n)
        rs = np.array([st.rotation for st in state.stations])[problem.st_idx]
        self.lever = (rs if problem.w is None else problem.w @ rs) @ d_q
        self.q, self.names = problem.q, list(names)
        self.joints = sorted({parse_name(nm)[2] for nm in names})
        self._columns: dict[tuple, tuple] = {}  # the same folds are asked again (orders, models of Rejudge)
        self._cached = 0  # harmonics values in the cache

    def columns(self, test: np.ndarray, names: list[str] | None = None) -> np.ndarray:
        """(3 len(test), len(names)) map columns of the `test` rows (indices), clamped to the arcs of the other rows
        (`names`: a subset of the map's coefficients, default all)."""
        key = (np.asarray(test).tobytes(), None if names is None else tuple(names))
        if key not in self._columns:
            train = np.setdiff1d(np.arange(len(self.q)), test)
            arcs = {j: Arc.covering(self.q[train, j]) for j in self.joints}
            names = self.names if names is None else names
            # one fold set's harmonics at most (the rows once): an older fold set's leave first (issue 41: the
            # search's folds, the edge folds of the held-out test and Rejudge's were three sets, 11 KB per row)
            while self._columns and self._cached + len(test) * len(names) > len(self.q) * len(self.names):
                _, old = self._columns.pop(next(iter(self._columns)))
                self._cached -= sum(v.size for _, _, v in old)
            self._columns[key] = (len(names), list(harmonics_by_joint(self.q[test], names, arcs)))
            self._cached += len(test) * len(names)
        n_cols, harmonics = self._columns[key]
        # the cache holds the harmonics (a row's values, a third of its three coordinates' columns: issue 41, the
        # cached columns were 65 KB per row of a diagnosis of Series B); the columns are their products with the
        # levers, formed on each call, the same products as before and so the same values, written in place when a
        # group's columns are a slice (the whole map's names, s1 c1 s2 c2 ..., and an order's: a product and its
        # scatter by a list of columns took twice as long, 6 % of a diagnosis of Series B under py-spy)
        lever, out = self.lever[test], np.empty((len(test), 3, n_cols))
        for j, cols, values in harmonics:  # a coefficient moves its own joint only
            if isinstance(cols, slice):
                np.multiply(lever[:, :, j, None], values[:, None, :], out=out[:, :, cols])
            else:
                out[:, :, cols] = lever[:, :, j, None] * values[:, None, :]
        return out.reshape(3 * len(test), -1)


class FoldGrams:
    """The held-out rows' part jm[hold]^T jm[hold] of the Gram matrix of the Jacobian jm, per fold of one fold
    assignment, formed once: the cross-validations of one linearised problem share their folds (issue 26: the
    map's search and its comparison without the map; the models of `Rejudge`, which differ in their columns)."""

    def __init__(self, jm: np.ndarray):
        self.jm = jm
        self.grams: dict[int, np.ndarray] = {}

    def __call__(self, k: int, hold: np.ndarray) -> np.ndarray:
        if k not in self.grams:
            jk = self.jm[hold]
            self.grams[k] = jk.T @ jk
        return self.grams[k]

    def columns(self, keep: np.ndarray):
        """The downdates of jm[:, keep]: blocks of the whole ones."""
        return lambda k, hold: self(k, hold)[np.ix_(keep, keep)]


def _cv_scores(
    jm,
    r,
    gram,
    rhs,
    unwhiten,
    pen_cols,
    fold,
    orders_cols,
    lambdas,
    held: HeldOutMap | None = None,
    downdate=None,
    executor: Executor | None = None,
    per_row: bool = False,
):
    """(held-out whitened sum of squares, held-out sum of squares in mm^2), each (orders, lambdas), for every
    order and ridge on the problem linearised at (jm, r); with `per_row`, also every order's squared held-out error
    of every row at the first ridge ((N, orders) mm^2, summed over its coordinates and the folds that held it out) and
    how many folds held it out. `fold`: the fold of every row (N,), or a list of held-out row indices (folds that need
    not partition the rows: edge folds). jm (3N, m) Jacobian, r (3N,) residual, whitened,
    gram = jm^T jm and rhs = jm^T r; unwhiten (N, 3, 3) or None (i.i.d.) turns residuals back into mm;
    pen_cols the penalised columns at the largest order; orders_cols[i] the subset of them kept at order i; `held`
    (its coefficients those of pen_cols, in order): the held-out rows' map columns clamped to the training rows'
    arcs; `downdate(k, hold)` the held-out rows' part of gram (jm[hold]^T jm[hold]) if already known. The folds are
    solved in `executor` when given (threads: their LAPACK calls release the GIL), summed in fold order."""
    free = np.setdiff1d(np.arange(jm.shape[1]), pen_cols)
    lam = np.asarray(lambdas, dtype=float)
    groups = (
        [np.flatnonzero(fold == k) for k in np.unique(fold)]
        if isinstance(fold, np.ndarray)
        else [np.sort(g) for g in fold]
    )
    n_rows = len(r) // 3

    def scores(k):
        ss = np.zeros((len(orders_cols), len(lambdas)))
        ss_mm = np.zeros_like(ss)
        rows = groups[k]
        hold = np.zeros(n_rows, dtype=bool)
        hold[rows] = True
        hold = np.repeat(hold, 3)
        jk, rk = jm[hold], r[hold]
        if downdate is None:  # the fold's part formed here, and the training rows' Gram matrix in its place
            g = jk.T @ jk
            np.subtract(gram, g, out=g)
        else:
            g = gram - downdate(k, hold)
        b = rhs - jk.T @ rk
        # predicted as predict will: the map clamped to the training rows' arcs (each order's columns taken from these,
        # the same values as when they were written into jk first, in the same layout)
        jmap = None if held is None else held.columns(rows)
        first = np.empty((len(rows), len(orders_cols)))
        # the Schur complement of every penalised column; an order's is its block (its columns a subset); none when
        # no order keeps a column (the comparison without the map: its 650 x 650 block was formed and not read)
        kept = pen_cols if any(len(cols) for cols in orders_cols) else pen_cols[:0]
        gaa_inv, gpf, schur_all, bf_all = _eliminated(g, b, free, kept)
        j_free = jk[:, free]
        for i, cols in enumerate(orders_cols):
            at = np.searchsorted(kept, cols)
            # an order that keeps every column reads the whole Schur complement, not a copy of it
            gaf, schur, bf = gpf[:, at], schur_all if len(at) == len(kept) else schur_all[np.ix_(at, at)], bf_all[at]
            if len(lam) == 1:  # one ridge: a solve is a fraction of the path's cost
                h = schur.copy()  # schur + lam I: the ridge added to the diagonal alone (no identity formed)
                h.flat[:: len(h) + 1] += lam[0]
                c = np.linalg.solve(h, bf)[:, None]
            else:
                c = ridge_path(schur, bf, lam)  # (p, L): every ridge
            a = gaa_inv @ (b[free][:, None] - gaf @ c)
            j_map = jk[:, cols] if jmap is None else jmap[:, np.searchsorted(pen_cols, cols)]
            e = rk[:, None] - j_free @ a - j_map @ c  # (3 n_k, L)
            ss[i] += np.sum(e**2, axis=0)
            if unwhiten is not None:
                e = np.einsum("nij,njl->nil", unwhiten[rows], e.reshape(-1, 3, len(lam))).reshape(e.shape)
            ss_mm[i] += np.sum(e**2, axis=0)
            first[:, i] = np.sum(e[:, 0].reshape(-1, 3) ** 2, axis=1)
        return ss, ss_mm, first

    parts = list((map if executor is None else executor.map)(scores, range(len(groups))))
    return _summed(parts, groups, n_rows, per_row)


def _eliminated(g: np.ndarray, b: np.ndarray, free: np.ndarray, kept: np.ndarray) -> tuple:
    """(gaa^-1, g_af, Schur complement, its right-hand side): the normal equations (g, b) with the unpenalised block
    `free` eliminated from the penalised columns `kept` (a = gaa^-1 (b_a - g_af c)); column scaling keeps the inverse
    accurate."""
    gaa = g[np.ix_(free, free)]
    sa = np.sqrt(np.diag(gaa))
    sa[sa == 0] = 1.0
    gaa_inv = np.linalg.pinv(gaa / np.outer(sa, sa), rcond=1e-12) / np.outer(sa, sa)
    gpf = g[np.ix_(free, kept)]
    # the penalised columns are a run (the map's coefficients): their block read in place, not copied first
    g_kept = g[kept[0] : kept[-1] + 1, kept[0] : kept[-1] + 1] if _is_run(kept) else g[np.ix_(kept, kept)]
    return gaa_inv, gpf, g_kept - gpf.T @ gaa_inv @ gpf, b[kept] - gpf.T @ (gaa_inv @ b[free])


def _is_run(cols: np.ndarray) -> bool:
    """Whether `cols` (increasing) are consecutive and not empty: a slice reads them."""
    return len(cols) > 0 and cols[-1] - cols[0] == len(cols) - 1


def _summed(parts: list[tuple], groups: list[np.ndarray], n_rows: int, per_row: bool) -> tuple:
    """_cv_scores' folds (`parts`: each fold's sums and every order's squared errors of its rows `groups[k]`)
    summed in fold order; with `per_row`, also every row's squared error per order and how many folds held it out."""
    out = sum(p[0] for p in parts), sum(p[1] for p in parts)
    if not per_row:
        return out
    sq, count = np.zeros((n_rows, parts[0][2].shape[1])), np.zeros(n_rows, dtype=int)
    for rows, p in zip(groups, parts, strict=True):
        np.add.at(sq, rows, p[2])
        np.add.at(count, rows, 1)
    return (*out, sq, count)


def _unidentifiable(probe: Problem, geo, arcs_all: dict[int, Arc]) -> dict[int, str]:
    """fit_error_map's joints whose map cannot be fitted, each with why: it does not move over the table, or its
    rotation barely moves the measured points (`probe`: the problem without the map, at the fit `geo`)."""
    levers = _levers(probe, _state_from(probe, geo, geo.ext))
    not_identifiable = {}
    for j in range(probe.chain.dof):
        if arcs_all[j].length <= 0.0:
            not_identifiable[j] = "it does not move over the table"
        elif levers[j] < LEVER_RATIO * levers.max():
            not_identifiable[j] = (
                f"its rotation moves the measured points by {levers[j]:.3g} mm/rad, below "
                f"{LEVER_RATIO:g} of the largest joint's {levers.max():.3g} (the reference points "
                "lie on its axis)"
            )
    return not_identifiable


def _searched(
    lin: Linearised,
    pen_all: np.ndarray,
    fold: np.ndarray,
    orders: tuple[int, ...],
    taus_rad: tuple[float, ...],
    s2: float,
    executor: Executor | None,
) -> tuple:
    """fit_error_map's search: (order, tau, CV RMS with the map, without it, every (order, tau) with its CV RMS) by
    cross-validation over `fold` on the linearised problem `lin`; `pen_all` the map's columns at the largest order,
    `s2` the residual variance without the map (a ridge is s2 / tau^2)."""
    orders_cols = [pen_all[[parse_name(nm)[1] <= h for nm in lin.names]] for h in orders]
    downdate, n_coord = FoldGrams(lin.jm), 3 * len(lin.table)
    ss, ss_mm = _cv_scores(
        lin.jm,
        lin.r,
        lin.gram,
        lin.rhs,
        lin.unwhiten,
        pen_all,
        fold,
        orders_cols,
        [s2 / t**2 for t in taus_rad],
        lin.held,
        downdate,
        executor,
    )
    _, without_mm = _cv_scores(
        lin.jm, lin.r, lin.gram, lin.rhs, lin.unwhiten, pen_all, fold, [pen_all[:0]], [1.0], None, downdate, executor
    )
    i, li = np.unravel_index(int(np.argmin(ss)), ss.shape)
    cv_table = [
        {"order": int(h), "tau_rad": float(t), "cv_rms_mm": float(np.sqrt(ss_mm[a, b] / n_coord))}
        for a, h in enumerate(orders)
        for b, t in enumerate(taus_rad)
    ]
    return (
        int(orders[i]),
        float(taus_rad[li]),
        float(np.sqrt(ss_mm[i, li] / n_coord)),
        float(np.sqrt(without_mm[0, 0] / n_coord)),
        cv_table,
    )


def fit_error_map(
    chain: Chain,
    table: MeasurementTable,
    tool_points: dict[str, np.ndarray],
    params: list[Param],
    noise: TrackerNoise | None = None,
    base: Extension | None = None,
    folds: int = 5,
    seed: int = 0,
    orders: tuple[int, ...] = ORDERS,
    taus_rad: tuple[float, ...] = TAUS_RAD,
    start: Identification | None = None,
    executor: Executor | None = None,
) -> ErrorMapFit:
    """Fit the joint error map jointly with the geometric model, the stations, the reference points and
    `base` (an unpenalised extension of the same table, e.g. joint_compliance); the harmonic order (one for
    every joint) and the ridge by `folds`-fold cross-validation by pose over `orders` x `taus_rad`.

    `start` is the fit without the map (geometry + base) if already computed (an Identification, or anything with
    its dev, stations, points and ext). A single order and a single tau skip the cross-validation (a fit inside
    another cross-validation reuses the outer choice). The folds of the search run in `executor` when given."""
    q = np.radians(table.q_deg)
    geo = start if start is not None else identify(chain, table, tool_points, params, noise, extension=base)
    n_base = 0 if base is None else base.size
    arcs_all = {j: Arc.covering(q[:, j]) for j in range(chain.dof)}
    not_identifiable = _unidentifiable(
        Problem(chain, table, geo.points, params, noise, extension=base, ext0=geo.ext), geo, arcs_all
    )
    arcs = {j: arcs_all[j] for j in range(chain.dof) if j not in not_identifiable}
    if not arcs:
        raise IdentificationError(f"{table.source}: no joint error map can be fitted: no joint moves the points")
    search = len(orders) > 1 or len(taus_rad) > 1
    names_max = [nm for j in arcs for nm in harmonic_names(j, max(orders))]
    ext = _with_base(base, map_extension(q, names=names_max, arcs=arcs))
    problem = Problem(chain, table, geo.points, params, noise, extension=ext)
    state = _state_from(problem, geo, np.concatenate([geo.ext, np.zeros(len(names_max))]))
    r, jm = problem.residual_and_jacobian(state)
    pen_all = len(params) + n_base + np.arange(len(names_max))
    s2 = float(r @ r) / max(len(r) - problem.n_cols + len(names_max), 1)  # residual variance without the map
    cv_table, cv_rms, cv_without, linearised = [], None, None, None
    order, tau = max(orders), float(taus_rad[0])
    if search:
        unwhiten = None if problem.w is None else np.linalg.inv(problem.w)
        gram, rhs = jm.T @ jm, jm.T @ r
        held = HeldOutMap(problem, state, names_max)
        linearised = Linearised(geo, base, table, names_max, r, jm, gram, rhs, held, unwhiten)
        order, tau, cv_rms, cv_without, cv_table = _searched(
            linearised, pen_all, _fold_ids(table, folds, seed), orders, taus_rad, s2, executor
        )
    names = [nm for nm in names_max if parse_name(nm)[1] <= order]
    if len(names) == len(names_max):  # the search's problem and its Jacobian at the start
        res, edf = _penalised_fit(
            problem, state, pen_all[0], len(names), s2 / tau**2, (r, jm, gram if search else jm.T @ jm)
        )
    else:
        ext = _with_base(base, map_extension(q, names=names, arcs=arcs))
        problem = Problem(chain, table, geo.points, params, noise, extension=ext)
        state = _state_from(problem, geo, np.concatenate([geo.ext, np.zeros(len(names))]))
        res, edf = _penalised_fit(problem, state, pen_all[0], len(names), s2 / tau**2)
    return ErrorMapFit(
        identification=res,
        names=names,
        arcs=arcs,
        orders={j: order for j in arcs},
        tau_rad=tau,
        ridge=s2 / tau**2,
        effective_params=edf,
        cv_rms_mm=cv_rms,
        cv_rms_without_mm=cv_without,
        not_identifiable=not_identifiable,
        cv_table=cv_table,
        n_base=n_base,
        linearised=linearised,
    )


def held_out_errors(
    mf: ErrorMapFit, groups: list[np.ndarray], n_params: int, executor: Executor | None = None
) -> tuple[tuple, tuple] | None:
    """((squared error, times held out) of every row with the map at its order and ridge, the same without the map),
    over the folds `groups` (held-out row indices; need not partition the rows), on the map search's linearised
    problem: what the paired test of its held-out gain needs (`calib.diagnose.significance`). None when the map was
    not searched (a single order and ridge: nothing was cross-validated). `n_params`: the geometric parameters."""
    lin = mf.linearised
    if lin is None:
        return None
    pen = n_params + mf.n_base + np.arange(len(lin.names))
    order = max(mf.orders.values())
    cols = pen[[parse_name(nm)[1] <= order for nm in lin.names]]
    # with the map and without it (no order's columns) in one pass over the folds: each fold's Gram downdate, held-out
    # rows and unpenalised block formed once for both
    *_, sq, count = _cv_scores(
        lin.jm,
        lin.r,
        lin.gram,
        lin.rhs,
        lin.unwhiten,
        pen,
        groups,
        [cols, pen[:0]],
        [mf.ridge],
        lin.held,
        None,
        executor,
        per_row=True,
    )
    return (sq[:, 0].copy(), count), (sq[:, 1].copy(), count)


class MapEvidence:
    """Models with the joint error map at `fit`'s joints, arcs, order and ridge, on one problem linearised
    at the fit of the geometric model + `base` without the map (`start`: an Identification or anything with
    its dev, stations, points and ext): the model with all of `base`, or with some of its parameters
    removed (held at zero: the residual moves by their columns times their fitted values). What the F
    test, the BIC and a held-out comparison of models that differ in their base need, from one Jacobian.

    Every model is the whole one with the step of its removed parameters fixed (to minus their fitted values): a
    linear constraint E^T d = -x on the penalised normal equations H d = g of the whole model, whose solution is
    the whole one moved by H^-1 E (E^T H^-1 E)^-1 (E^T d0 + x). One Cholesky factor of H per fold (and of the
    whole table) then serves every model of `Rejudge`, and the removed parameters' columns of H^-1 (a few) are
    all it needs besides; the inverse of a model's H, for its effective number of parameters, is H^-1 less the
    same low-rank term (issue 26: each model's own elimination and inverse cost 2.5 s of 11 on Series B). When a
    fold's training rows cannot identify the whole model (H not positive definite), that fold set's models are
    solved one by one (`_cv_scores`, the unpenalised block by pseudo-inverse)."""

    def __init__(
        self,
        chain: Chain,
        table: MeasurementTable,
        params: list[Param],
        noise: TrackerNoise | None,
        base: Extension | None,
        start,
        fit: ErrorMapFit,
    ):
        names = [nm for j in fit.arcs for nm in harmonic_names(j, max(fit.orders.values()))]
        lin = fit.linearised
        if lin is None or not lin.serves(start, base, table, names):  # else the map's search formed it already
            ext = _with_base(base, map_extension(np.radians(table.q_deg), names=names, arcs=fit.arcs))
            problem = Problem(chain, table, start.points, params, noise, extension=ext)
            state = _state_from(problem, start, np.concatenate([start.ext, np.zeros(len(names))]))
            r, jm = problem.residual_and_jacobian(state)
            lin = Linearised(
                start,
                base,
                table,
                names,
                r,
                jm,
                jm.T @ jm,
                jm.T @ r,
                HeldOutMap(problem, state, names),
                None if problem.w is None else np.linalg.inv(problem.w),
            )
        self.r, self.jm, self.gram, self.rhs, self.held, self.unwhiten = (
            lin.r,
            lin.jm,
            lin.gram,
            lin.rhs,
            lin.held,
            lin.unwhiten,
        )
        self.k, self.x_base = len(params), np.asarray(start.ext, dtype=float)
        self.n_pen = len(names)
        self.ridge = fit.ridge
        self.pen = self.k + len(self.x_base) + np.arange(self.n_pen)  # the map's columns
        self.base_cols = self.k + np.arange(len(self.x_base))  # the base extension's columns
        # column scaling (the column norms of the Jacobian) keeps the factorisations accurate
        self.scale = np.sqrt(np.diag(self.gram))
        self.scale[self.scale == 0] = 1.0
        self.ridge_s = np.zeros(len(self.scale))
        self.ridge_s[self.pen] = self.ridge / self.scale[self.pen] ** 2
        self._whole = None  # (Cholesky factor of the whole table's H, its solution, H^-1 E, diag H^-1 on the map)
        self.fold_sets: dict[bytes, list | None] = {}  # per fold assignment: each fold's factor and held-out rows
        self.downdates: dict[bytes, FoldGrams] = {}  # the one-by-one path's fold Gram matrices

    def _factor(self, gram: np.ndarray, rhs: np.ndarray):
        """(Cholesky factor of the scaled penalised H, scaled solution d0, scaled H^-1 E for every base column)."""
        h = gram / np.outer(self.scale, self.scale) + np.diag(self.ridge_s)
        factor = cho_factor(h, lower=True, check_finite=False)
        e = np.zeros((len(h), len(self.base_cols)))
        e[self.base_cols, np.arange(len(self.base_cols))] = 1.0
        sol = cho_solve(factor, np.column_stack([rhs / self.scale, e]), check_finite=False)
        return factor, sol[:, 0], sol[:, 1:]

    def _step(self, d0: np.ndarray, w: np.ndarray, drop: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray | None]:
        """(the unscaled step of the model with base parameters `drop` at zero, the scaled H^-1 E of them and the
        inverse of E^T H^-1 E, for the low-rank term; None when nothing is dropped)."""
        if not drop:
            return d0 / self.scale, None
        sub = np.asarray(drop, dtype=int)
        w = w[:, sub]
        gone = self.base_cols[sub]
        m_inv = np.linalg.inv(w[gone])  # E^T H^-1 E, small
        ds = d0 - w @ (m_inv @ (d0[gone] + self.x_base[sub] * self.scale[gone]))
        return ds / self.scale, (w, m_inv)

    def whole(self, drop: tuple[int, ...] = ()) -> tuple[float, float]:
        """(whitened residual sum of squares of the penalised fit, the penalty not included; unpenalised
        columns + the map's effective number of parameters) with base parameters `drop` at zero."""
        if self._whole is None:
            factor, d0, w = self._factor(self.gram, self.rhs)
            l_inv = solve_triangular(factor[0], np.eye(len(d0)), lower=True, check_finite=False)
            self._whole = factor, d0, w, np.sum(l_inv[:, self.pen] ** 2, axis=0)  # diag of H^-1 = L^-T L^-1
        _, d0, w, h_inv_diag = self._whole
        step, low = self._step(d0, w, drop)
        if low is not None:  # a model's H^-1 is the whole one's less W (E^T H^-1 E)^-1 W^T
            h_inv_diag = h_inv_diag - np.einsum("ij,jk,ik->i", low[0][self.pen], low[1], low[0][self.pen])
        rss = float(np.sum((self.r - self.jm @ step) ** 2))
        # (H^-1 G)_ii = 1 - ridge_i (H^-1)_ii over the map's columns (G = H - ridge)
        edf = float(np.sum(1.0 - self.ridge_s[self.pen] * h_inv_diag))
        return rss, self.jm.shape[1] - len(drop) - self.n_pen + edf

    def _folds(self, fold: np.ndarray) -> list | None:
        """Each fold's (d0, H^-1 E, held-out row indices, their Jacobian rows' mask); None when a training set cannot
        identify the whole model."""
        key = fold.tobytes()
        if key not in self.fold_sets:
            out, row_fold = [], np.repeat(fold, 3)
            for k in np.unique(fold):
                hold = row_fold == k
                jk = self.jm[hold]
                try:
                    _, d0, w = self._factor(self.gram - jk.T @ jk, self.rhs - jk.T @ self.r[hold])
                except np.linalg.LinAlgError:  # not positive definite: this training set cannot identify it
                    out = None
                    break
                out.append((d0, w, np.flatnonzero(fold == k), hold))
            self.fold_sets[key] = out
        return self.fold_sets[key]

    def _held_rows(self, rows: np.ndarray, hold: np.ndarray) -> np.ndarray:
        """The held-out rows' Jacobian with the map's columns as predict sees them: formed on each call, the same
        values each time (issue 41: kept per fold they were a second whole Jacobian, 16 KB per row of Series B)."""
        jk = self.jm[hold]
        jk[:, self.pen[0] : self.pen[-1] + 1] = self.held.columns(rows)  # the map's columns are a run: a slice's copy
        return jk

    def cv_rms_mm(self, fold: np.ndarray, drop: tuple[int, ...] = ()) -> float:
        """Held-out RMS of one coordinate (mm) over `fold` (the fold of every row), base parameters `drop` at 0."""
        folds = self._folds(fold)
        if folds is None:
            return self._cv_rms_one_by_one(fold, drop)
        ss = 0.0
        for d0, w, rows, hold in folds:
            e = self.r[hold] - self._held_rows(rows, hold) @ self._step(d0, w, drop)[0]
            if self.unwhiten is not None:
                e = np.einsum("nij,nj->ni", self.unwhiten[rows], e.reshape(-1, 3)).ravel()
            ss += float(e @ e)
        return float(np.sqrt(ss / len(self.r)))

    def _cv_rms_one_by_one(self, fold: np.ndarray, drop: tuple[int, ...]) -> float:
        gone = self.k + np.asarray(drop, dtype=int)
        keep = np.setdiff1d(np.arange(self.jm.shape[1]), gone)
        pen = np.flatnonzero(np.isin(keep, self.pen))
        x = self.x_base[list(drop)]
        r = self.r + self.jm[:, gone] @ x
        rhs = self.rhs[keep] + self.gram[np.ix_(keep, gone)] @ x
        whole = self.downdates.setdefault(fold.tobytes(), FoldGrams(self.jm))
        _, ss_mm = _cv_scores(
            self.jm[:, keep],
            r,
            self.gram[np.ix_(keep, keep)],
            rhs,
            self.unwhiten,
            pen,
            fold,
            [pen],
            [self.ridge],
            self.held,
            whole.columns(keep),
        )
        return float(np.sqrt(ss_mm[0, 0] / len(r)))


def _with_base(base: Extension | None, ext: Extension) -> Extension:
    return ext if base is None else combine([base, ext], cause=CAUSE)


def _penalised_fit(
    problem: Problem,
    state: State,
    k0: int,
    n_map: int,
    lam: float,
    at_start: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[Identification, float]:
    """Gauss-Newton on |r|^2 + lam |c|^2 (c the map coefficients, the `n_map` unknowns from column `k0`) from
    `state`, the fit without the map (`at_start`: its residual, Jacobian and Gram matrix if already formed):
    (identification with the posterior covariance s^2 (J^T J + lam P)^-1, effective number of map parameters).

    It stops as `calib.identify.solver.solve` does: when a step, or all the steps still to come after it (the rate of
    the last two steps telling their sum), moves the fit by less than 1e-9 of the residual (issue 26: two
    Gauss-Newton steps on Series B where a fixed test on the step alone took five, each a Jacobian of ~700 columns;
    the steps skipped were below 2e-9 of the residual). The covariance is taken with the Jacobian of the state
    before the last step."""
    pen = np.zeros(problem.n_cols)
    pen[k0 : k0 + n_map] = lam
    converged, prev, iterations = False, 0.0, 0
    if at_start is None:
        r, jm = problem.residual_and_jacobian(state)
        gram = jm.T @ jm
    else:
        r, jm, gram = at_start
    for _ in range(GN_ITERATIONS):
        scale = np.sqrt(np.diag(gram))
        scale[scale == 0] = 1.0
        x = np.zeros(problem.n_cols)
        x[k0 : k0 + n_map] = state.ext[k0 - len(problem.params) :]
        ds = np.linalg.solve(gram / np.outer(scale, scale) + np.diag(pen / scale**2), (jm.T @ r - pen * x) / scale)
        state = problem.retract(state, ds / scale)
        iterations += 1
        step, tol = float(np.linalg.norm(jm @ (ds / scale))), 1e-9 * float(np.linalg.norm(r))
        rate = step / prev if prev > 0 else 1.0
        if step <= tol or (rate <= 0.5 and rate / (1.0 - rate) * step <= tol):
            # the last step moved the fit by a small multiple of 1e-9 of the residual: the covariance keeps the
            # Jacobian of the state before it (its entries differ by ~1e-9 relative), and a Jacobian of ~700
            # columns and its Gram matrix (a third of the fit's time) are not formed again
            converged = True
            break
        jm = gram = None  # the last Jacobian let go before the next is formed: one held, not two (issue 41)
        r, jm = problem.residual_and_jacobian(state)
        gram = jm.T @ jm
        prev = step
    jm = None  # the covariance needs the Gram matrix alone: the Jacobian is not held meanwhile (issue 41)
    scale = np.sqrt(np.diag(gram))
    scale[scale == 0] = 1.0
    gram = gram / np.outer(scale, scale)  # not in place: it can be the caller's (at_start)
    h_inv = np.linalg.inv(gram + np.diag(pen / scale**2))
    hat = np.einsum("ij,ji->i", h_inv, gram)  # diagonal of (G + P)^-1 G: each unknown's share of the fit
    edf = float(hat.sum())
    dof = max(int(round(3 * problem.n_rows - edf)), 1)
    residuals = problem.xyz - problem.predicted(state)
    r = problem._whiten(residuals).ravel()
    s2 = float(r @ r) / dof
    cov = s2 * h_inv / np.outer(scale, scale)
    message = (
        "the Gauss-Newton steps to come are below 1e-9 of the residual"
        if converged
        else f"stopped after {GN_ITERATIONS} Gauss-Newton iterations"
    )
    res = identification_of(problem, state, residuals, cov, s2, dof, iterations, converged, message)
    return res, float(hat[k0 : k0 + n_map].sum())
