"""What `trackcal identify` skips or does faster (issue 41) gives what it gave before: the rows' distinct values by
one lexsort as np.unique's, and the nominal robot's "before" fit without its covariance the same fit."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tests.helpers import kr270_campaign
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify, unique_rows

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
