"""What `trackcal identify` skips or does faster (issue 41) gives what it gave before: the rows' distinct values by
one lexsort as np.unique's, the nominal robot's "before" fit without its covariance the same fit, and the
covariance from the normal equations' Cholesky factor the QR's to 1e-12 (README tables, hypothesis-drawn ones), or
the QR's itself when ill conditioned."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, reject, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tests.calib.identify.test_determined import UR10_P
from tests.helpers import README_TABLE_ARGS, README_TABLES, drawn_kr270_campaign, kr270_campaign, readme_table_fit
from trackcal.calib.diagnose.extensions import build_extension
from trackcal.calib.doe.poses import random_poses
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import (
    Identification,
    IdentificationError,
    Problem,
    Rows,
    State,
    cholesky_r,
    identify,
    unique_rows,
)
from trackcal.calib.identify.unknowns import campaign_params
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import param_by_name
from trackcal.mocks.twin import Twin, simulate_campaign

# few values, so that rows repeat; signed zeros, which np.unique takes as equal
VALUES = st.sampled_from([-1.5, -0.0, 0.0, 0.25, 1.0, 3.0])


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 40), st.integers(1, 6)), elements=VALUES))
def test_unique_rows_is_nps_unique(a):
    first, inverse = unique_rows(a)
    _, first_np, inverse_np = np.unique(a, axis=0, return_index=True, return_inverse=True)
    np.testing.assert_array_equal(first, first_np)
    np.testing.assert_array_equal(inverse, inverse_np.ravel())


@settings(max_examples=100, deadline=None)
@given(hnp.arrays(np.int64, st.tuples(st.integers(1, 40), st.integers(1, 9)), elements=st.integers(-2, 2)))
def test_unique_rows_of_integer_keys(a):
    """The noise floor's keys: label codes and approach directions."""
    first, inverse = unique_rows(a)
    _, first_np, inverse_np = np.unique(a, axis=0, return_index=True, return_inverse=True)
    np.testing.assert_array_equal(first, first_np)
    np.testing.assert_array_equal(inverse, inverse_np.ravel())


def test_before_fit_without_covariance_is_the_same_fit(kr270):
    """The "before" fit's residuals are all any reader uses (model.json's residuals.before, the report's figure);
    without its covariance every other result is the same, bit for bit, and the covariance says it is not there."""
    _, table = kr270_campaign(kr270, seed=3, n_poses=30)
    full = identify(kr270.chain, table, kr270.tool_points, [], noise=TrackerNoise())
    quick = identify(kr270.chain, table, kr270.tool_points, [], noise=TrackerNoise(), covariance=False)
    np.testing.assert_array_equal(quick.residuals, full.residuals)
    for sid in full.stations:
        np.testing.assert_array_equal(quick.stations[sid].rotation, full.stations[sid].rotation)
        np.testing.assert_array_equal(quick.stations[sid].translation, full.stations[sid].translation)
    for pid in full.points:
        np.testing.assert_array_equal(quick.points[pid], full.points[pid])
    assert (quick.variance_factor, quick.dof, quick.iterations) == (full.variance_factor, full.dof, full.iterations)
    assert np.isfinite(full.cov).all() and np.isnan(quick.cov).all() and quick.r_factor is None


