"""issue 41: what a diagnosis holds per row of its table. Measured with tracemalloc (numpy reports its buffers to
it), never with the clock.

Bounds are in units of what the data needs, counted from the shapes: a map column is 8 bytes (float64) per
coordinate (3 per row) per coefficient; the harmonics it is made of, 8 bytes per row per coefficient."""

import gc
import tracemalloc

import numpy as np
import pytest

from studies.ur10_ipa.study import DATA, SERIES
from trackcal.calib.diagnose import diagnose
from trackcal.calib.diagnose.joint_map import Arc, harmonic_names, map_extension
from trackcal.calib.diagnose.joint_map_fit import HeldOutMap, MapEvidence, _fold_ids, fit_error_map
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import Problem, State, identify
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
    arcs = {j: Arc.covering(q[:, j]) for j in range(CELL.chain.dof)}
    names = [nm for j in arcs for nm in harmonic_names(j, 16)]
    problem = Problem(
        CELL.chain, table, geo.points, params, TrackerNoise(), extension=map_extension(q, names=names, arcs=arcs)
    )
    state = State(
        geo.dev,
        [geo.stations[s] for s in problem.station_ids],
        np.array([geo.points[p] for p in problem.point_ids]),
        np.zeros(len(names)),
    )
    held = HeldOutMap(problem, state, names)
    fold = _fold_ids(table, 5, 0)

    def ask_every_fold():
        for k in range(5):
            held.columns(np.flatnonzero(fold == k))  # the columns returned are dropped: what stays is kept

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
    joints: 640 coefficients, a Jacobian row 3 x ~680 float64 = 16 KB) stays under 7 such Jacobian rows per row of
    the table, 114 KB per row: 92 KB per row measured (a margin of a quarter). Before issue 41 it was 272 KB per row
    (17 rows); before the joint features' block form 154 KB per row (9.4: two dense maps (N, 6, 650), the held-out
    Jacobian rows MapEvidence kept per fold, the folds' Gram matrices held through the map's fit)."""
    cell, b, tmac, params = series_b()
    d, _, peak = traced(lambda: diagnose(cell.chain, b, tmac, params, None))
    assert d.cause == "cyclic_error"
    jacobian_row = 3 * (640 + 40) * F64
    assert peak <= 7 * jacobian_row * len(b)


@pytest.mark.slow
def test_diagnose_peak_grows_by_at_most_20_kb_per_row():
    """Issue 41's goal: what a diagnosis's peak grows by per row of its table, at most 20 KB (a 100k-row table under
    2.5 GB), measured as the slope of the traced peak between two KR-270 twin campaigns of one kind (a joint error
    map hidden, the map searched up to order 64 on six joints: a dense Jacobian row alone is 3 x ~800 float64,
    19 KB). What does not grow with the rows (imports, the Gram matrices, a piece of Jacobian rows) cancels in the
    slope; before issue 41's third step it was 65 KB per row."""
    peaks, rows = [], []
    for n_poses in (300, 1200):
        twin = Twin(CELL, seed=7, effects={"cyclic_error": 0.05})
        table = simulate_campaign(twin, np.degrees(random_poses(CELL, n_poses, np.random.default_rng(7))))
        params = irreducible_params(CELL.chain)[0]
        d, _, peak = traced(lambda t=table, p=params: diagnose(CELL.chain, t, CELL.tool_points, p, None))
        assert d.cause == "cyclic_error"
        peaks.append(peak)
        rows.append(len(table))
    assert (peaks[1] - peaks[0]) / (rows[1] - rows[0]) <= 20 * 1024
