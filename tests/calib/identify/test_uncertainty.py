"""Honest uncertainty: on simulated campaigns the truth falls inside the 95 % intervals 95 % of the time.

Each seed is an independent campaign (new poses, new noise), so per parameter the number of seeds whose
interval holds the truth is Binomial(n, 0.95) exactly when the intervals are honest (linear-Gaussian
theory; the KR-270 problem is linear to far below the noise at these deviations). Two-sided binomial
tests reject intervals that are too narrow and too wide alike. The joint region (F test of the whole
parameter vector) is checked the same way.
"""

import numpy as np
import pytest
from scipy import stats

from tests.helpers import kr270_campaign, truth_of
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.identify.solver import identify


def coverage(cell, params, seeds, weighting, twin_noise):
    inside = np.zeros(len(params), dtype=int)
    joint = 0
    for seed in seeds:
        twin, table = kr270_campaign(cell, seed=seed, n_poses=30, noise=twin_noise)
        res = identify(cell.chain, table, cell.tool_points, params, noise=weighting)
        err = res.dev - truth_of(twin, params)
        inside += np.abs(err) <= res.param_ci95()
        f = err @ np.linalg.solve(res.param_cov(), err) / len(err)
        joint += f <= stats.f.ppf(0.95, len(err), res.dof)
    return inside, joint


def check(inside, joint, n):
    # 18 per-parameter tests + 1 joint test: alpha 1e-4 each keeps a false alarm below 0.2 %
    for k in inside:
        assert stats.binomtest(int(k), n, 0.95).pvalue > 1e-4, (inside, n)
    assert stats.binomtest(int(joint), n, 0.95).pvalue > 1e-4, (joint, n)


@pytest.mark.slow  # a statistical acceptance check, among make test's slowest (issue 37): make test-slow
@pytest.mark.parametrize(
    "weighting, twin_noise",
    # the tracker model (every command's default weighting) and i.i.d. (12 s more), both in the slow suite
    [pytest.param(None, TrackerNoise.isotropic(0.010), marks=pytest.mark.slow), (TrackerNoise(), TrackerNoise())],
    ids=["iid", "tracker-model"],
)
def test_confidence_intervals_are_honest(kr270, kr270_params, weighting, twin_noise):
    n = 120
    inside, joint = coverage(kr270, kr270_params, range(1000, 1000 + n), weighting, twin_noise)
    check(inside, joint, n)


@pytest.mark.slow
def test_confidence_intervals_are_honest_many_seeds(kr270, kr270_params):
    n = 1500
    inside, joint = coverage(kr270, kr270_params, range(5000, 5000 + n), TrackerNoise(), TrackerNoise())
    check(inside, joint, n)


def test_wrong_weighting_is_detected_by_the_variance_factor(kr270, kr270_params):
    """A-posteriori variance factor: ~1 with the true noise model; far from 1 when the model is wrong
    (noise 4x larger than the AT901 model assumes gives s^2 ~ 16)."""
    _, table = kr270_campaign(kr270, seed=3, n_poses=40, noise=TrackerNoise(0.02, 0.03, 0.012))
    res = identify(kr270.chain, table, kr270.tool_points, kr270_params, noise=TrackerNoise())
    lo, hi = 16 * stats.chi2.ppf([0.0005, 0.9995], res.dof) / res.dof
    assert lo < res.variance_factor < hi
