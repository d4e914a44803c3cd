"""The Student t quantile of the identification's intervals, without scipy (issue 41: `scipy.special`, the only
scipy module `trackcal identify` needed, was about a quarter of the command's start-up).

With theta = arctan(t / sqrt(dof)), A(t | dof) = P(|T| <= t) is a finite series in theta (Abramowitz & Stegun
26.7.3 for odd dof, 26.7.4 for even dof) whose derivative in theta is c(dof) cos(theta)^(dof - 1), c(dof) =
2 Gamma((dof + 1) / 2) / (sqrt(pi) Gamma(dof / 2)). A is concave in theta on [0, pi/2): Newton's method from
below the root (the normal quantile's theta: t's quantiles lie beyond the normal's) rises to it monotonically;
near it the error squares at each step, so once a step is below 1e-9 of theta the one taken leaves an error near
1e-18 of it, under the rounding of theta.
"""

from __future__ import annotations

import math
from functools import cache
from statistics import NormalDist

import numpy as np

from trackcal.calib.errors import CalibError

MAX_NEWTON = 50  # steps: dof 1 to 1e6 at levels up to 0.9995 take at most 8 (tests/calib/identify/test_student.py)


class QuantileError(CalibError):
    """A t quantile asked outside its domain (degrees of freedom a whole number from 1, a level strictly in (0, 1))."""


def central_probability(theta: float, dof: int) -> float:
    """A(t | dof) = P(|T| <= t) at theta = arctan(t / sqrt(dof)): A&S 26.7.3 (odd dof), 26.7.4 (even dof). The
    powers of cos(theta)^2 are exp(j log1p(-sin(theta)^2)): a product of j rounded cos^2 would carry j times its
    rounding (5e-11 of the last terms at a million degrees of freedom)."""
    log_c2 = math.log1p(-(math.sin(theta) ** 2))
    odd = dof % 2
    j = np.arange(1, (dof - 2 - odd) // 2 + 1)
    ratio = 2 * j / (2 * j + 1) if odd else (2 * j - 1) / (2 * j)
    series = float(dof > 1) + float(np.sum(np.cumprod(ratio) * np.exp(j * log_c2)))  # dof 1: A = 2 theta / pi
    if odd:  # (2/pi) [theta + sin cos (1 + 2/3 cos^2 + 2*4/(3*5) cos^4 + ... up to cos^(dof-3))]
        return 2.0 / math.pi * (theta + math.sin(theta) * math.cos(theta) * series)
    return math.sin(theta) * series  # sin (1 + 1/2 cos^2 + 1*3/(2*4) cos^4 + ... up to cos^(dof-2))


@cache
def t_quantile(dof: int, p: float) -> float:
    """The p quantile of Student's t with `dof` (a whole number from 1) degrees of freedom, 0 < p < 1 (what
    scipy.special.stdtrit(dof, p) gives)."""
    if int(dof) != dof or dof < 1 or not 0.0 < p < 1.0:
        raise QuantileError(f"t quantile: dof a whole number from 1 and 0 < p < 1, got dof={dof}, p={p}")
    dof = int(dof)
    target = abs(2.0 * p - 1.0)  # A(|t|)
    slope = 2.0 * math.exp(math.lgamma((dof + 1) / 2) - math.lgamma(dof / 2)) / math.sqrt(math.pi)
    theta = math.atan(NormalDist().inv_cdf(0.5 + target / 2) / math.sqrt(dof))  # the normal quantile's: below
    for _ in range(MAX_NEWTON):
        step = (target - central_probability(theta, dof)) / (slope * math.cos(theta) ** (dof - 1))
        theta = min(theta + step, math.nextafter(math.pi / 2, 0.0))
        if abs(step) <= 1e-9 * theta:
            break
    return math.copysign(math.sqrt(dof) * math.tan(theta), p - 0.5)
