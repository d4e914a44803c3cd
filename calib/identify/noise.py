"""Laser-tracker noise: radial (interferometer/ADM) and transverse (angle encoders, growing with range).

The numbers are an instrument's (calib.model.instruments: named models from their datasheets, or the cell's own);
the defaults are the Leica AT901's: MPE of a point = 15 um + 6 um/m (angular), distance MPE 10 um; Leica states
its MPE as twice the standard deviation, hence sigma_radial = 5 um, sigma_transverse = 7.5 um + 3 um/m * range.
The covariance of a point at x (station frame, tracker at the origin) is
sigma_r^2 u u^T + sigma_t^2 (I - u u^T),  u = x / |x|  (paper eqs. 23-24, 28-29), sigma_r = radial + its small
range part (a distance meter's ppm; 0 for the Leica models).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.model.instruments import DEFAULT, MODELS, Instrument

_AT901 = MODELS[DEFAULT]


@dataclass(frozen=True)
class TrackerNoise:
    radial_mm: float = _AT901.radial_mm
    transverse_mm: float = _AT901.transverse_mm
    transverse_mm_per_m: float = _AT901.transverse_mm_per_m
    radial_mm_per_m: float = _AT901.radial_mm_per_m
    name: str = _AT901.name

    @staticmethod
    def isotropic(sigma_mm: float) -> TrackerNoise:
        return TrackerNoise(
            radial_mm=sigma_mm, transverse_mm=sigma_mm, transverse_mm_per_m=0.0, name=f"isotropic {sigma_mm:g} mm"
        )

    @staticmethod
    def of(instrument: Instrument) -> TrackerNoise:
        """The noise model of an instrument (calib.model.instruments)."""
        return TrackerNoise(
            instrument.radial_mm,
            instrument.transverse_mm,
            instrument.transverse_mm_per_m,
            instrument.radial_mm_per_m,
            instrument.name,
        )

    def _parts(self, xyz: np.ndarray):
        xyz = np.atleast_2d(np.asarray(xyz, dtype=float))
        rng = np.linalg.norm(xyz, axis=1)
        u = xyz / np.maximum(rng, 1e-9)[:, None]
        uu = np.einsum("ni,nj->nij", u, u)
        sr, st = self.sigmas(rng)
        return uu, np.eye(3) - uu, st, sr

    def sigmas(self, range_mm) -> tuple[np.ndarray, np.ndarray]:
        """(radial, transverse) one-sigma noise, mm, of points at these ranges (mm)."""
        rng = np.asarray(range_mm, dtype=float)
        return (
            self.radial_mm + self.radial_mm_per_m * rng / 1000.0,
            self.transverse_mm + self.transverse_mm_per_m * rng / 1000.0,
        )

    def covariance(self, xyz: np.ndarray) -> np.ndarray:
        uu, perp, st, sr = self._parts(xyz)
        return (sr**2)[:, None, None] * uu + (st**2)[:, None, None] * perp

    def whitening(self, xyz: np.ndarray) -> np.ndarray:
        """W with W^T W = covariance^-1 (symmetric square root), shape (N, 3, 3)."""
        uu, perp, st, sr = self._parts(xyz)
        return uu / sr[:, None, None] + perp / st[:, None, None]

    def sample(self, xyz: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One noise draw per point, (N, 3)."""
        uu, perp, st, sr = self._parts(xyz)
        z = rng.standard_normal((uu.shape[0], 3))
        return sr[:, None] * np.einsum("nij,nj->ni", uu, z) + st[:, None] * np.einsum("nij,nj->ni", perp, z)


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


def noise_for(weighting: str, instrument: Instrument | None = None) -> TrackerNoise | None:
    """The noise model of a weighting name (WEIGHTINGS): "tracker" is the instrument's (the cell's; default the
    AT901), None is i.i.d. least squares."""
    if weighting not in WEIGHTINGS:
        raise NoiseError(f"weighting {weighting!r}: choose one of {', '.join(WEIGHTINGS)}")
    if weighting != "tracker":
        return None
    return TrackerNoise() if instrument is None else TrackerNoise.of(instrument)


def model_noise(doc: dict) -> TrackerNoise | None:
    """The weighting a model.json was identified with: its `tracker` figures under "tracker" weighting (a model
    written before instruments were named has none: the AT901's), None for i.i.d."""
    if doc.get("weighting", "iid") != "tracker":
        return None
    return TrackerNoise.of(model_instrument(doc))


def model_instrument(doc: dict) -> Instrument:
    """The instrument a model.json names (`tracker`), else the AT901 (models written before instruments)."""
    t = doc.get("tracker")
    if not isinstance(t, dict):
        return _AT901
    um = [t.get(k) for k in ("radial_um", "transverse_um", "transverse_um_per_m", "radial_um_per_m")]
    if not all(isinstance(v, int | float) and not isinstance(v, bool) and v >= 0 for v in um) or not um[0] or not um[1]:
        raise NoiseError(
            f"model tracker: expected one-sigma radial_um, transverse_um, transverse_um_per_m, "
            f"radial_um_per_m (micrometres), got {t!r}"
        )
    key = str(t.get("model", "custom"))
    return Instrument(
        key,
        str(t.get("name", key)),
        um[0] / 1000,
        um[1] / 1000,
        um[2] / 1000,
        um[3] / 1000,
        assumed=bool(t.get("assumed", False)),
    )
