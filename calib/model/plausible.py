"""Physical bounds of a calibration: how far an identified geometric deviation may lie from the nominal robot.

An uncalibrated industrial robot misses its targets by about a millimetre: the paper's KR-270 by 0.94 mm RMS and
1.31 mm at most (Wu, Klimchik et al., RCIM 2015, Table 9, distance-based residuals before calibration), over a reach
of 2.7 m, i.e. about 0.05 % of its reach; the identified deviations that explain it are tenths of a millimetre and
hundredths of a degree (Table 8: at most 0.51 mm and 0.025 deg). Datasheets state the same order for the absolute
accuracy of uncalibrated arms (1-2 mm; their repeatability is tens of micrometres).

A deviation that alone moves the tool by more than 1 % of the reach (20 times that) is not a calibration: it is a wrong
nominal robot, a wrong unit, a model fitted to noise or a hand edit. So a length deviation is plausible up to
PLAUSIBLE_SHARE of the chain's reach (KR-270: 27 mm, UR10: 17 mm, IRB 120: 10 mm) and an angle one up to
PLAUSIBLE_SHARE rad (0.57 deg), the angle that turns the far end of the reach by as much.
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.model.chain import Chain
from trackcal.calib.model.params import Param, reach_mm

PLAUSIBLE_SHARE = 0.01  # of the reach (lengths) or in radians (angles): 20x the uncalibrated error of ~0.05 %


def deviation_bounds(chain: Chain) -> tuple[float, float]:
    """(largest plausible length deviation in mm, largest plausible angle deviation in deg) of `chain`."""
    return PLAUSIBLE_SHARE * reach_mm(chain), float(np.degrees(PLAUSIBLE_SHARE))


def implausible(chain: Chain, params: list[Param], values: np.ndarray) -> list[str]:
    """One phrase per parameter whose deviation `values` (boundary units: mm, deg) lies outside the chain's
    physical bounds, e.g. "dq2 = +25 deg is beyond +-0.573 deg"; [] when every one is plausible."""
    length, angle = deviation_bounds(chain)
    out = []
    for p, v in zip(params, np.asarray(values, dtype=float), strict=True):
        bound, unit = (length, "mm") if p.is_length else (angle, "deg")
        if not abs(v) <= bound:
            out.append(f"{p.name} = {v:+.4g} {unit} is beyond +-{bound:.3g} {unit}")
    return out
