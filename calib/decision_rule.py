"""Pass or fail of a measured figure against an upper tolerance limit, under a stated decision rule.

A figure y (AP, RP, ...; the smaller the better) with its expanded uncertainty U (k = 2) meets a tolerance T when
y <= T. Where y lies near T, the measurement cannot tell, and the decision rule says what is stated then:

- simple acceptance (ILAC-G8:09/2019, "simple acceptance", guard band w = 0): the measured value decides alone:
  pass when y <= T, fail when y > T. The risk of a wrong pass near the limit is up to 50 % and is the customer's.
- guarded acceptance (ISO 14253-1:2017, the guard band w = U): conformity is proven only in the conformity zone,
  the tolerance zone reduced by U (pass when y + U <= T); non-conformity only outside the tolerance zone extended by
  U (fail when y - U > T). An interval y +- U that straddles T proves neither: "not proven". A figure without a
  stated U cannot prove either.
"""

from __future__ import annotations

import math

from trackcal.calib.errors import CalibError

PASS, FAIL, NOT_PROVEN = "pass", "fail", "not proven"

RULES = {
    "simple": "simple acceptance (ILAC-G8:09/2019, guard band w = 0): a figure passes when its measured value is at "
    "or below the tolerance, and fails above it, whatever its uncertainty",
    "guarded": "guarded acceptance (ISO 14253-1:2017, guard band w = U): a figure passes when its value plus its "
    "expanded uncertainty U is at or below the tolerance, fails when its value minus U is above it, and "
    "is not proven either way when the interval value ± U straddles the tolerance",
}


class DecisionError(CalibError):
    """A tolerance or a rule a decision cannot be made with."""


def decide(value: float, u95: float, limit: float, rule: str) -> str:
    """PASS, FAIL or NOT_PROVEN for the figure `value` (expanded uncertainty `u95`) against the upper `limit`."""
    if rule not in RULES:
        raise DecisionError(f"decision rule {rule!r}: expected one of {', '.join(RULES)}")
    if not (math.isfinite(limit) and limit > 0):
        raise DecisionError(f"tolerance {limit!r}: expected a positive finite number")
    if not math.isfinite(value):
        return NOT_PROVEN
    if rule == "simple":
        return PASS if value <= limit else FAIL
    if not (math.isfinite(u95) and u95 >= 0):
        return NOT_PROVEN
    if value + u95 <= limit:
        return PASS
    return FAIL if value - u95 > limit else NOT_PROVEN
