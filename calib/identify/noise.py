"""Laser-tracker noise: radial (interferometer/ADM) and transverse (angle encoders, growing with range).

Leica AT901 specification: MPE of a point = 15 um + 6 um/m (angular), distance MPE 10 um; Leica states
its MPE as twice the standard deviation, hence the defaults: sigma_radial = 5 um,
sigma_transverse = 7.5 um + 3 um/m * range. The covariance of a point at x (station frame, tracker at
the origin) is  sigma_r^2 u u^T + sigma_t^2 (I - u u^T),  u = x / |x|  (paper eqs. 23-24, 28-29).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.errors import CalibError


@dataclass(frozen=True)
class TrackerNoise:
    radial_mm: float = 0.005
    transverse_mm: float = 0.0075
    transverse_mm_per_m: float = 0.003

    @staticmethod
    def isotropic(sigma_mm: float) -> TrackerNoise:
        return TrackerNoise(radial_mm=sigma_mm, transverse_mm=sigma_mm, transverse_mm_per_m=0.0)

    def _parts(self, xyz: np.ndarray):
        xyz = np.atleast_2d(np.asarray(xyz, dtype=float))
        rng = np.linalg.norm(xyz, axis=1)
        u = xyz / np.maximum(rng, 1e-9)[:, None]
        uu = np.einsum("ni,nj->nij", u, u)
        st = self.transverse_mm + self.transverse_mm_per_m * rng / 1000.0
        return uu, np.eye(3) - uu, st

    def covariance(self, xyz: np.ndarray) -> np.ndarray:
        uu, perp, st = self._parts(xyz)
        return self.radial_mm**2 * uu + (st**2)[:, None, None] * perp

    def whitening(self, xyz: np.ndarray) -> np.ndarray:
        """W with W^T W = covariance^-1 (symmetric square root), shape (N, 3, 3)."""
        uu, perp, st = self._parts(xyz)
        return uu / self.radial_mm + perp / st[:, None, None]

    def sample(self, xyz: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One noise draw per point, (N, 3)."""
        uu, perp, st = self._parts(xyz)
        z = rng.standard_normal((uu.shape[0], 3))
        return self.radial_mm * np.einsum("nij,nj->ni", uu, z) + st[:, None] * np.einsum("nij,nj->ni", perp, z)


class NoiseError(CalibError):
    """A noise model or weighting that does not exist."""


# The one default weighting of identify, diagnose, run and the demo: this noise model. A laser tracker measures the
# range by interferometer/ADM (5 µm) and the direction by angle encoders (7.5 µm + 3 µm/m of range), so the noise of
# a point is anisotropic and grows with its distance. Weighting by the inverse covariance is the best linear
# unbiased estimate (Gauss-Markov; paper eqs. 23-24); equal weights ("iid") give the transverse components of far
# points the weight of the radial ones, and intervals too narrow in some directions, too wide in others. iid stays
# for trackers whose noise model is not known.
WEIGHTINGS = ("tracker", "iid")
DEFAULT_WEIGHTING = "tracker"


def noise_for(weighting: str) -> TrackerNoise | None:
    """The noise model of a weighting name (WEIGHTINGS): None is i.i.d. least squares."""
    if weighting not in WEIGHTINGS:
        raise NoiseError(f"weighting {weighting!r}: choose one of {', '.join(WEIGHTINGS)}")
    return TrackerNoise() if weighting == "tracker" else None
