"""The drift check's alarm level (calib.identify.drift.distance_level) against scipy's chi-square quantile, which the
drift check used before (issue 41: without scipy, `trackcal run` imports none of it)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import chdtrc, chdtri

from trackcal.calib.errors import CalibError
from trackcal.calib.identify.drift import FALSE_ALARM, DriftTest, distance_exceeded, distance_level

EPS = 2.0**-52
# from far in the tail (1e-15) to near certainty (0.999); a campaign's levels are FALSE_ALARM / checks (1e-3 and less)
LEVELS = np.logspace(-15, math.log10(0.999), 400)


def bound(p: float) -> float:
    """The relative error the rounding of Q allows: Q is a sum of terms each rounded (a few eps of Q, 4: a bound), and
    r moves by that over |dQ/dr| = sqrt(2 / pi) r^2 exp(-r^2 / 2): relative to r, times Q / (r |dQ/dr|) (below 1 in
    the tail, 93 at p = 0.999)."""
    r = math.sqrt(float(chdtri(3, p)))
    slope = math.sqrt(2.0 / math.pi) * r * r * math.exp(-r * r / 2.0)
    return 4 * EPS * max(1.0, p / (r * slope))


def test_survival_function_is_the_chi_square_one():
    for r in (0.01, 0.5, math.sqrt(2.0), 3.0, 4.033, 8.0):
        assert distance_exceeded(r) == pytest.approx(float(chdtrc(3, r * r)), rel=16 * EPS), r


@pytest.mark.parametrize("p", LEVELS)
def test_level_matches_scipy(p):
    assert distance_level(p) == pytest.approx(math.sqrt(float(chdtri(3, p))), rel=bound(p)), p


def test_campaign_level_is_the_one_the_check_used_with_scipy():
    """The level of one check at the campaign's false-alarm rate: sqrt of the chi-square (3 dof) 0.999 quantile,
    16.266 (tables of chi-square: 16.27), so 4.033 standard deviations."""
    assert DriftTest(checks=1).level == pytest.approx(math.sqrt(float(chdtri(3, FALSE_ALARM))), rel=4 * EPS)
    assert DriftTest(checks=1).level == pytest.approx(math.sqrt(16.266), abs=1e-3)


@pytest.mark.parametrize("p", [0.0, 1.0, -0.1, 1.5])
def test_level_outside_its_domain_is_refused(p):
    with pytest.raises(CalibError, match="false-alarm rate"):
        distance_level(p)
