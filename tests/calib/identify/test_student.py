"""The identification's Student t quantile (calib.identify.student) against scipy's, which identify used before."""

from __future__ import annotations

import math

import pytest
from scipy.special import stdtr, stdtrit

from trackcal.calib.errors import CalibError
from trackcal.calib.identify import student
from trackcal.calib.identify.student import QuantileError, t_quantile

# dof: 1 to 3 (the series' first terms), odd and even, a 100-row table's 3 x 100 - 18 - 12 - 9 and a 100k-row
# table's 299,961 (identify's dof: 3 rows per measurement less the unknowns), a million
DOFS = [1, 2, 3, 4, 5, 6, 7, 10, 11, 30, 31, 100, 101, 261, 1000, 1001, 12345, 100_000, 299_961, 1_000_000]
LEVELS = [0.5, 0.6, 0.9, 0.95, 0.975, 0.995, 0.9995]
EPS = 2.0**-52


def bound(dof: int, p: float) -> float:
    """The relative error the series' rounding allows: A(t) = P(|T| <= t) sums dof / 2 terms each rounded
    independently (about sqrt(dof / 2) eps, 4 of them: a bound), and t moves by that over dA/dt = 2 f(t): relative
    to t, times A / (t 2 f(t)) (84 at the 0.9995 level and a million dof, 4 at 0.975)."""
    t = float(stdtrit(dof, p))
    if t == 0.0:
        return 4 * EPS
    a = 2 * p - 1
    f = (stdtr(dof, t * (1 + 1e-6)) - stdtr(dof, t * (1 - 1e-6))) / (2e-6 * t)  # the density, centrally
    return 4 * math.sqrt(dof / 2 + 1) * EPS * max(1.0, a / (t * 2 * f))


@pytest.mark.parametrize("dof", DOFS)
def test_matches_scipy_across_dof_and_levels(dof):
    for p in LEVELS:
        expected = float(stdtrit(dof, p))
        assert t_quantile(dof, p) == pytest.approx(expected, rel=bound(dof, p), abs=4 * EPS), (dof, p)
        assert t_quantile(dof, 1 - p) == pytest.approx(-expected, rel=bound(dof, p), abs=4 * EPS), (dof, 1 - p)


def test_identify_level_to_1e12():
    """The 95 % intervals' level, to 1e-12 of scipy's at every dof listed (the issue's equivalence figure)."""
    for dof in DOFS:
        assert t_quantile(dof, 0.975) == pytest.approx(float(stdtrit(dof, 0.975)), rel=1e-12), dof


def test_closed_forms():
    """dof 1 is Cauchy's, t = tan(pi (p - 1/2)); dof 2's is t = (2p - 1) sqrt(2 / (1 - (2p - 1)^2))."""
    for p in LEVELS[1:]:
        assert t_quantile(1, p) == pytest.approx(math.tan(math.pi * (p - 0.5)), rel=4 * EPS)
        a = 2 * p - 1
        assert t_quantile(2, p) == pytest.approx(a * math.sqrt(2 / (1 - a * a)), rel=8 * EPS)


def test_newton_steps_within_its_bound(monkeypatch):
    """MAX_NEWTON is never what stops it: the most series evaluations any case takes stays well below."""
    calls = []
    series = student.central_probability
    monkeypatch.setattr(student, "central_probability", lambda theta, dof: calls.append(dof) or series(theta, dof))
    most = 0
    for dof in DOFS:
        for p in LEVELS[1:]:
            calls.clear()
            t_quantile.__wrapped__(dof, p)
            most = max(most, len(calls))
    assert most <= 8 < student.MAX_NEWTON


@pytest.mark.parametrize("dof, p", [(0, 0.975), (2.5, 0.975), (10, 0.0), (10, 1.0)])
def test_refuses_outside_its_domain(dof, p):
    with pytest.raises(QuantileError, match="t quantile"):
        t_quantile(dof, p)
    assert issubclass(QuantileError, CalibError)
