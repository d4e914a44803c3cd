"""Has a revisited reference point moved? The campaign's drift check as a test against the instrument's noise.

A campaign measures a reference pose at the start, middle and end of each station block (calib.doe.order). Two
measurements of the same point at the same commanded pose differ, with nothing wrong, by

- the tracker's noise of each (calib.identify.noise, the AT901 model: 5 µm in range, 7.5 µm + 3 µm/m across):
  the difference of two independent measurements has the sum of their covariances;
- the robot's pose repeatability: the reference pose is left and reached again, and each arrival scatters about
  the mean arrival. ISO 9283 states repeatability as RP = l_mean + 3 S_l, l the distance of an arrival from the
  mean arrival: for an isotropic normal scatter of sigma per axis l follows a Maxwell distribution, mean
  2 sigma sqrt(2/pi) and standard deviation sigma sqrt(3 - 8/pi), so RP = (2 sqrt(2/pi) + 3 sqrt(3 - 8/pi)) sigma
  = 3.616 sigma. Two arrivals differ by 2 sigma^2 per axis.

The check alarms when the Mahalanobis distance of the difference under that covariance exceeds the chi-square
quantile of 3 degrees of freedom at a false-alarm rate of FALSE_ALARM per campaign, shared among the campaign's
checks (Bonferroni): a clean campaign then raises a false alarm once in a thousand campaigns, whatever its number of
checks, and a threshold grows with the distance to the tracker as its noise does.

That quantile is computed here, without scipy (issue 41: scipy.special was a quarter of the start-up of every
command that imports the campaign engine, and `run` needs nothing else of scipy). The Mahalanobis distance r of a 3-D
standard normal exceeds r with probability Q(r) = erfc(r / sqrt(2)) + sqrt(2 / pi) r exp(-r^2 / 2) (the chi-square
survival function of 3 degrees of freedom at r^2, Abramowitz & Stegun 26.4.5), dQ/dr = -sqrt(2 / pi) r^2
exp(-r^2 / 2). Q is concave below its inflection point sqrt(2) and convex above it: Newton's method from sqrt(2)
approaches the root monotonically from whichever side it lies, and near it the error squares at each step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.identify.noise import TrackerNoise

FALSE_ALARM = 1e-3  # per campaign: the share of clean campaigns that would warn once
RP_PER_SIGMA = 2.0 * np.sqrt(2.0 / np.pi) + 3.0 * np.sqrt(3.0 - 8.0 / np.pi)  # ISO 9283 RP / sigma per axis: 3.616
MAX_NEWTON = 100  # steps: levels 1e-15 to 0.999 take at most 38 (tests/calib/identify/test_drift_level.py)


def distance_exceeded(r: float) -> float:
    """Q(r): the probability that a 3-D standard normal lies farther than r from its mean (chi-square, 3 dof, at
    r^2: what scipy.special.chdtrc(3, r**2) gives)."""
    return math.erfc(r / math.sqrt(2.0)) + math.sqrt(2.0 / math.pi) * r * math.exp(-r * r / 2.0)


def distance_level(p: float) -> float:
    """The distance r that a 3-D standard normal exceeds with probability p, 0 < p < 1 (what
    sqrt(scipy.special.chdtri(3, p)) gives): Newton's method on Q(r) = p from Q's inflection point sqrt(2)."""
    if not 0.0 < p < 1.0:
        raise CalibError(f"drift check: a false-alarm rate strictly between 0 and 1, got {p}")
    r = math.sqrt(2.0)
    for _ in range(MAX_NEWTON):
        step = (distance_exceeded(r) - p) / (math.sqrt(2.0 / math.pi) * r * r * math.exp(-r * r / 2.0))
        r += step
        if abs(step) <= 1e-9 * r:
            break
    return r


@dataclass(frozen=True)
class DriftTest:
    noise: TrackerNoise = field(default_factory=TrackerNoise)
    repeatability_mm: float = 0.0  # the robot's ISO 9283 pose repeatability RP (datasheet "+-RP"); 0: not known
    checks: int = 1  # comparisons in the campaign, sharing FALSE_ALARM
    false_alarm: float = FALSE_ALARM

    @property
    def level(self) -> float:
        """The Mahalanobis distance above which a check alarms."""
        return distance_level(self.false_alarm / max(self.checks, 1))

    def covariance(self, first: np.ndarray, again: np.ndarray) -> np.ndarray:
        """(3, 3) mm^2: covariance of again - first when nothing moved (station frame)."""
        sigma = self.repeatability_mm / RP_PER_SIGMA
        cov = self.noise.covariance(np.array([first, again], dtype=float)).sum(axis=0)
        return cov + 2.0 * sigma**2 * np.eye(3)

    def distance(self, first: np.ndarray, again: np.ndarray) -> float:
        """Mahalanobis distance of the difference of two measurements of the same point at the same pose."""
        d = np.subtract(again, first)
        return float(np.sqrt(d @ np.linalg.solve(self.covariance(first, again), d)))

    def threshold_mm(self, first: np.ndarray, again: np.ndarray) -> float:
        """The smallest displacement (mm) that alarms: along the least noisy direction."""
        return self.level * float(np.sqrt(np.linalg.eigvalsh(self.covariance(first, again))[0]))

    def alarms(self, first: np.ndarray, again: np.ndarray) -> bool:
        return self.distance(first, again) > self.level
