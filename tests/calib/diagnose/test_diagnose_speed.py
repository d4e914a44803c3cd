"""issue 26: diagnose made faster without changing what it finds. Each fast path against the code it replaced, kept
here as a reference function: equal where the arithmetic is the same, within 1e-9 relative / 1e-6 mm where it is
not (a warm start stops at the same minimum to the solver's step test). On the real UR10's Series B (when the data
set is present) the verdict and its held-out figures are those of the code before issue 26."""

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from studies.ur10_ipa.study import DATA, SERIES
from tests.helpers import DenseRows, backlash_twin_case, held_columns, held_out_map
from trackcal.calib.diagnose import crossval, diagnose, fits
from trackcal.calib.diagnose.extensions import approach_signs
from trackcal.calib.diagnose.joint_map import Arc, harmonic_names, map_features, parse_name
from trackcal.calib.diagnose.joint_map_fit import FoldParts, _cv_scores
from trackcal.calib.diagnose.structure import (
    RANDOM_FEATURES,
    RIDGES,
    STRUCTURE_HARMONICS,
    _coords,
    _ridge_fit,
    _ridge_predict,
    _structure_features,
)
from trackcal.calib.identify import solver
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Problem, State, Station, _distinct_poses
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.extension import JointFeatures
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model.rigid import exp_so3
from trackcal.campaign.cli import main

CELL = load_cell("kr270")


@pytest.fixture(scope="module")
def twin_case():
    return backlash_twin_case(CELL)


def reference_distinct_poses(q, feats):
    """Before issue 26: np.unique over the whole key [q, features]."""
    key = q if feats is None else np.hstack([q, feats.reshape(len(q), -1)])
    _, first, of_row = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return first, of_row.ravel()


@pytest.mark.parametrize("kind", ["none", "of_angles", "not_of_angles"])
def test_distinct_poses_equal_the_whole_key(kind):
    rng = np.random.default_rng(3)
    q = rng.uniform(-3, 3, (12, 6))[rng.integers(0, 12, 60)]  # 60 rows, poses repeated
    one_joint = np.zeros((6, 6))  # column e moves joint e alone, as every extension's features do (JointFeatures)
    one_joint[np.arange(6), np.arange(6)] = 1.0
    dense = {
        "none": None,
        "of_angles": np.sin(q)[:, :, None] * one_joint,
        "not_of_angles": rng.choice([-1.0, 1.0], (60, 6, 1)) * one_joint,
    }[kind]
    feats = None if dense is None else JointFeatures.of(dense)
    first, of_row = _distinct_poses(q, feats)
    ref_first, ref_of_row = reference_distinct_poses(q, dense)
    assert np.array_equal(first, ref_first) and np.array_equal(of_row, ref_of_row)
    if kind == "not_of_angles":  # the direction of motion splits poses of equal angles
        assert len(first) > len(np.unique(q, axis=0))


def test_map_features_equal_one_call_per_coefficient():
    rng = np.random.default_rng(4)
    q = rng.uniform(-3, 3, (200, 6))
    arcs = {j: Arc.covering(q[:, j]) for j in (0, 2, 3)}
    names = [nm for j in arcs for nm in harmonic_names(j, 9)][::-1]
    feats = map_features(q, names, arcs)
    ref = np.zeros_like(feats)
    clamped = {j: arc.clamp(q[:, j])[0] for j, arc in arcs.items()}
    for i, name in enumerate(names):  # before issue 26
        kind, h, j = parse_name(name)
        ref[:, j, i] = (np.sin if kind == "s" else np.cos)(h * clamped[j])
    assert np.array_equal(feats, ref)


