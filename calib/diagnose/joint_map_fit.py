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

from trackcal.calib.diagnose.joint_map import (
    CAUSE,
    Arc,
    JointMapError,
    harmonic_names,
    harmonics_by_joint,
    map_curve,
    map_extension,
    parse_name,
)
from trackcal.calib.diagnose.lapack import dpotrf_in_place, dpotrs, dtrtrs_lower
from trackcal.calib.diagnose.ridge import ridge_inverse, ridge_path, ridge_solve
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
from trackcal.calib.model.extension import Extension, JointFeatures, combine
from trackcal.calib.model.params import Param

ORDERS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)  # candidate harmonic orders H
TAUS_RAD = tuple(np.geomspace(1e-6, 1e-2, 17))  # candidate prior RMS of one coefficient: 1 urad .. 10 mrad
LEVER_RATIO = 1e-3  # a joint whose lever is below this fraction of the largest one is not mapped
GN_ITERATIONS = 6
PIECE = 512  # rows of Jacobian formed at once where the whole is not held (3 x 512 x ~700 float64: 8.6 MB)


class ProblemRows(NamedTuple):
    """The whitened residual (3 n,) and Jacobian rows (3 n, m) of a problem at a state, of any n rows (in that order),
    formed when asked: a linearised problem keeps this, not its Jacobian (issue 41)."""

    problem: Problem
    state: State

    def __call__(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.problem.residual_and_jacobian(self.state, rows)

    def normal(self, rows: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, ...]:
        """(J^T J, J^T r, r, J[:, keep]) of the rows (`Problem.normal_rows`)."""
        return self.problem.normal_rows(self.state, rows, keep)


class Linearised(NamedTuple):
    """The map search's problem linearised at `start` (the fit without the map) with the map's coefficients of the
    largest order searched at zero: what `MapEvidence` forms again for the same start, base and coefficients. Its
    Jacobian is not held (3N x ~700 float64, 16 KB per row of the UR10's Series B, issue 41): its Gram matrix and
    J^T r are, and `rows` forms the Jacobian rows of any rows when asked."""

    start: object
    base: Extension | None
    table: MeasurementTable
    names: list[str]
    rr: float  # r.r of the whitened residual r
    rows: ProblemRows
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
    of the reflector position in the station frame by joint j (as `Problem` forms it), phi_e the harmonic. The
    harmonics are the problem's own map features (the last of its extension's: the whole table's arcs hold every
    row, and an angle inside an arc is not moved, so they are the same values) except at a held-out row whose angle
    lies beyond the training rows' arc of its joint (or beyond the arc its feature was clamped to): those are formed
    again, clamped. Nothing is kept per fold but
    its arcs (issue 41: a cache of the held-out harmonics was 6 KB per row, and their sines and cosines 3 % of a
    diagnosis of Series B)."""

    def __init__(self, problem: Problem, state: State, names: list[str]):
        q = problem.q
        if problem.ext is not None and problem.ext.joint_features is not None:
            q = q + problem.ext.joint_offsets(state.ext)
        d_q = problem.kin.jacobian(q, state.points[problem.pt_idx], state.dev).d_q  # (N, 3, n)
        rs = np.array([st.rotation for st in state.stations])[problem.st_idx]
        self.lever = (rs if problem.w is None else problem.w @ rs) @ d_q
        self.q, self.names = problem.q, list(names)
        if list(problem.ext.names[len(problem.ext.names) - len(names) :]) != self.names:
            raise JointMapError("the problem's extension does not end with the map's coefficients")
        feats = problem.ext.joint_features.columns(slice(problem.ext.size - len(names), None))
        self.feats = feats  # a view of the problem's: (N, e) values, the joint each moves
        self.feature_arcs = problem.ext.meta.get("arcs", {})  # the arcs its features were clamped to
        self.of_joint = {}  # joint -> (its coefficients' names, their columns)
        for i, nm in enumerate(self.names):
            names_j, cols_j = self.of_joint.setdefault(parse_name(nm)[2], ([], []))
            names_j.append(nm)
            cols_j.append(i)
        self._arcs: dict[bytes, dict[int, Arc]] = {}  # each fold's training arcs (the same folds are asked again)

    def _training_arcs(self, test: np.ndarray) -> dict[int, Arc]:
        key = test.tobytes()
        if key not in self._arcs:
            train = np.ones(len(self.q), dtype=bool)  # a mask: no sort of the rows (setdiff1d's)
            train[test] = False
            self._arcs[key] = {j: Arc.covering(self.q[train, j]) for j in self.of_joint}
        return self._arcs[key]

    def piece(self, test: np.ndarray, at: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """(the n rows test[at] (`test`: the held-out rows, indices), their (n, e) map features clamped to the arcs of
        the rows not in `test`): what `times` multiplies."""
        test = np.asarray(test)
        rows = test[at]
        values, q = self.feats.values[rows], self.q[rows]
        for j, arc in self._training_arcs(test).items():
            beyond = arc.clamp(q[:, j])[1]
            if j in self.feature_arcs:  # a row its feature clamped (a table wider than the map's arcs) is formed again
                beyond |= self.feature_arcs[j].clamp(q[:, j])[1]
            beyond = np.flatnonzero(beyond)
            if len(beyond):
                names, cols = self.of_joint[j]
                for _, sub, vals in harmonics_by_joint(q[beyond], names, {j: arc}):
                    values[np.ix_(beyond, np.asarray(cols)[sub])] = vals
        return rows, values

    def times(self, piece: tuple[np.ndarray, np.ndarray], c: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(3 n, k): the map's columns `idx` of a piece's n rows (`piece`) times c (len(idx), k): a coefficient moves
        its own joint, so the product is the rows' levers times the joint offsets of c (`JointFeatures.offsets`). The
        columns (3 n x len(idx)) are never formed (issue 41: forming them (`JointFeatures.lever_columns`) and
        multiplying them took three times as long on Series B)."""
        rows, values = piece
        idx = np.asarray(idx)
        offsets = JointFeatures(values[:, idx], self.feats.joint[idx], self.feats.n).offsets(c)  # (n, joints, k)
        return np.matmul(self.lever[rows], offsets).reshape(3 * len(rows), -1)


