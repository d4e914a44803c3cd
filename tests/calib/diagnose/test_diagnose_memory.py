"""issue 41: what a diagnosis holds per row of its table. Measured with tracemalloc (numpy reports its buffers to
it), never with the clock.

Bounds are in units of what the data needs, counted from the shapes: a map column is 8 bytes (float64) per
coordinate (3 per row) per coefficient; the harmonics it is made of, 8 bytes per row per coefficient."""

import gc
import tracemalloc

import numpy as np
import pytest

from studies.ur10_ipa.study import DATA, SERIES
from tests.helpers import held_out_map
from trackcal.calib.diagnose import crossval, diagnose, fits, structure
from trackcal.calib.diagnose.joint_map import Arc, harmonic_names, map_extension
from trackcal.calib.diagnose.joint_map_fit import MapEvidence, _fold_ids, fit_error_map
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import irreducible_params
from trackcal.calib.model.subset import identifiable_subset
from trackcal.campaign.importers.ipa_ur10 import POINT, read_ipa_series
from trackcal.mocks.twin import Twin, simulate_campaign

CELL = load_cell("kr270")
F64 = 8  # bytes of a float64


def traced(fn):
    """(what fn returns, bytes it left allocated, peak bytes above the start while it ran)."""
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        out = fn()
        gc.collect()
        after, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return out, after - before, peak - before


def test_held_out_map_keeps_nothing_per_fold_but_its_arcs():
    """The held-out columns of every fold are asked again (orders, models of Rejudge); they are formed from the
    problem's own map features on each call (a row beyond a training arc formed again), and only each fold's training
    arcs are kept, under its key (the fold's row indices: one int64 per row over a partition). Before issue 41 a
    cache held the held-out rows' harmonics, N x e float64 (e = 6 joints x 32 here)."""
    twin = Twin(CELL, seed=5, effects={"cyclic_error": 0.05})
    table = simulate_campaign(twin, np.degrees(random_poses(CELL, 120, np.random.default_rng(5))))
    params = irreducible_params(CELL.chain)[0]
    geo = identify(CELL.chain, table, CELL.tool_points, params, noise=TrackerNoise())
    q = np.radians(table.q_deg)
    held, names = held_out_map(CELL, table, geo, params, {j: Arc.covering(q[:, j]) for j in range(CELL.chain.dof)}, 16)
    fold = _fold_ids(table, 5, 0)

    def ask_every_fold():
        for k in range(5):
            held.piece(np.flatnonzero(fold == k))  # the features returned are dropped: what stays is kept

    _, kept, _ = traced(ask_every_fold)
    harmonics = len(table) * len(names) * F64
    # the keys' row indices, five dicts of six arcs and the harmonics' groups of each joint's names (parsed once,
    # `joint_map._groups`): Python objects of some 20 KB whatever the rows, not the harmonics (a quarter of them here)
    assert kept <= len(table) * F64 + 32 * 1024 < harmonics / 4


def test_map_evidence_holds_no_whole_jacobian():
    """`MapEvidence` (the models of Rejudge) works from the normal equations and each fold's part of them, formed from
    the fold's Jacobian rows a piece at a time and kept with the fold's residual and unpenalised columns. Before issue
    41 it held the search's whole Jacobian (3 N x m float64), and before that each fold's rows too."""
    twin = Twin(CELL, seed=5, effects={"cyclic_error": 0.05})
    table = simulate_campaign(twin, np.degrees(random_poses(CELL, 40, np.random.default_rng(5))))
    params = irreducible_params(CELL.chain)[0]
    geo = identify(CELL.chain, table, CELL.tool_points, params, noise=TrackerNoise())
    mf = fit_error_map(CELL.chain, table, CELL.tool_points, params, TrackerNoise(), orders=(1, 2, 8), start=geo)
    ev = MapEvidence(CELL.chain, table, params, TrackerNoise(), None, geo, mf)
    m = len(ev.gram)
    grams = 5 * (m * m + m) * F64
    _, kept, _ = traced(lambda: ev.cv_rms_mm(_fold_ids(table, 5, 0)))
    # each fold's part of the normal equations, its solutions, and the held-out rows' residual and unpenalised
    # columns (3 N (|free| + 1) float64): no Jacobian rows of the map's columns (the whole-diagnosis bound below
    # checks the peak)
    rows_kept = 3 * len(table) * (len(ev.free) + 1) * F64
    assert kept <= 1.1 * (grams + rows_kept) + 64 * 1024