def assert_same_fit(a: Identification, b: Identification) -> None:
    for name in ("dev", "residuals", "cov"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for sid in a.stations:
        np.testing.assert_array_equal(a.stations[sid].rotation, b.stations[sid].rotation)
        np.testing.assert_array_equal(a.stations[sid].translation, b.stations[sid].translation)
    for pid in a.points:
        np.testing.assert_array_equal(a.points[pid], b.points[pid])
    assert (a.iterations, a.variance_factor) == (b.iterations, b.variance_factor)


def test_fits_sharing_the_row_layout_are_the_fits_alone(kr270):
    """identify's "before" fit and fit share the table's layout (solver.Rows, made once): each is the fit it is alone,
    bit for bit; a layout made for another noise model is not used (the i.i.d. fit given the whitened rows is the
    i.i.d. fit)."""
    _, table = kr270_campaign(kr270, seed=3, n_poses=30)
    params, noise = campaign_params(kr270.chain), TrackerNoise()
    rows = Rows(kr270.chain, table, kr270.tool_points, noise, None)
    for fit_params in ([], params):
        shared = identify(kr270.chain, table, kr270.tool_points, fit_params, noise=noise, rows=rows)
        assert_same_fit(shared, identify(kr270.chain, table, kr270.tool_points, fit_params, noise=noise))
    iid = identify(kr270.chain, table, kr270.tool_points, params, rows=rows)
    assert_same_fit(iid, identify(kr270.chain, table, kr270.tool_points, params))


@pytest.mark.parametrize("cause", ["backlash", "encoder_scale"])
def test_a_layout_shared_across_features_gives_each_problem_its_own(kr270, cause):
    """A diagnosis's candidates share the table's layout whatever their joint-offset features (Rows.with_features):
    the distinct poses and the normal equations of a Problem made from the shared layout are those of one made alone,
    bit for bit, and the shared layout keeps its own poses. backlash's features follow the direction of motion (its
    poses are not those of the angles alone), encoder_scale's are a function of the angles."""
    _, table = kr270_campaign(kr270, seed=3, n_poses=30)
    table = table.subset(np.r_[np.arange(len(table)), np.arange(12)])  # poses measured again, from another side
    params, noise = campaign_params(kr270.chain), TrackerNoise()
    rows = Rows(kr270.chain, table, kr270.tool_points, noise, None)
    first = rows.poses
    ext = build_extension(cause, kr270.chain, table)
    shared = Problem(kr270.chain, table, kr270.tool_points, params, noise, extension=ext, rows=rows)
    alone = Problem(kr270.chain, table, kr270.tool_points, params, noise, extension=ext)
    assert shared.rows is not rows and shared.rows.q is rows.q and rows.poses is first
    for a, b in zip(shared.rows.poses, alone.rows.poses, strict=True):
        np.testing.assert_array_equal(a, b)
    state = alone.initial
    state.ext = np.random.default_rng(1).normal(0, 1e-3, ext.size)  # offsets that move the rows' angles
    for a, b in zip(shared.normal_equations(state), alone.normal_equations(state), strict=True):
        np.testing.assert_array_equal(a, b)


def qr_covariance(res: Identification, table) -> np.ndarray:
    """The covariance as identify formed it before (issue 41): from the R of a QR of the whitened Jacobian at the
    solution (Problem.r_factor), eq. 27."""
    problem = Problem(res.chain, table, res.points, res.params, res.noise, res.dev, res.extension, res.ext)
    stations, points = [res.stations[s] for s in problem.station_ids], [res.points[p] for p in problem.point_ids]
    state = State(res.dev, stations, np.array(points), np.asarray(res.ext, dtype=float))
    rf = problem.r_factor(state)
    scale = np.linalg.norm(rf, axis=0)
    _, sv, vt = np.linalg.svd(rf / scale)
    return res.variance_factor * ((vt.T / sv**2) @ vt) / np.outer(scale, scale)


def assert_same_covariance(res: Identification, table) -> None:
    """To 1e-12 of each entry's scale sqrt(c_ii c_jj): the Cholesky factor of a Jacobian of scaled condition number
    at most CHOLESKY_COND carries eps * cond^2 = 2.2e-12 at most, the QR's eps * cond (measured: 3e-14 on these)."""
    old = qr_covariance(res, table)
    sd = np.sqrt(np.diag(old))
    np.testing.assert_allclose(res.cov / np.outer(sd, sd), old / np.outer(sd, sd), rtol=0, atol=1e-12)


@pytest.mark.parametrize(README_TABLE_ARGS, README_TABLES)
def test_readme_tables_same_covariance(cell_name, poses, seed, effects, cause):
    fit = readme_table_fit(cell_name, poses, seed, effects, cause)
    assert_same_covariance(fit.result, fit.table)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), poses=st.integers(12, 40), drop=st.lists(st.integers(0, 17), max_size=4))
def test_drawn_campaigns_same_covariance(seed, poses, drop):
    cell, table, params = drawn_kr270_campaign(seed, poses, drop)
    try:
        res = identify(cell.chain, table, cell.tool_points, params, noise=TrackerNoise())
    except IdentificationError:  # a drawn campaign too small to separate the unknowns
        reject()
    assert_same_covariance(res, table)


def test_ill_conditioned_fit_takes_the_qr():
    """Issue 25's one-point UR10 (px5 and phix5 near-dependent: scaled condition number far above CHOLESKY_COND):
    its R is the QR's, so its covariance is the one of before, bit for bit."""
    cell = load_cell("ur10-ipa")
    twin = Twin(cell, seed=2, deviations={"px4": 0.5})
    table = simulate_campaign(twin, np.degrees(random_poses(cell, 60, np.random.default_rng(2))), points=["TMAC"])
    params = [param_by_name(cell.chain, n) for n in [*UR10_P, "px5", "phix5"]]
    res = identify(cell.chain, table, cell.tool_points, params, noise=TrackerNoise())
    problem = Problem(res.chain, table, res.points, res.params, res.noise, res.dev)
    state = State(
        res.dev, [res.stations[s] for s in problem.station_ids], np.array([res.points[p] for p in problem.point_ids])
    )
    assert cholesky_r(problem.normal_equations(state)[0]) is None
    np.testing.assert_array_equal(res.cov, qr_covariance(res, table))