def _linearised(problem: Problem, state: State, start, base, table, names, normal: tuple) -> Linearised:
    """The Linearised problem of `problem` at `state` (`normal`: its normal equations, (J^T J, J^T r, r.r))."""
    gram, rhs, rr = normal
    unwhiten = None if problem.w is None else np.linalg.inv(problem.w)
    rows = ProblemRows(problem, state)
    return Linearised(start, base, table, names, rr, rows, gram, rhs, HeldOutMap(problem, state, names), unwhiten)


class FoldParts:
    """Each fold's held-out part of the normal equations of one linearised problem, (J_k^T J_k, J_k^T r_k), with the
    held-out rows' residual r_k and their Jacobian's unpenalised columns `free`, formed by `rows` (`ProblemRows`, or
    anything whose `normal(rows, keep)` gives them for given rows) `PIECE` rows at a time: the whole Jacobian is
    never held (issue 41). Kept per fold with `keep`: the cross-validations of one linearised problem share their
    folds (the models of `MapEvidence`), and the map's search reads the parts whose sums are its normal equations
    (`whole`)."""

    def __init__(self, rows, free: np.ndarray, keep: bool = True):
        self.rows, self.free, self.keep = rows, free, keep
        self.parts: dict[int, tuple] = {}

    def __call__(self, k: int, held: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(J_k^T J_k, J_k^T r_k, r_k, J_k[:, free]) of fold k, its held-out rows `held`."""
        if k in self.parts:
            return self.parts[k]
        g = b = None
        rk, jf = [], []
        for a in range(0, len(held), PIECE):
            g_a, b_a, r, j = self.rows.normal(held[a : a + PIECE], self.free)
            g, b = (g_a, b_a) if g is None else (g + g_a, b + b_a)
            rk.append(r)
            jf.append(j)
        out = (g, b, np.concatenate(rk), np.concatenate(jf))
        if self.keep:
            self.parts[k] = out
        return out

    def whole(self, groups: list[np.ndarray], executor: Executor | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(J^T J, J^T r, r.r) of the whole table from the parts of `groups` (a partition of its rows, fold k the rows
        groups[k]; formed in `executor` when given), which are kept."""
        parts = list((map if executor is None else executor.map)(self, range(len(groups)), groups))
        return sum(p[0] for p in parts), sum(p[1] for p in parts), float(sum(p[2] @ p[2] for p in parts))


def _cv_scores(
    parts,
    n_rows: int,
    gram,
    rhs,
    unwhiten,
    pen_cols,
    fold,
    orders_cols,
    lambdas,
    held: HeldOutMap | None = None,
    executor: Executor | None = None,
    per_row: bool = False,
):
    """(held-out whitened sum of squares, held-out sum of squares in mm^2), each (orders, lambdas), for every
    order and ridge on a linearised problem of `n_rows` rows; with `per_row`, also every order's squared held-out error
    of every row at the first ridge ((N, orders) mm^2, summed over its coordinates and the folds that held it out) and
    how many folds held it out. `fold`: the fold of every row (N,), or a list of held-out row indices (folds that need
    not partition the rows: edge folds). gram = J^T J and rhs = J^T r of the whitened Jacobian J (m columns) and
    residual r; `parts(k, rows)` fold k's (J_k^T J_k, J_k^T r_k, r_k, J_k's unpenalised columns) (`FoldParts`);
    unwhiten (N, 3, 3) or None (i.i.d.) turns residuals back into mm; pen_cols the penalised columns at the largest
    order; orders_cols[i] the subset of them kept at order i; `held` (its coefficients those of pen_cols, in order;
    needed when an order keeps a column): the held-out rows' map columns clamped to the training rows' arcs, as a
    product (`HeldOutMap.piece` and `times`). The folds
    are solved in `executor` when given (threads: their LAPACK calls release the GIL), summed in fold order."""
    free = np.setdiff1d(np.arange(len(gram)), pen_cols)
    lam = np.asarray(lambdas, dtype=float)
    groups = (
        [np.flatnonzero(fold == k) for k in np.unique(fold)]
        if isinstance(fold, np.ndarray)
        else [np.sort(g) for g in fold]
    )

    def scores(k):
        ss = np.zeros((len(orders_cols), len(lambdas)))
        ss_mm = np.zeros_like(ss)
        rows = groups[k]
        g_k, b_k, rk, j_free = parts(k, rows)
        g, b = gram - g_k, rhs - b_k  # the training rows' normal equations
        first = np.empty((len(rows), len(orders_cols)))
        # the Schur complement of every penalised column; an order's is its block (its columns a subset); none when
        # no order keeps a column (the comparison without the map: its 650 x 650 block was formed and not read)
        kept = pen_cols if any(len(cols) for cols in orders_cols) else pen_cols[:0]
        gaa_inv, gpf, schur_all, bf_all = _eliminated(g, b, free, kept)
        solved = []  # every order's (unpenalised solution, map coefficients, their columns among pen_cols)
        for cols in orders_cols:
            pos = np.searchsorted(kept, cols)
            # an order that keeps every column reads the whole Schur complement, not a copy of it
            gaf, bf = gpf[:, pos], bf_all[pos]
            schur = schur_all if len(pos) == len(kept) else schur_all[np.ix_(pos, pos)]
            # (p, L): every ridge; one ridge by a solve (Cholesky), a fraction of the path's cost
            c = ridge_solve(schur, bf, lam[0])[:, None] if len(lam) == 1 else ridge_path(schur, bf, lam)
            solved.append((gaa_inv @ (b[free][:, None] - gaf @ c), c, np.searchsorted(pen_cols, cols)))
        # the held-out errors `PIECE` rows at a time, the map's columns predicted as predict will (clamped to the
        # training rows' arcs) formed once per piece for every order: never the fold's whole (issue 41)
        for a0 in range(0, len(rows), PIECE):
            at, at3 = slice(a0, a0 + PIECE), slice(3 * a0, 3 * (a0 + PIECE))
            piece = held.piece(rows, at) if held is not None and len(kept) else None
            for i, (a, c, idx) in enumerate(solved):
                e = rk[at3, None] - j_free[at3] @ a  # (3 n, L)
                if len(idx):
                    e -= held.times(piece, c, idx)
                ss[i] += np.sum(e**2, axis=0)
                if unwhiten is not None:
                    e = np.einsum("nij,njl->nil", unwhiten[rows[at]], e.reshape(-1, 3, len(lam))).reshape(e.shape)
                ss_mm[i] += np.sum(e**2, axis=0)
                first[at, i] = np.sum(e[:, 0].reshape(-1, 3) ** 2, axis=1)
        return ss, ss_mm, first

    out = list((map if executor is None else executor.map)(scores, range(len(groups))))
    return _summed(out, groups, n_rows, per_row)


def _eliminated(g: np.ndarray, b: np.ndarray, free: np.ndarray, kept: np.ndarray) -> tuple:
    """(gaa^-1, g_af, Schur complement, its right-hand side): the normal equations (g, b) with the unpenalised block
    `free` eliminated from the penalised columns `kept` (a = gaa^-1 (b_a - g_af c)); column scaling keeps the inverse
    accurate. A training set of a few rows leaves a column's sum of squares at the rounding of the downdate, which
    can fall below zero: such a column counts as zero."""
    gaa = g[np.ix_(free, free)]
    sa = np.sqrt(np.maximum(np.diag(gaa), 0.0))
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
    parts: FoldParts,
    executor: Executor | None,
) -> tuple:
    """fit_error_map's search: (order, tau, CV RMS with the map, without it, every (order, tau) with its CV RMS) by
    cross-validation over `fold` on the linearised problem `lin`, `parts` the folds' parts of its normal equations;
    `pen_all` the map's columns at the largest order, `s2` the residual variance without the map (a ridge is
    s2 / tau^2)."""
    orders_cols = [pen_all[[parse_name(nm)[1] <= h for nm in lin.names]] for h in orders]
    n_rows = len(lin.table)
    # with the map and, last, without it (no order's columns: every ridge the same) in one pass over the folds: each
    # fold's downdate and unpenalised block once for both
    ss, ss_mm = _cv_scores(
        parts,
        n_rows,
        lin.gram,
        lin.rhs,
        lin.unwhiten,
        pen_all,
        fold,
        [*orders_cols, pen_all[:0]],
        [s2 / t**2 for t in taus_rad],
        lin.held,
        executor,
    )
    ss, ss_mm, without_mm, n_coord = ss[:-1], ss_mm[:-1], ss_mm[-1, 0], 3 * n_rows
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
        float(np.sqrt(without_mm / n_coord)),
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
    pen_all = len(params) + n_base + np.arange(len(names_max))
    # the normal equations summed over row chunks: the Jacobian (3N x ~700) is never held whole (issue 41); for a
    # search, the sums of its folds' parts, which it reads (a pass over the rows less: issue 41, CPU)
    if search:
        fold = _fold_ids(table, folds, seed)
        parts = FoldParts(ProblemRows(problem, state), np.setdiff1d(np.arange(problem.n_cols), pen_all))
        normal = parts.whole([np.flatnonzero(fold == k) for k in np.unique(fold)], executor)
    else:
        normal = problem.normal_equations(state, executor)
    s2 = normal[2] / max(3 * len(table) - problem.n_cols + len(names_max), 1)  # residual variance without the map
    cv_table, cv_rms, cv_without, linearised = [], None, None, None
    order, tau = max(orders), float(taus_rad[0])
    if search:
        linearised = _linearised(problem, state, geo, base, table, names_max, normal)
        order, tau, cv_rms, cv_without, cv_table = _searched(
            linearised, pen_all, fold, orders, taus_rad, s2, parts, executor
        )
    names = [nm for nm in names_max if parse_name(nm)[1] <= order]
    if len(names) == len(names_max):  # the search's problem and its normal equations at the start
        res, edf = _penalised_fit(problem, state, pen_all[0], len(names), s2 / tau**2, normal, executor)
    else:
        ext = _with_base(base, map_extension(q, names=names, arcs=arcs))
        problem = Problem(chain, table, geo.points, params, noise, extension=ext)
        state = _state_from(problem, geo, np.concatenate([geo.ext, np.zeros(len(names))]))
        res, edf = _penalised_fit(problem, state, pen_all[0], len(names), s2 / tau**2, executor=executor)
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
    free = np.setdiff1d(np.arange(len(lin.gram)), pen)
    *_, sq, count = _cv_scores(
        FoldParts(lin.rows, free, keep=False),  # edge folds are asked once
        len(lin.table),
        lin.gram,
        lin.rhs,
        lin.unwhiten,
        pen,
        groups,
        [cols, pen[:0]],
        [mf.ridge],
        lin.held,
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
        executor: Executor | None = None,
    ):
        names = [nm for j in fit.arcs for nm in harmonic_names(j, max(fit.orders.values()))]
        lin = fit.linearised
        if lin is None or not lin.serves(start, base, table, names):  # else the map's search formed it already
            ext = _with_base(base, map_extension(np.radians(table.q_deg), names=names, arcs=fit.arcs))
            problem = Problem(chain, table, start.points, params, noise, extension=ext)
            state = _state_from(problem, start, np.concatenate([start.ext, np.zeros(len(names))]))
            lin = _linearised(problem, state, start, base, table, names, problem.normal_equations(state))
        self.rr, self.rows, self.gram, self.rhs, self.held, self.unwhiten = (
            lin.rr,
            lin.rows,
            lin.gram,
            lin.rhs,
            lin.held,
            lin.unwhiten,
        )
        self.n_rows = len(table)
        self.k, self.x_base = len(params), np.asarray(start.ext, dtype=float)
        self.n_pen = len(names)
        self.ridge = fit.ridge
        self.pen = self.k + len(self.x_base) + np.arange(self.n_pen)  # the map's columns
        self.at_pen = np.arange(self.n_pen)  # every coefficient of the held-out map (`HeldOutMap.times`)
        self.free = np.setdiff1d(np.arange(len(self.gram)), self.pen)
        self.base_cols = self.k + np.arange(len(self.x_base))  # the base extension's columns
        # column scaling (the column norms of the Jacobian) keeps the factorisations accurate
        self.scale = np.sqrt(np.diag(self.gram))
        self.scale[self.scale == 0] = 1.0
        self.ridge_s = np.zeros(len(self.scale))
        self.ridge_s[self.pen] = self.ridge / self.scale[self.pen] ** 2
        self._whole = None  # (Cholesky factor of the whole table's H, its solution, H^-1 E, diag H^-1 on the map)
        self.fold_sets: dict[bytes, list | None] = {}  # per fold assignment: each fold's factor and held-out rows
        self.parts: dict[bytes, FoldParts] = {}  # per fold assignment: each fold's part of the normal equations
        self.executor = executor  # forms and factors the folds at once when given (threads)

    def _factor(self, gram: np.ndarray, rhs: np.ndarray):
        """(Cholesky factor of the scaled penalised H (its lower triangle), scaled solution d0, scaled H^-1 E for every
        base column)."""
        h = np.asfortranarray(gram / np.outer(self.scale, self.scale) + np.diag(self.ridge_s))
        if dpotrf_in_place(h, lower=True):  # its lower triangle now the factor (`calib.diagnose.lapack`: no GIL held)
            raise np.linalg.LinAlgError("the penalised normal matrix is not positive definite")
        e = np.zeros((len(h), len(self.base_cols)))
        e[self.base_cols, np.arange(len(self.base_cols))] = 1.0
        sol = dpotrs(h, np.column_stack([rhs / self.scale, e]), lower=True)[0]
        return h, sol[:, 0], sol[:, 1:]

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
            l_inv = dtrtrs_lower(factor, np.eye(len(d0)))[0]
            self._whole = factor, d0, w, np.sum(l_inv[:, self.pen] ** 2, axis=0)  # diag of H^-1 = L^-T L^-1
        _, d0, w, h_inv_diag = self._whole
        step, low = self._step(d0, w, drop)
        if low is not None:  # a model's H^-1 is the whole one's less W (E^T H^-1 E)^-1 W^T
            h_inv_diag = h_inv_diag - np.einsum("ij,jk,ik->i", low[0][self.pen], low[1], low[0][self.pen])
        # |r - J d|^2 from the normal equations (the Jacobian is not held)
        rss = self.rr - 2.0 * float(step @ self.rhs) + float(step @ self.gram @ step)
        # (H^-1 G)_ii = 1 - ridge_i (H^-1)_ii over the map's columns (G = H - ridge)
        edf = float(np.sum(1.0 - self.ridge_s[self.pen] * h_inv_diag))
        return rss, len(self.gram) - len(drop) - self.n_pen + edf

    def _parts(self, fold: np.ndarray) -> FoldParts:
        return self.parts.setdefault(fold.tobytes(), FoldParts(self.rows, self.free))

    def _folds(self, fold: np.ndarray) -> list | None:
        """Each fold's (d0, H^-1 E, held-out row indices, fold); None when a training set cannot identify the whole
        model."""
        key = fold.tobytes()
        if key not in self.fold_sets:
            parts = self._parts(fold)

            def solved(k):
                rows = np.flatnonzero(fold == k)
                g_k, b_k, _, _ = parts(k, rows)
                try:
                    _, d0, w = self._factor(self.gram - g_k, self.rhs - b_k)
                except np.linalg.LinAlgError:  # not positive definite: this training set cannot identify it
                    return None
                return d0, w, rows, k

            out = list((map if self.executor is None else self.executor.map)(solved, np.unique(fold)))
            self.fold_sets[key] = None if any(f is None for f in out) else out
        return self.fold_sets[key]

    def cv_rms_mm(self, fold: np.ndarray, drop: tuple[int, ...] = ()) -> float:
        """Held-out RMS of one coordinate (mm) over `fold` (the fold of every row), base parameters `drop` at 0."""
        folds = self._folds(fold)
        if folds is None:
            return self._cv_rms_one_by_one(fold, drop)
        ss, parts = 0.0, self._parts(fold)
        for d0, w, rows, k in folds:
            step = self._step(d0, w, drop)[0]
            _, _, rk, j_free = parts(k, rows)
            e = rk - j_free @ step[self.free]
            # the map's columns as predict sees them (clamped to the training rows' arcs), `PIECE` rows at a time
            for a0 in range(0, len(rows), PIECE):
                piece = self.held.piece(rows, slice(a0, a0 + PIECE))
                e[3 * a0 : 3 * (a0 + PIECE)] -= self.held.times(piece, step[self.pen][:, None], self.at_pen)[:, 0]
            if self.unwhiten is not None:
                e = np.einsum("nij,nj->ni", self.unwhiten[rows], e.reshape(-1, 3)).ravel()
            ss += float(e @ e)
        return float(np.sqrt(ss / (3 * self.n_rows)))

    def _cv_rms_one_by_one(self, fold: np.ndarray, drop: tuple[int, ...]) -> float:
        """cv_rms_mm by `_cv_scores` (the unpenalised block by pseudo-inverse) on the model with `drop` removed: its
        residual r + J_gone x (x the removed parameters' fitted values), its folds' parts those of the whole model
        less the removed columns."""
        gone = self.k + np.asarray(drop, dtype=int)
        keep = np.setdiff1d(np.arange(len(self.gram)), gone)
        pen = np.flatnonzero(np.isin(keep, self.pen))
        x = self.x_base[list(drop)]
        rhs = self.rhs[keep] + self.gram[np.ix_(keep, gone)] @ x
        whole, at_gone = self._parts(fold), np.searchsorted(self.free, gone)  # the base's columns are unpenalised
        stay = np.setdiff1d(np.arange(len(self.free)), at_gone)

        def parts(k, rows):
            g, b, rk, j_free = whole(k, rows)
            moved = (b[keep] + g[np.ix_(keep, gone)] @ x, rk + j_free[:, at_gone] @ x)
            return g[np.ix_(keep, keep)], *moved, j_free[:, stay]

        _, ss_mm = _cv_scores(
            parts,
            self.n_rows,
            self.gram[np.ix_(keep, keep)],
            rhs,
            self.unwhiten,
            pen,
            fold,
            [pen],
            [self.ridge],
            self.held,
        )
        return float(np.sqrt(ss_mm[0, 0] / (3 * self.n_rows)))


