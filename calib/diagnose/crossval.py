"""Cross-validation of the candidate models: folds, held-out errors, and comparisons of two models on the same folds.

A fold's fit is one Gauss-Newton step from the whole-table fit (`calib.diagnose.fits.whole_fit`) on the training
rows (the Gram matrix of the whole table minus the fold's rows): the fold's solution is about a standard deviation
away, where the model is linear to far below the noise. Folds are whole poses (with edge folds: each joint's extreme
poses held out, so that extrapolation is judged), passes of the plan, or blocks of time within each station; a
scheme whose training sets cannot identify the model gives None, and the comparison moves to the next.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from trackcal.calib.diagnose.changepoint import SHIFT
from trackcal.calib.diagnose.fits import (
    Context,
    Fit,
    extension_of,
    fit_model,
    identifiable,
    predict_rows,
    scan,
    whole_fit,
)
from trackcal.calib.diagnose.significance import HeldOut
from trackcal.calib.identify.solver import CHUNK_BYTES, IdentificationError
from trackcal.calib.io.table import MeasurementTable

TIME_CAUSES = ("thermal_drift", SHIFT, "thermal_warmup")  # judged by blocks of time within each station first
FOLD_ITERATIONS = 30
EDGE_SHARE = 0.1  # the share of each joint's poses, at either end of its range, an edge fold holds out


def fold_rows(
    table: MeasurementTable, scheme: str, folds: int, seed: int, cut: tuple[str, float] | None = None
) -> list[np.ndarray] | None:
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
        sides = (
            [rows]
            if cut is None or cut[0] != sid
            else [rows[table.t_s[rows] <= cut[1]], rows[table.t_s[rows] > cut[1]]]
        )
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
    gram, grad = full.gram, full.grad
    # the training rows only for a change point's scan (a set difference per fold was 1 % of a diagnosis of the UR10's
    # Series B, issue 41)
    trains = [None] * len(folds) if full.shift is None else [np.setdiff1d(np.arange(n), test) for test in folds]
    cut = None if full.shift is None else (full.shift["station"], full.shift["after_t_s"])
    moved = [train is not None and scan(ctx, train) != cut for train in trains]
    held = _held_out_rows(full, [test for test, m in zip(folds, moved, strict=True) if not m], n)
    sq, count = np.zeros(n), np.zeros(n, dtype=int)
    for test, train, m in zip(folds, trains, moved, strict=True):
        if m:
            try:
                fit = fit_model(ctx, causes, train, FOLD_ITERATIONS)
            except IdentificationError:
                return None
            pred = predict_rows(ctx, fit, test, extension_of(ctx, causes, test))
            if pred is None:
                return None
            e = ctx.table.xyz[test] - pred
        else:
            rt, jt = next(held)
            g = gram - jt.T @ jt
            if not identifiable(g):
                return None
            d = np.sqrt(np.diag(g))
            step = np.linalg.solve(g / np.outer(d, d), (grad - jt.T @ rt) / d) / d
            e = (rt - jt @ step).reshape(-1, 3)
            e = e if ctx.unwhiten is None else np.einsum("nij,nj->ni", ctx.unwhiten[test], e)
        np.add.at(sq, test, np.sum(e**2, axis=1))
        np.add.at(count, test, 1)
    return HeldOut(sq, count)


def _held_out_rows(full: Fit, folds: list[np.ndarray], n: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The whitened residuals and Jacobian rows (`Fit.rows`) of each fold's rows (of a table of n) at the fit, fold
    by fold. The rows of folds that follow each other are formed at once, as many folds as keep their Jacobian within
    CHUNK_BYTES (at least one fold): the fit holds no whole Jacobian (issue 41), and a pass per fold was half of a
    cross-validation of the UR10's Series B. A row's numbers do not depend on the rows formed with it (bar rounding
    where one station's rows are formed with another's: the rotations are then applied row by row)."""
    limit = max(1, CHUNK_BYTES // (24 * full.n_cols))  # rows: 3 float64 per row and column
    i = 0
    while i < len(folds):
        formed = np.zeros(n, dtype=bool)
        formed[folds[i]], j = True, i + 1
        while j < len(folds) and np.count_nonzero(formed) + np.count_nonzero(~formed[folds[j]]) <= limit:
            formed[folds[j]], j = True, j + 1
        rows = np.flatnonzero(formed)
        r, jm = full.rows(rows)
        r, jm = r.reshape(-1, 3), jm.reshape(len(rows), 3, -1)
        for test in folds[i:j]:
            at = np.searchsorted(rows, test)
            yield r[at].ravel(), jm[at].reshape(-1, jm.shape[2])
        i = j


def trainable(ctx: Context, causes: tuple[str, ...], test: np.ndarray) -> bool:
    """Whether the rows other than `test` identify the model `causes` (its whole-table fit's Gram matrix less
    the held-out rows')."""
    try:
        full = whole_fit(ctx, causes)
    except IdentificationError:
        return False
    jt = full.rows(np.asarray(test))[1]
    return identifiable(full.gram - jt.T @ jt)


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
            folds = (
                self.fold_sets[scheme] if cut is None else fold_rows(self.ctx.table, scheme, self.folds, self.seed, cut)
            )
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

    def compare(
        self, base: tuple[str, ...], model: tuple[str, ...]
    ) -> tuple[str | None, HeldOut | None, HeldOut | None]:
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
