"""Residual structure: can the residuals of a fitted model be predicted at all, whatever the cause?

Two tests, each at alpha / 2 (the caller's alpha):
- an end-frame error per pose: a free 6-dof perturbation of the robot's end frame at every pose seen
  with three points, F test against the rest of the residuals (any error of the arm at a pose, whatever
  its form; a ratio of variances, so the noise model's scale cancels);
- a generic smoother: ridge regression on joint-angle harmonics and approach directions through the
  joint Jacobian, time, station drift, and random Fourier features of angles and time, cross-validated
  by pose against predicting zero (one-sided t test over poses), the ridge chosen by an inner
  cross-validation over the training poses.
"""

from __future__ import annotations

import numpy as np
from scipy.special import fdtrc, stdtr  # F and t tails (scipy.stats: ~1 s to import)

from trackcal.calib.diagnose.extensions import approach_signs
from trackcal.calib.diagnose.fits import Context, Fit
from trackcal.calib.diagnose.ridge import ridge_path
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.rigid import skew

STRUCTURE_HARMONICS = 6
RANDOM_FEATURES = 48
RANK_TOL = 1e-9  # relative singular value below which a column direction counts as dependent
RIDGES = np.geomspace(1e-4, 1e4, 17)  # ridge values (relative to the mean squared feature times their count)


def _structure_features(ctx: Context, fit: Fit, table: MeasurementTable, seed: int) -> np.ndarray:
    """(3N, p) whitened regressors a residual with structure would correlate with, each column of unit norm. Written
    into one array group by group, whitened and scaled in place (issue 41: their concatenation, whitening and
    scaling were four copies, 22 KB per row of a KR-270 campaign)."""
    q = np.radians(table.q_deg)
    n_rows, n = q.shape
    tool = np.array([fit.points[p] for p in table.point])
    off = None if fit.extension is None else fit.extension.joint_offsets(fit.ext)
    jac = Kinematics(ctx.chain, ctx.params).jacobian(q if off is None else q + off, tool, fit.dev)
    rot = np.array([fit.stations[s].rotation for s in table.station])
    dq = np.einsum("nij,njk->nik", rot, jac.d_q)  # (N, 3, n): a joint error seen in the station frame
    t = table.t_s - table.t_s.min()
    t = t / max(float(t.max()), 1e-300)
    signs = approach_signs(q)
    stations = sorted(set(table.station))
    per_joint = 2 * STRUCTURE_HARMONICS + 2
    feats = np.zeros((n_rows, 3, n * per_joint + 3 * len(stations) + 3 * RANDOM_FEATURES))
    h = np.arange(1, STRUCTURE_HARMONICS + 1)
    for j in range(n):
        basis = np.column_stack([np.sin(np.outer(q[:, j], h)), np.cos(np.outer(q[:, j], h)), signs[:, j], t])
        np.multiply(dq[:, :, j, None], basis[:, None, :], out=feats[:, :, j * per_joint : (j + 1) * per_joint])
    at = n * per_joint
    for i, sid in enumerate(stations):
        m = (np.array(table.station) == sid).astype(float) * t
        for c in range(3):  # a drift of the station along its axis c
            feats[:, c, at + 3 * i + c] = m
    at += 3 * len(stations)
    x = np.column_stack([np.sin(q), np.cos(q), t])
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((x.shape[1], RANDOM_FEATURES))
    phase = rng.uniform(0, 2 * np.pi, RANDOM_FEATURES)
    rff = np.cos(x @ w + phase)
    for c in range(3):  # random Fourier features of the angles and time, in each coordinate
        feats[:, c, at + c * RANDOM_FEATURES : at + (c + 1) * RANDOM_FEATURES] = rff
    if ctx.noise is not None:
        wh = ctx.noise.whitening(table.xyz)
        for a0 in range(0, n_rows, 1024):  # in place, a block of rows at a time
            sl = slice(a0, a0 + 1024)
            feats[sl] = wh[sl] @ feats[sl]
    feats = feats.reshape(3 * n_rows, -1)
    norm = np.sqrt(np.einsum("ij,ij->j", feats, feats))
    if np.any(norm == 0):
        feats, norm = feats[:, norm > 0], norm[norm > 0]
    feats /= norm
    return feats


def _ridge_fit(gram: np.ndarray, rhs: np.ndarray, lams: np.ndarray) -> np.ndarray:
    """(len(lams), p) ridge coefficients (x^T x + lam I)^-1 x^T y for every ridge value, from x^T x and x^T y, by one
    tridiagonal reduction (`ridge_path`). Before issue 26 an SVD of x gave the same for 5x the cost (x has thousands
    of rows and ~230 unit columns). The smallest ridge (RIDGES) is far above the rounding of x^T x (eps times its
    largest eigenvalue), so the digits squaring loses do not reach the coefficients."""
    return ridge_path(gram, rhs, lams).T