def series_b():
    """As bench.bench_diagnose and `trackcal diagnose --weighting iid` run it: the identifiable subset."""
    cell = load_cell("ur10-ipa")
    tmac = {POINT: cell.tool_points[POINT]}
    b = read_ipa_series(DATA / SERIES["B"], station="B")
    params, _ = identifiable_subset(cell.chain, irreducible_params(cell.chain)[0], np.radians(b.q_deg), tmac)
    return cell, b, tmac, params


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="IPA data set not present")
def test_diagnose_of_series_b_stays_under_its_per_row_bound():
    """The peak a diagnosis of the UR10's Series B allocates (1,495 rows, the joint error map up to order 64 on five
    joints: 640 coefficients, a Jacobian row 3 x ~680 float64 = 16 KB) stays under 4 such Jacobian rows per row of
    the table, 65 KB per row: 57 KB per row measured (a margin of a tenth; 53 before the map's search kept its five
    folds' parts, whose sums are its normal equations), most of it what does not grow with the rows (the folds' Gram
    matrices, 680 x 680 each; pieces of 512 rows of the Jacobian). Before issue 41 it was 272
    KB per row (17 rows); 154 before the joint features' block form; 92 before the Jacobian was never held whole."""
    cell, b, tmac, params = series_b()
    d, _, peak = traced(lambda: diagnose(cell.chain, b, tmac, params, None))
    assert d.cause == "cyclic_error"
    jacobian_row = 3 * (640 + 40) * F64
    assert peak <= 4 * jacobian_row * len(b)


@pytest.mark.slow
def test_diagnose_peak_grows_by_at_most_20_kb_per_row():
    """Issue 41's goal: what a diagnosis's peak grows by per row of its table, at most 20 KB (a 100k-row table under
    2.5 GB), measured as the slope of the traced peak between two KR-270 twin campaigns of one kind (a joint error
    map hidden, the map searched up to order 64 on six joints: a dense Jacobian row alone is 3 x ~800 float64,
    19 KB), ~2,700 and ~6,200 rows. What does not grow with the rows (imports, the Gram matrices, a piece of Jacobian
    rows: `joint_map_fit.PIECE` rows of a fold, full from folds of 512 rows, tables of 2,560) cancels in the slope;
    before issue 41's third step it was 65 KB per row."""
    peaks, rows = [], []
    for n_poses in (1200, 2700):
        twin = Twin(CELL, seed=7, effects={"cyclic_error": 0.05})
        table = simulate_campaign(twin, np.degrees(random_poses(CELL, n_poses, np.random.default_rng(7))))
        params = irreducible_params(CELL.chain)[0]
        d, _, peak = traced(lambda t=table, p=params: diagnose(CELL.chain, t, CELL.tool_points, p, None))
        assert d.cause == "cyclic_error"
        peaks.append(peak)
        rows.append(len(table))
    assert (peaks[1] - peaks[0]) / (rows[1] - rows[0]) <= 20 * 1024


@pytest.fixture(scope="module")
def map_cause():
    """A diagnosis's context of a KR-270 twin campaign (200 poses of 400 drawn feasible, each seen with three points
    and one or two stations, but the last 10 poses without their first point: ~870 rows) with a joint error map's
    extension as a cause beside the geometric model: order 32 on the joints that turn over ~6 rad (1, 4 and 6: 192
    coefficients; over the narrower arcs of the others, harmonics of that order are not told apart), a candidate of
    231 columns."""
    twin = Twin(CELL, seed=5, effects={"cyclic_error": 0.05})
    table = simulate_campaign(twin, np.degrees(random_poses(CELL, 400, np.random.default_rng(5))))
    last, first = sorted(set(table.pose))[-10:], table.point[0]
    keep = [i for i in range(len(table)) if table.pose[i] not in last or table.point[i] != first]
    table = table.subset(np.array(keep))
    params = irreducible_params(CELL.chain)[0]
    geo = identify(CELL.chain, table, CELL.tool_points, params, noise=TrackerNoise())
    ctx = fits.context(CELL.chain, table, params, TrackerNoise(), geo, ())
    q = np.radians(table.q_deg)
    arcs = {j: Arc.covering(q[:, j]) for j in (0, 3, 5)}
    ctx.features["map"] = map_extension(q, names=[nm for j in arcs for nm in harmonic_names(j, 32)], arcs=arcs)
    fits.extension_of(ctx, ("map",))  # the combined extension, cached in the context before any fit
    return ctx