def _with_base(base: Extension | None, ext: Extension) -> Extension:
    return ext if base is None else combine([base, ext], cause=CAUSE)


def _penalised_fit(
    problem: Problem,
    state: State,
    k0: int,
    n_map: int,
    lam: float,
    at_start: tuple[np.ndarray, np.ndarray, float] | None = None,
    executor: Executor | None = None,
) -> tuple[Identification, float]:
    """Gauss-Newton on |r|^2 + lam |c|^2 (c the map coefficients, the `n_map` unknowns from column `k0`) from
    `state`, the fit without the map (`at_start`: its normal equations (J^T J, J^T r, r.r) if already formed; the
    row chunks of the others formed in `executor` when given):
    (identification with the posterior covariance s^2 (J^T J + lam P)^-1, effective number of map parameters).

    It stops as `calib.identify.solver.solve` does: when a step, or all the steps still to come after it (the rate of
    the last two steps telling their sum), moves the fit by less than 1e-9 of the residual (issue 26: two
    Gauss-Newton steps on Series B where a fixed test on the step alone took five, each a Jacobian of ~700 columns;
    the steps skipped were below 2e-9 of the residual). The covariance is taken with the Jacobian of the state
    before the last step. Each step's normal equations are summed over row chunks (`Problem.normal_equations`), and
    |J d| is sqrt(d^T J^T J d): the Jacobian (3N x ~700 float64) is never held whole (issue 41)."""
    pen = np.zeros(problem.n_cols)
    pen[k0 : k0 + n_map] = lam
    converged, prev, iterations = False, 0.0, 0
    gram, rhs, rr = problem.normal_equations(state, executor) if at_start is None else at_start
    for _ in range(GN_ITERATIONS):
        scale = np.sqrt(np.diag(gram))
        scale[scale == 0] = 1.0
        x = np.zeros(problem.n_cols)
        x[k0 : k0 + n_map] = state.ext[k0 - len(problem.params) :]
        ds = ridge_solve(gram / np.outer(scale, scale), (rhs - pen * x) / scale, pen / scale**2)
        state = problem.retract(state, ds / scale)
        iterations += 1
        d = ds / scale
        step, tol = float(np.sqrt(max(float(d @ gram @ d), 0.0))), 1e-9 * float(np.sqrt(rr))
        rate = step / prev if prev > 0 else 1.0
        if step <= tol or (rate <= 0.5 and rate / (1.0 - rate) * step <= tol):
            # the last step moved the fit by a small multiple of 1e-9 of the residual: the covariance keeps the
            # Gram matrix of the state before it (its entries differ by ~1e-9 relative), and the normal equations of
            # ~700 columns (a third of the fit's time) are not formed again
            converged = True
            break
        gram, rhs, rr = problem.normal_equations(state, executor)
        prev = step
    scale = np.sqrt(np.diag(gram))
    scale[scale == 0] = 1.0
    gram = gram / np.outer(scale, scale)  # not in place: it can be the caller's (at_start)
    h_inv = ridge_inverse(gram, pen / scale**2)
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
