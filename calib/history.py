"""Has the robot changed between two calibrations? The two estimates of its parameters against their uncertainty.

Two campaigns measure the same robot independently, so the difference d = b - a of their estimates of the k
parameters both identified has covariance S = S_a + S_b (each the identification's covariance, paper eq. 27, with
its variance factor estimated from the residuals). If the robot did not change, d is zero-mean Gaussian and
T = d^T S^-1 d / k follows Snedecor's F(k, nu), nu the smaller of the two fits' residual degrees of freedom (the
variance factors are estimated: Hotelling's T^2 with estimated scale, approximated by F; for large nu it is
chi-square(k) / k). "Recalibrate" when the p-value of T is below alpha: one test for the whole robot, so its false
alarm rate is alpha, however many parameters there are. Which parameters moved: each |d_i| / sqrt(S_ii) against the
two-sided Student-t quantile at alpha / k (Bonferroni), so that together they too hold alpha.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from trackcal.calib.errors import CalibError

ALPHA = 0.05


class HistoryError(CalibError):
    """Estimates that cannot be compared (no common parameter, a covariance that is not one)."""


@dataclass(frozen=True)
class Change:
    names: list[str]
    difference: np.ndarray  # (k,) b - a, boundary units
    sigma: np.ndarray  # (k,) standard deviation of each difference
    moved: np.ndarray  # (k,) bool: beyond the Bonferroni-corrected interval
    statistic: float  # T = d^T S^-1 d / k
    dof: tuple[int, int]  # (k, nu)
    p_value: float
    alpha: float

    @property
    def changed(self) -> bool:
        return self.p_value < self.alpha


def compare_estimates(
    names_a: list[str], value_a, cov_a, dof_a: int, names_b: list[str], value_b, cov_b, dof_b: int, alpha: float = ALPHA
) -> Change:
    """The change from estimate a to estimate b over the parameters both hold (in a's order)."""
    common = [n for n in names_a if n in names_b]
    if not common:
        raise HistoryError("the two models share no identified parameter")
    ia = [names_a.index(n) for n in common]
    ib = [names_b.index(n) for n in common]
    va, vb = np.asarray(value_a, float)[ia], np.asarray(value_b, float)[ib]
    ca = np.asarray(cov_a, float)[np.ix_(ia, ia)]
    cb = np.asarray(cov_b, float)[np.ix_(ib, ib)]
    s = ca + cb
    if not (np.isfinite(s).all() and np.allclose(s, s.T, rtol=1e-9, atol=0.0)):
        raise HistoryError("a model's covariance is not a finite symmetric matrix")
    d = vb - va
    k = len(common)
    nu = max(1, min(int(dof_a), int(dof_b)))
    try:
        w = np.linalg.cholesky(s)
    except np.linalg.LinAlgError:
        raise HistoryError("the covariance of the difference is not positive definite") from None
    z = np.linalg.solve(w, d)
    t_stat = float(z @ z) / k
    p = float(stats.f.sf(t_stat, k, nu))
    sigma = np.sqrt(np.diag(s))
    quantile = stats.t.ppf(1.0 - alpha / (2 * k), nu)
    return Change(common, d, sigma, np.abs(d) > quantile * sigma, t_stat, (k, nu), p, alpha)
