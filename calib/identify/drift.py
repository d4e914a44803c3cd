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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri  # the inverse chi-square survival function (scipy.stats: ~1 s to import)

from trackcal.calib.identify.noise import TrackerNoise

FALSE_ALARM = 1e-3  # per campaign: the share of clean campaigns that would warn once
RP_PER_SIGMA = 2.0 * np.sqrt(2.0 / np.pi) + 3.0 * np.sqrt(3.0 - 8.0 / np.pi)  # ISO 9283 RP / sigma per axis: 3.616


@dataclass(frozen=True)
class DriftTest:
    noise: TrackerNoise = field(default_factory=TrackerNoise)
    repeatability_mm: float = 0.0  # the robot's ISO 9283 pose repeatability RP (datasheet "+-RP"); 0: not known
    checks: int = 1  # comparisons in the campaign, sharing FALSE_ALARM
    false_alarm: float = FALSE_ALARM

    @property
    def level(self) -> float:
        """The Mahalanobis distance above which a check alarms."""
        return float(np.sqrt(chdtri(3, self.false_alarm / max(self.checks, 1))))

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