def _ridge_predict(
    x: np.ndarray, y: np.ndarray, gram: np.ndarray, rhs: np.ndarray, test: np.ndarray, pose_idx: np.ndarray
) -> np.ndarray:
    """Ridge regression on every row (`x`, `y` by coordinate; gram = x^T x, rhs = x^T y) but the `test` rows,
    predicting the `test` rows' coordinates; the ridge chosen by an inner 3-fold cross-validation over the training
    poses (rows of a pose share their error, so rows are not independent enough for leave-one-out or GCV). Every fit
    from Gram matrices, the whole table's less the rows left out, each group of rows taken once (issue 41: the
    training rows' copies, four per fold, were 15 KB per row of a KR-270 campaign)."""
    te3 = _coords(test)
    x_te = x[te3]
    g_tr, b_tr = gram - x_te.T @ x_te, rhs - x_te.T @ y[te3]
    lams = RIDGES * float(np.trace(g_tr)) / (len(y) - len(te3))  # the mean squared feature times their count
    train = np.setdiff1d(np.arange(len(pose_idx)), test)
    pose_tr = pose_idx[train]
    sse = np.zeros(len(lams))
    for g in np.array_split(np.unique(pose_tr), 3):
        c3 = _coords(train[np.isin(pose_tr, g)])
        x_g, y_g = x[c3], y[c3]
        coef = _ridge_fit(g_tr - x_g.T @ x_g, b_tr - x_g.T @ y_g, lams)
        sse += np.sum((y_g[None] - coef @ x_g.T) ** 2, axis=1)
    return x_te @ _ridge_fit(g_tr, b_tr, lams[[int(np.argmin(sse))]])[0]


def _coords(rows: np.ndarray) -> np.ndarray:
    """The coordinates (3 per row) of `rows`, in order."""
    return (3 * np.asarray(rows)[:, None] + np.arange(3)).ravel()


def smoother_test(
    ctx: Context, fit: Fit, table: MeasurementTable, folds: list[np.ndarray] | None, seed: int
) -> dict | None:
    """Can the residuals be predicted from joint angles, approach directions, time or station? A ridge
    regression on generic features, cross-validated against predicting zero, paired over poses, one-sided
    t test. None with fewer than 10 poses."""
    if folds is None or len(set(table.pose)) < 10:
        return None
    y = fit.r
    x = _structure_features(ctx, fit, table, seed)
    pose_idx = np.unique(np.array(table.pose), return_inverse=True)[1]

    gram, rhs = x.T @ x, x.T @ y

    def fold_gain(test: np.ndarray) -> np.ndarray:
        te3 = _coords(test)
        pred = _ridge_predict(x, y, gram, rhs, test, pose_idx)
        return np.sum((y[te3] ** 2 - (y[te3] - pred) ** 2).reshape(-1, 3), axis=1)

    gain = np.zeros(len(table))
    # the folds in the context's threads when it has them (their LAPACK calls release the GIL)
    for test, g in zip(folds, (map if ctx.executor is None else ctx.executor.map)(fold_gain, folds), strict=True):
        gain[test] = g
    pose_arr = np.array(table.pose)
    per_pose = np.array([gain[pose_arr == p].sum() for p in sorted(set(table.pose))])
    sd = float(per_pose.std(ddof=1))
    tval = float(per_pose.mean()) / (sd / np.sqrt(len(per_pose))) if sd > 0 else 0.0
    return {
        "test": "cross-validated smoother",
        "pvalue": float(stdtr(len(per_pose) - 1, -tval)),
        "predictable_fraction": float(gain.sum() / float(y @ y)),
    }