def test_fold_parts_formed_once_give_the_same_scores():
    # each fold's part of the normal equations is formed once and kept for the next cross-validation of the same
    # problem (the map's search and its comparison without the map): the same scores bit for bit, and the held-out
    # rows' residual and unpenalised columns those of the Jacobian
    rng = np.random.default_rng(5)
    jm, r = rng.standard_normal((300, 30)), rng.standard_normal(300)
    fold = np.repeat(np.arange(5), 20)[rng.permutation(100)]
    pen, gram, rhs = np.arange(10, 30), jm.T @ jm, jm.T @ r
    orders, rows, free = [pen[:10], pen], DenseRows(jm, r, pen), np.arange(10)
    plain = _cv_scores(FoldParts(rows, free, keep=False), 100, gram, rhs, None, pen, fold, orders, [0.1, 1.0], rows)
    kept = FoldParts(rows, free)
    for _ in range(2):  # formed the first time, reused the second
        fast = _cv_scores(kept, 100, gram, rhs, None, pen, fold, orders, [0.1, 1.0], rows)
        assert all(np.array_equal(a, b) for a, b in zip(plain, fast, strict=True))
    held = np.flatnonzero(fold == 3)
    g, b, rk, j_free = kept(3, held)
    coords = _coords(held)
    assert np.array_equal(rk, r[coords]) and np.array_equal(j_free, jm[coords][:, free])
    assert np.allclose(g, jm[coords].T @ jm[coords], rtol=1e-12, atol=1e-12 * np.abs(g).max())


