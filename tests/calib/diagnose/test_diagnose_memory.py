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


def test_held_out_map_keeps_the_harmonics_not_the_columns():
    """The held-out columns of every fold are asked again (orders, models of Rejudge), so they are cached; the cache
    holds each held-out row's harmonics (N x e values), a third of the columns (3 N x e) formed from them on every
    call. Before issue 41 the cache held the columns: 3 N e float64 and more, above this bound."""
    twin = Twin(CELL, seed=5, effects={"cyclic_error": 0.05})
    table = simulate_campaign(twin, np.degrees(random_poses(CELL, 40, np.random.default_rng(5))))
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
            held.columns(np.flatnonzero(fold == k))  # the columns returned are dropped: the cache is what stays

    _, kept, _ = traced(ask_every_fold)
    harmonics = len(table) * len(names) * F64
    assert kept <= 1.25 * harmonics  # the harmonics once, and the small change of bookkeeping (keys, lists)


def test_map_evidence_keeps_no_held_out_jacobian_rows():
    """`MapEvidence` (the models of Rejudge) keeps per fold its factor's solution and the held-out rows, and forms
    their Jacobian rows on each call. Before issue 41 it kept them: every row once over the folds, a second whole
    Jacobian (3 N x m float64) beside the search's, 16 KB per row of Series B."""
    twin = Twin(CELL, seed=5, effects={"cyclic_error": 0.05})
    table = simulate_campaign(twin, np.degrees(random_poses(CELL, 40, np.random.default_rng(5))))
    params = irreducible_params(CELL.chain)[0]
    geo = identify(CELL.chain, table, CELL.tool_points, params, noise=TrackerNoise())
    mf = fit_error_map(CELL.chain, table, CELL.tool_points, params, TrackerNoise(), orders=(1, 2, 4), start=geo)
    ev = MapEvidence(CELL.chain, table, params, TrackerNoise(), None, geo, mf)
    jacobian, harmonics = ev.jm.nbytes, len(table) * ev.n_pen * F64
    _, kept, _ = traced(lambda: ev.cv_rms_mm(_fold_ids(table, 5, 0)))
    # the held-out rows' harmonics (cached by `HeldOutMap` unless the map's search cached them at this order), and a
    # solution (m values) and the rows' indices per fold: well under a Jacobian
    assert kept <= harmonics + 0.25 * jacobian


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