def pose_frame_test(ctx: Context, fit: Fit, table: MeasurementTable) -> dict | None:
    """Do the residuals of each pose share an error of the robot's end frame (6 dof per pose: any error
    of the arm at that pose, whatever its form)? F test of the residuals explained by a free end-frame
    perturbation per pose (beyond what the fitted model can absorb) against the rest. Scale-free: the
    residuals' radial and transverse scales (tracker line of sight) are estimated from the residuals and
    divided out first, so a tracker noisier than its model, in either direction, does not pass for
    structure. Needs poses seen with three points; None with fewer than 5 such poses."""
    n_rows = len(table)
    poses: dict[str, list[int]] = {}
    for i, p in enumerate(table.pose):
        poses.setdefault(p, []).append(i)
    usable = [np.array(rows) for rows in poses.values() if len({table.point[i] for i in rows}) >= 3]
    if len(usable) < 5:
        return None
    q = np.radians(table.q_deg)
    off = None if fit.extension is None else fit.extension.joint_offsets(fit.ext)
    q = q if off is None else q + off
    tool = np.array([fit.points[p] for p in table.point])
    kin = Kinematics(ctx.chain, ctx.params)
    _, o_end = kin.end_frames(q, fit.dev)
    p_base = kin.points(q, tool, fit.dev)
    rot = np.array([fit.stations[s].rotation for s in table.station])
    frame = np.concatenate([np.broadcast_to(np.eye(3), (n_rows, 3, 3)), -skew(p_base - o_end)], axis=2)
    cols = np.einsum("nij,njk->nik", rot, frame)  # (N, 3, 6): end-frame translation and rotation
    if ctx.noise is not None:
        cols = np.einsum("nij,njk->nik", ctx.noise.whitening(table.xyz), cols)
    r, jm = fit.r.reshape(n_rows, 3), fit.jm.reshape(n_rows, 3, -1)
    # the line of sight stays an eigen-direction of the tracker-model whitening: rescale along and across it
    los = table.xyz / np.linalg.norm(table.xyz, axis=1)[:, None]
    along = np.einsum("ni,ni->n", los, r)
    k_along = np.sqrt(np.mean(along**2))
    k_across = np.sqrt(np.mean(np.sum(r**2, axis=1) - along**2) / 2.0)

    def rescale(v: np.ndarray) -> np.ndarray:
        a = np.einsum("ni,ni...->n...", los, v)
        return (v - np.einsum("ni,n...->ni...", los, a)) / k_across + np.einsum("ni,n...->ni...", los, a) / k_along

    r, jm, cols = rescale(r), rescale(jm), rescale(cols)
    rss0 = _orthogonal_rss(r.ravel(), _basis(jm.reshape(3 * n_rows, -1)))
    rank_b = 0
    for rows in usable:
        b = cols[rows].reshape(-1, 6)
        u, sv, _ = np.linalg.svd(b, full_matrices=False)
        u = u[:, sv > RANK_TOL * sv[0]]
        rank_b += u.shape[1]
        rp, jp = r[rows].ravel(), jm[rows].reshape(-1, jm.shape[2])
        r[rows] = (rp - u @ (u.T @ rp)).reshape(-1, 3)
        jm[rows] = (jp - u @ (u.T @ jp)).reshape(len(rows), 3, -1)
    basis = _basis(jm.reshape(3 * n_rows, -1))
    rss1, rank_mj = _orthogonal_rss(r.ravel(), basis), basis.shape[1]
    df1 = rank_b + rank_mj - fit.n_cols
    df2 = 3 * n_rows - rank_b - rank_mj
    if df1 <= 0 or df2 <= 0 or rss1 <= 0:
        return None
    f = ((rss0 - rss1) / df1) / (rss1 / df2)
    return {
        "test": "end-frame error per pose",
        "pvalue": float(fdtrc(df1, df2, f)),
        "predictable_fraction": float((rss0 - rss1) / rss0),
        "dof": [int(df1), int(df2)],
        "scale_along_line_of_sight": float(k_along),
        "scale_across": float(k_across),
    }


def _basis(m: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the column space of m (columns scaled to unit norm first)."""
    m = m / np.where(np.linalg.norm(m, axis=0) > 0, np.linalg.norm(m, axis=0), 1.0)
    u, sv, _ = np.linalg.svd(m, full_matrices=False)
    return u[:, sv > RANK_TOL * sv[0]]


def _orthogonal_rss(r: np.ndarray, basis: np.ndarray) -> float:
    """Residual sum of squares of r after least squares on an orthonormal basis."""
    return float(r @ r - np.sum((basis.T @ r) ** 2))


def structure_test(
    ctx: Context, fit: Fit, table: MeasurementTable, folds: list[np.ndarray] | None, seed: int, alpha: float
) -> dict:
    """Residual structure of `fit`: the tests that apply to this table, each at alpha / (number of tests)."""
    tests = [t for t in (pose_frame_test(ctx, fit, table), smoother_test(ctx, fit, table, folds, seed)) if t]
    if not tests:
        return {
            "structure": False,
            "pvalue": None,
            "tests": [],
            "note": "too few poses to test the residuals for structure",
        }
    p = min(1.0, len(tests) * min(t["pvalue"] for t in tests))
    return {"structure": p < alpha, "pvalue": p, "tests": tests}