def test_a_candidate_fit_keeps_no_jacobian(map_cause):
    """A whole-table fit kept in the context (ctx.fits) keeps its Gram matrix and J^T r (n_cols^2 and n_cols
    float64), and per row its residuals and its Problem's layout of the rows (angles, measurements,
    whitening, indices): under 64 float64 per row. Before issue 41 it kept its Jacobian, 3 n_cols float64 per row
    (231 columns here: 5.5 KB per row)."""
    ctx = map_cause
    fit, kept, _ = traced(lambda: fits.whole_fit(ctx, ("map",)))
    n, m = len(ctx.table), fit.n_cols
    assert m > 200
    assert kept <= (m * m + m + 64 * n) * F64 < 3 * n * m * F64 / 4


def dense_orthogonal_rss(r: np.ndarray, j: np.ndarray) -> tuple[float, int]:
    """(RSS, rank) of r after least squares on j's columns as before issue 41: an SVD of the whole j, its columns
    scaled to unit norm, the directions above RANK_TOL of the largest singular value kept."""
    norm = np.linalg.norm(j, axis=0)
    u, sv, _ = np.linalg.svd(j / np.where(norm > 0, norm, 1.0), full_matrices=False)
    u = u[:, sv > structure.RANK_TOL * sv[0]]
    return float(r @ r - np.sum((u.T @ r) ** 2)), u.shape[1]


def test_the_fits_users_give_the_dense_results(map_cause, monkeypatch):
    """Cross-validation, the trainable check and the end-frame test's least squares, with the fit's Jacobian rows
    formed on demand (a fold's; chunks of whole poses), give what the whole Jacobian gave (the formulas before issue
    41, computed here from the Jacobian formed at the solution)."""
    ctx = map_cause
    fit = fits.whole_fit(ctx, ("map",))
    n = len(ctx.table)
    r, jm = fit.problem.residual_and_jacobian(fit.state)
    gram, grad = jm.T @ jm, jm.T @ r
    folds = crossval.fold_rows(ctx.table, "pose", 5, 0)
    sq = np.zeros(n)
    for test in folds:
        te3 = structure._coords(test)
        jt, rt = jm[te3], r[te3]
        g = gram - jt.T @ jt
        d = np.sqrt(np.diag(g))
        step = np.linalg.solve(g / np.outer(d, d), (grad - jt.T @ rt) / d) / d
        e = np.einsum("nij,nj->ni", ctx.unwhiten[test], (rt - jt @ step).reshape(-1, 3))
        sq[test] += np.sum(e**2, axis=1)
        assert crossval.trainable(ctx, ("map",), test) == fits.identifiable(g)
    # the Gram matrix summed in another order (rounding ~1e-13 of its entries) through the folds' solves
    np.testing.assert_allclose(crossval.cross_validate(ctx, ("map",), folds).sq, sq, rtol=1e-8)

    # the end-frame test's least squares over chunks of 100 rows (several chunks, and rows of poses seen with fewer
    # than three points apart), each usable pose's end-frame directions a random orthonormal 6-column basis: no
    # model column lies in them, so the ranks are clear of rounding
    monkeypatch.setattr(structure, "STRUCTURE_CHUNK", 100)
    rng = np.random.default_rng(1)
    pose_arr = np.array(ctx.table.pose)
    poses = []
    for p in sorted(set(ctx.table.pose)):
        rows = np.flatnonzero(pose_arr == p)
        if len({ctx.table.point[i] for i in rows}) >= 3:
            poses.append((rows, np.linalg.qr(rng.standard_normal((3 * len(rows), 6)))[0]))
    assert len(poses) < len(set(ctx.table.pose))
    los = ctx.table.xyz / np.linalg.norm(ctx.table.xyz, axis=1)[:, None]
    scales = (los, 0.8, 1.3)  # any scales along and across the line of sight: the rescaling is linear
    rs = structure._rescale(fit.r.reshape(n, 3), *scales)
    j = structure._rescale(jm.reshape(n, 3, -1), *scales).reshape(3 * n, -1)
    before = [dense_orthogonal_rss(rs.ravel(), j)]
    rp = rs.reshape(-1).copy()
    for rows, u in poses:
        rr = structure._coords(rows)
        rp[rr] -= u @ (u.T @ rp[rr])
        j[rr] -= u @ (u.T @ j[rr])
    before.append(dense_orthogonal_rss(rp, j))
    now = structure._model_rss(fit, rs, scales, poses)
    for (rss, rank), (rss_dense, rank_dense) in zip(now, before, strict=True):
        assert rank == rank_dense == fit.n_cols
        assert rss == pytest.approx(rss_dense, rel=1e-9)  # rounding of r.r through the least squares' cancellation