def test_the_search_without_the_map_in_the_same_pass():
    # issue 41: the map's search scores the model without the map as one more order (no column) of its own pass over
    # the folds: the map's orders' scores bit for bit those of a pass without it, and the model without the map's, at
    # every ridge, the held-out errors of least squares on each fold's training rows (its unpenalised columns alone)
    rng = np.random.default_rng(8)
    jm, r = rng.standard_normal((300, 30)), rng.standard_normal(300)
    fold = np.repeat(np.arange(5), 20)[rng.permutation(100)]
    pen, gram, rhs = np.arange(10, 30), jm.T @ jm, jm.T @ r
    orders, rows, free, lams = [pen[:10], pen], DenseRows(jm, r, pen), np.arange(10), [0.1, 1.0, 10.0]
    args = (100, gram, rhs, None, pen, fold)
    alone = _cv_scores(FoldParts(rows, free, keep=False), *args, orders, lams, rows)
    both = _cv_scores(FoldParts(rows, free, keep=False), *args, [*orders, pen[:0]], lams, rows)
    assert all(np.array_equal(a, b[:-1]) for a, b in zip(alone, both, strict=True))
    ss = 0.0
    for k in range(5):
        test = np.isin(np.arange(300) // 3, np.flatnonzero(fold == k))
        x = np.linalg.lstsq(jm[~test][:, free], r[~test], rcond=None)[0]
        ss += float(np.sum((r[test] - jm[test][:, free] @ x) ** 2))
    assert np.allclose(both[0][-1], ss, rtol=1e-12) and np.array_equal(both[0][-1], both[1][-1])


def test_ridge_path_from_the_gram_matrix_equals_the_svd():
    rng = np.random.default_rng(6)
    x = rng.standard_normal((600, 80))
    x[:, -1] = x[:, 0] + 1e-9 * rng.standard_normal(600)  # a nearly dependent column, as generic features have
    x /= np.linalg.norm(x, axis=0)
    y = rng.standard_normal(600)
    lams = RIDGES * float(np.mean(x**2)) * x.shape[1]
    u, s, vt = np.linalg.svd(x, full_matrices=False)  # before issue 26
    ref = np.array([vt.T @ (s / (s**2 + lam) * (u.T @ y)) for lam in lams])
    fast = _ridge_fit(x.T @ x, x.T @ y, lams)
    assert np.allclose(x @ fast.T, x @ ref.T, rtol=1e-9, atol=1e-12 * np.linalg.norm(y))  # the predictions
    assert np.allclose(fast, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())


def reference_solve(problem, state, max_iter=100):
    """`solver.solve` before issue 26 (every trial after a taken step formed its normal equations): (state, nit)."""
    info, g, cost = problem.normal_equations(state)
    dof = max(3 * problem.n_rows - problem.n_cols, 1)
    floor = 1e-15 * float(np.linalg.norm(problem._whiten(problem.xyz)))
    lam, iterations, fused, prev, eye, info_s = 1e-8, 1, True, 0.0, np.eye(problem.n_cols), None
    for _ in range(max_iter):
        if info_s is None:
            scale = np.sqrt(np.diag(info))
            scale[scale == 0] = 1.0
            info_s, gs = info / np.outer(scale, scale), g / scale
        ds = np.linalg.solve(info_s + lam * eye, gs)
        jd2 = float(ds @ info_s @ ds)
        step, tol = np.sqrt(jd2), 1e-9 * np.sqrt(cost / dof) + floor
        rate = step / prev if prev > 0 else 1.0
        if lam <= 1e-6 and (step <= tol or (rate <= 0.5 and rate / (1.0 - rate) * step <= tol)):
            return problem.retract(state, ds / scale), iterations + 1
        cand = problem.retract(state, ds / scale)
        if fused:
            info_new, g_new, cost_new = problem.normal_equations(cand)
        else:
            r_new = problem.residual(cand)
            cost_new = float(r_new @ r_new)
        if cost_new <= cost or 2.0 * float(gs @ ds) - jd2 <= 1e-10 * cost:
            state = cand
            info, g, cost = (info_new, g_new, cost_new) if fused else problem.normal_equations(state)
            info_s, iterations, prev = None, iterations + 1, step if lam <= 1e-6 else 0.0
            lam, fused = max(lam / 10.0, 1e-12), True
        else:
            lam, fused = lam * 10.0, False
            if lam > 1e8:
                break
    return state, iterations


def test_solver_takes_the_same_steps_with_fewer_normal_equations(twin_case):
    """From far off (the station turned by 2.5 rad and moved by 100 mm, the points by 50 mm), where the undamped step
    overshoots and steps are refused, the solver walks the same iterates as before and forms fewer normal
    equations (72 iterations: 74 against 94; from 1.8 rad on this table nothing was refused, 14 against 14)."""
    table, params, _ = twin_case
    calls = {"new": 0, "old": 0}
    results = {}
    for which, run in (
        ("new", lambda p, s: (lambda sol: (sol.state, sol.nit))(solver.solve(p, s))),
        ("old", reference_solve),
    ):
        problem = Problem(CELL.chain, table, CELL.tool_points, params, TrackerNoise())
        s0 = problem.initial
        turn = exp_so3(2.5 * np.array([0.3, -0.2, 1.0]))
        start = State(
            s0.dev,
            [Station(turn @ st.rotation, st.translation + 100.0) for st in s0.stations],
            s0.points + 50.0,
            s0.ext,
        )
        counted = problem.normal_equations

        def count(s, counted=counted, which=which):
            calls[which] += 1
            return counted(s)

        problem.normal_equations = count
        results[which] = run(problem, start)
    (new, nit_new), (old, nit_old) = results["new"], results["old"]
    assert nit_new == nit_old
    assert np.array_equal(new.dev, old.dev) and np.array_equal(new.points, old.points)
    assert calls["new"] < calls["old"]  # refused steps happened, and their normal equations were not formed


def test_warm_started_fit_stops_at_the_same_minimum(twin_case):
    """A model of two causes fitted from the fit of one (issue 26) and from the geometric solution (before): the
    same residual sum to 1e-9 and the same held-out RMS to 1e-6 mm."""
    table, params, geo = twin_case
    causes = ("joint_compliance", "backlash")
    ctx = fits.context(CELL.chain, table, params, TrackerNoise(), geo, causes)
    fits.whole_fit(ctx, causes[:1])
    assert fits.warm_start(ctx, causes) is ctx.fits[causes[:1]]
    folds = crossval.fold_rows(table, "pose", 5, 0)
    warm = fits.fit_model(ctx, causes)
    ctx.fits[tuple(sorted(causes))] = warm
    hold_warm = crossval.cross_validate(ctx, causes, folds).rms_mm
    cold = fits._whole_fit(ctx, ctx.table, fits.extension_of(ctx, causes), 100)
    ctx.fits[tuple(sorted(causes))] = cold
    hold_cold = crossval.cross_validate(ctx, causes, folds).rms_mm
    assert warm.rss == pytest.approx(cold.rss, rel=1e-9)
    assert hold_warm == pytest.approx(hold_cold, abs=1e-6)
    assert np.allclose(warm.ext, cold.ext, rtol=1e-6, atol=1e-9)


def reference_cross_validate(ctx, causes, folds):
    """Before issue 41's shared passes: each fold's rows formed alone (`Fit.rows` of the fold)."""
    full = fits.whole_fit(ctx, causes)
    sq, count = np.zeros(len(ctx.table)), np.zeros(len(ctx.table), dtype=int)
    for test in folds:
        rt, jt = full.rows(test)
        g = full.gram - jt.T @ jt
        d = np.sqrt(np.diag(g))
        step = np.linalg.solve(g / np.outer(d, d), (full.grad - jt.T @ rt) / d) / d
        e = np.einsum("nij,nj->ni", ctx.unwhiten[test], (rt - jt @ step).reshape(-1, 3))
        np.add.at(sq, test, np.sum(e**2, axis=1))
        np.add.at(count, test, 1)
    return sq, count


@pytest.mark.parametrize("piece_rows", [None, 40])
def test_folds_formed_together_give_the_held_out_errors_of_folds_formed_alone(twin_case, monkeypatch, piece_rows):
    """cross_validate forms the rows of several folds in one pass (all 87 rows of the 16 folds here, or, with pieces
    of 40 rows of Jacobian, those of folds that follow each other up to 40 rows): the same held-out errors as each
    fold formed alone, to rounding: a fold of one station's rows alone is rotated into its frame at once, with the
    other station's rows row by row, which moves a coordinate of ~3,000 mm by its rounding (~5e-13 mm), a held-out
    error of ~0.05 mm by ~1e-11 of it (5.6e-11 measured): 1e-9 leaves a margin, and catches any row or fold mixed up."""
    table, params, geo = twin_case
    causes = ("joint_compliance", "backlash")
    ctx = fits.context(CELL.chain, table, params, TrackerNoise(), geo, causes)
    full = fits.whole_fit(ctx, causes)
    if piece_rows is not None:
        monkeypatch.setattr(crossval, "CHUNK_BYTES", 24 * full.n_cols * piece_rows)
    formed = []

    def rows(fit, r):
        formed.append(len(r))
        return fit.problem.residual_and_jacobian(fit.state, r)

    monkeypatch.setattr(fits.Fit, "rows", rows)
    folds = crossval.fold_rows(table, "pose", 5, 0) + crossval.edge_rows(table)  # edge folds overlap the others
    held = crossval.cross_validate(ctx, causes, folds)
    passes = formed[:]
    sq, count = reference_cross_validate(ctx, causes, folds)
    assert np.array_equal(held.count, count)
    assert np.allclose(held.sq, sq, rtol=1e-9, atol=0)
    if piece_rows is None:
        assert passes == [len(table)]
    else:
        assert len(folds) > len(passes) > 1 and max(passes) <= piece_rows


# Series B as the README's UR10 section runs it (--weighting iid --params P): the verdict and held-out figures the
# code before issue 26 (commit c83d06f) printed on this data set. A regression check of identical algorithm output:
# the verdict's figures are computed by the same arithmetic today (the warm starts move the candidates' figures by
# ~1e-12 mm, the structure test's by ~1e-16 relative).
B_PARAMS = "px1,py1,phix1,dq2,px2,phix2,phiy2,dq3,px3,phix3,phiy3,dq4,px4,py4,phix4,dq5"
# Issue 36 added the edge folds (each joint's extreme poses held out) to the held-out figures, on purpose: the
# verdict is unchanged, its figures are now those of the partition and the edge folds (before: 0.25695947777930694
# -> 0.07770870938575124 on the partition alone).
B_BEFORE = {
    "cause": "cyclic_error",
    "causes": ["joint_compliance", "cyclic_error"],
    "rms_geometric_mm": 0.25725176765956365,
    "rms_extended_mm": 0.10522610739998324,
}


# slow: 12 s of real data; the fast paths are checked against the code they replaced by default (above)
@pytest.mark.slow
@pytest.mark.skipif(not (DATA / SERIES["B"]).exists(), reason="IPA data set not present (TRACKCAL_IPA_DATA)")
def test_series_b_verdict_and_held_out_figures_are_unchanged(tmp_path: Path):
    b = tmp_path / "b.csv"
    assert main(["import", "ipa-ur10", str(DATA / SERIES["B"]), "--out", str(b)]) == 0
    out = tmp_path / "verdict.json"
    assert (
        main(["diagnose", str(b), "--cell", "ur10-ipa", "--weighting", "iid", "--params", B_PARAMS, "--json", str(out)])
        == 0
    )
    doc = json.loads(out.read_text())
    assert doc["cause"] == B_BEFORE["cause"]
    assert [c["cause"] for c in doc["causes"]] == B_BEFORE["causes"]
    assert doc["holdout"]["rms_geometric_mm"] == pytest.approx(B_BEFORE["rms_geometric_mm"], abs=1e-6)
    assert doc["holdout"]["rms_extended_mm"] == pytest.approx(B_BEFORE["rms_extended_mm"], abs=1e-6)


def test_threads_give_the_same_diagnosis_bit_for_bit(twin_case):
    """The folds of the joint map's search and of the structure test solved in a thread pool, put together in fold
    order: every candidate's figures and the structure test equal those of the diagnosis without threads, to the
    last bit."""
    table, params, geo = twin_case
    plain = diagnose(CELL.chain, table, CELL.tool_points, params, TrackerNoise(), geometric=geo)
    with ThreadPoolExecutor(2) as ex:
        threaded = diagnose(CELL.chain, table, CELL.tool_points, params, TrackerNoise(), geometric=geo, executor=ex)
    assert any(c.cause == "cyclic_error" and c.detail.get("error_map") for c in plain.candidates)  # the search ran
    figures = [
        (c.cause, c.step, c.rss, c.f_pvalue, c.delta_bic, c.holdout_rms_mm, c.holdout_base_mm) for c in plain.candidates
    ]
    assert figures == [
        (c.cause, c.step, c.rss, c.f_pvalue, c.delta_bic, c.holdout_rms_mm, c.holdout_base_mm)
        for c in threaded.candidates
    ]
    assert (plain.cause, plain.holdout_extended_mm) == (threaded.cause, threaded.holdout_extended_mm)
    assert plain.structure == threaded.structure  # the smoother test folds in threads
    assert "cross-validated smoother" in [t["test"] for t in plain.structure["tests"]]


def test_held_out_map_columns_equal_the_dense_features_times_the_levers(twin_case):
    """The held-out rows' map columns formed joint by joint (a coefficient moves its own joint only), from the
    problem's features where a row lies inside the training rows' arcs and formed again, clamped, where it does not,
    equal the columns from the dense (N, n, e) features, as formed before issue 26's last stop, bit for bit."""
    table, params, geo = twin_case
    q = np.radians(table.q_deg)
    arcs = {j: Arc.covering(q[:, j]) for j in range(CELL.chain.dof)}
    held, names = held_out_map(CELL, table, geo, params, arcs, 5)
    test = np.arange(0, len(table), 4)
    train = np.setdiff1d(np.arange(len(table)), test)
    arcs_train = {j: Arc.covering(q[train, j]) for j in arcs}
    assert any(arc.clamp(q[test, j])[1].any() for j, arc in arcs_train.items())  # rows beyond a training arc
    feats = map_features(q[test], names, arcs_train)
    ref = np.einsum("rcj,rje->rce", held.lever[test], feats).reshape(3 * len(test), -1)
    assert np.array_equal(held_columns(held, test), ref)
    # a piece of the held-out rows: its rows of the same columns
    assert np.array_equal(held_columns(held, test, slice(5, 17)), ref[15:51])


def test_held_out_map_times_coefficients_equals_its_columns_times_them(twin_case):
    """`HeldOutMap.times`, joint by joint from the clamped features (issue 41: the columns are not formed), equals the
    columns times the coefficients to rounding, for every coefficient and for an order's subset (a joint's lower
    harmonics), several right-hand sides at once, on a piece of the held-out rows."""
    table, params, geo = twin_case
    q = np.radians(table.q_deg)
    held, names = held_out_map(CELL, table, geo, params, {j: Arc.covering(q[:, j]) for j in range(CELL.chain.dof)}, 4)
    test = np.arange(2, len(table), 3)
    cols = held_columns(held, test, slice(3, 20))
    c = np.random.default_rng(7).standard_normal((len(names), 3))
    low = np.flatnonzero([parse_name(nm)[1] <= 2 for nm in names])
    piece = held.piece(test, slice(3, 20))
    for idx in (np.arange(len(names)), low):
        ref = cols[:, idx] @ c[idx]
        # float64 sums of len(idx) products: the two orders of summation differ by len(idx) eps of the terms' sum
        tol = len(idx) * np.finfo(float).eps * (np.abs(cols[:, idx]) @ np.abs(c[idx])).max()
        got = held.times(piece, c[idx], idx)
        assert got.shape == ref.shape and np.abs(got - ref).max() <= tol
    assert np.abs(ref).max() > 1e3 * tol  # the products are not all zero: the comparison can fail


def ridge_predict_reference(x_tr, y_tr, x_te, pose_tr):
    """structure._ridge_predict before issue 41: the training rows copied, each inner fit on copies of its rows."""
    lams = RIDGES * float(np.mean(x_tr**2)) * x_tr.shape[1]
    sse = np.zeros(len(lams))
    for g in np.array_split(np.unique(pose_tr), 3):
        inner = np.isin(pose_tr, g)
        xi, yi = x_tr[~inner], y_tr[~inner]
        coef = _ridge_fit(xi.T @ xi, xi.T @ yi, lams)
        sse += np.sum((y_tr[inner][None] - coef @ x_tr[inner].T) ** 2, axis=1)
    return x_te @ _ridge_fit(x_tr.T @ x_tr, x_tr.T @ y_tr, lams[[int(np.argmin(sse))]])[0]


@settings(deadline=None, max_examples=20)
@given(seed=st.integers(0, 2**32 - 1), n_poses=st.integers(12, 40), p=st.integers(3, 30))
def test_smoother_predictions_from_gram_matrices_equal_the_copies(seed, n_poses, p):
    # issue 41: the smoother's ridge fits from the whole table's Gram matrix less the rows left out give the
    # predictions of the fits on copies of the training rows, to rounding (the ridge chosen the same)
    rng = np.random.default_rng(seed)
    pose_idx = np.repeat(np.arange(n_poses), 2)[rng.permutation(2 * n_poses)]
    x = rng.standard_normal((3 * len(pose_idx), p))
    y = x @ rng.standard_normal(p) * 0.3 + rng.standard_normal(len(x))
    test = np.flatnonzero(pose_idx % 5 == 2)
    train = np.setdiff1d(np.arange(len(pose_idx)), test)
    tr3, te3 = _coords(train), _coords(test)
    ref = ridge_predict_reference(x[tr3], y[tr3], x[te3], np.repeat(pose_idx[train], 3))
    got = _ridge_predict(x, y, x.T @ x, x.T @ y, test, pose_idx)
    assert np.allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def structure_features_reference(ctx, fit, table, seed):
    """structure._structure_features before issue 41: the groups concatenated, then whitened, then scaled."""
    q = np.radians(table.q_deg)
    n_rows, n = q.shape
    tool = np.array([fit.points[p] for p in table.point])
    off = None if fit.extension is None else fit.extension.joint_offsets(fit.ext)
    jac = Kinematics(ctx.chain, ctx.params).jacobian(q if off is None else q + off, tool, fit.dev)
    rot = np.array([fit.stations[s].rotation for s in table.station])
    dq = np.einsum("nij,njk->nik", rot, jac.d_q)
    t = table.t_s - table.t_s.min()
    t = t / max(float(t.max()), 1e-300)
    signs = approach_signs(q)
    cols = []
    for j in range(n):
        h = np.arange(1, STRUCTURE_HARMONICS + 1)
        basis = np.column_stack([np.sin(np.outer(q[:, j], h)), np.cos(np.outer(q[:, j], h)), signs[:, j], t])
        cols.append(dq[:, :, j, None] * basis[:, None, :])
    for sid in sorted(set(table.station)):
        m = (np.array(table.station) == sid).astype(float) * t
        cols.append(m[:, None, None] * np.eye(3)[None])
    x = np.column_stack([np.sin(q), np.cos(q), t])
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((x.shape[1], RANDOM_FEATURES))
    phase = rng.uniform(0, 2 * np.pi, RANDOM_FEATURES)
    rff = np.cos(x @ w + phase)
    cols.append(np.einsum("nm,ab->nabm", rff, np.eye(3)).reshape(n_rows, 3, 3 * RANDOM_FEATURES))
    feats = np.concatenate(cols, axis=2)
    if ctx.noise is not None:
        feats = np.einsum("nij,njp->nip", ctx.noise.whitening(table.xyz), feats)
    feats = feats.reshape(3 * n_rows, -1)
    norm = np.linalg.norm(feats, axis=0)
    return feats[:, norm > 0] / norm[norm > 0]


def test_structure_features_written_in_place_equal_the_concatenation(twin_case):
    # issue 41: the smoother's regressors written group by group into one array, whitened and scaled in place, are
    # the concatenated ones to rounding (the whitening a product per block of rows, the norms summed otherwise)
    table, params, geo = twin_case
    ctx = fits.context(CELL.chain, table, params, TrackerNoise(), geo, ("backlash",))
    fit = fits.whole_fit(ctx, ("backlash",))
    ref = structure_features_reference(ctx, fit, table, 3)
    got = _structure_features(ctx, fit, table, 3)
    assert got.shape == ref.shape and np.allclose(got, ref, rtol=1e-12, atol=1e-14)


def test_held_out_map_columns_of_rows_beyond_the_features_arcs(twin_case):
    """A problem whose map features were clamped to arcs narrower than its rows (a map fitted on part of a table,
    asked of the whole): a held-out row beyond them is formed again, clamped to the training rows' arcs, as the dense
    features give it, bit for bit."""
    table, params, geo = twin_case
    q = np.radians(table.q_deg)
    narrow = {j: Arc.covering(q[: len(q) // 2, j]) for j in range(CELL.chain.dof)}
    held, names = held_out_map(CELL, table, geo, params, narrow, 3)
    test = np.arange(1, len(table), 5)
    train = np.setdiff1d(np.arange(len(table)), test)
    arcs_train = {j: Arc.covering(q[train, j]) for j in narrow}
    assert any(narrow[j].clamp(q[test, j])[1].any() for j in narrow)  # rows beyond the features' arcs
    ref = np.einsum("rcj,rje->rce", held.lever[test], map_features(q[test], names, arcs_train))
    assert np.array_equal(held_columns(held, test), ref.reshape(3 * len(test), -1))
