"""The model's lack of fit in the filter's bound: what the model's form misses of the robot (issue 38).

The parameters' covariance (model.json's `covariance`, `extension_covariance`) is the uncertainty of a model of the
RIGHT form: what the fit estimated. When the robot does something the model's form does not hold (a compliance whose
true masses differ from the config's, an effect none of diagnose's candidates has in its exact form), the model is
wrong by that part at every pose, and no covariance of its parameters holds it: a stated 95 % bound then covers a
third of the targets or less. That part shows in the fit's residual: model.json records the residual RMS of one
coordinate over the fit's degrees of freedom (`residual_rms_mm`, RSS / dof: unbiased for a model of the right form)
and the tracker's noise floor of one coordinate (`noise_floor_mm`, calib.diagnose.noise_floor: repeated
measurements, else the tracker's noise model). Their excess is the lack of fit:

    s^2 = max(residual_rms^2 - noise_floor^2, 0)   (mm^2, per coordinate)

the variance, per coordinate, of the model's own error at the measured poses: the residual is that error plus the
tracker's noise, independent of it, so their variances add (the residual's expectation over dof is the noise's
variance plus the mean square of the unmodelled part the model could not absorb). It is zero when the fit is at the
noise floor (a model of the right form: the bound is the parameters' alone, as before), and it is the variance of the
deterministic misfit over the poses, not a random error: a target's error is the same each time it is run.

Why it transfers to a target: the misfit is a smooth function of the joints (what the model misses of a compliance,
a scale, a map), sampled at the measured poses. A target inside the space the model was measured in
(calib.measured_space: the same joint ranges and volume) is a point of that same function, so over such targets its
variance is the one over the measured poses (the dof in the residual's divisor already counts what the fit absorbed
of it, to first order). Outside that space the function is extrapolated and nothing bounds it: those targets' bounds
stay "not covered" (calib.program_filter). The misfit at the measured reflectors stands for the misfit at the
target's TCP: the same arm, its lever (the tool's length against the measurement tool's) being of the same order.

Its 95 % radius: model.json holds the misfit's RMS over the three coordinates, not its direction, and a misfit has
one (a compliance sags the arm mostly down). Of every normal law with the same variance 3 s^2 over the three axes, the
one along a single axis has the largest 95 % radius: 1.95996 sqrt(3) s = 3.39 s (the normal law's 97.5 % point;
all along one axis), against 2.7955 s (the chi distribution with 3 degrees of freedom) spread evenly. The bound takes
the single axis, the direction being unknown, and adds it to the parameters' 95 % radius in quadrature (exact when
both lie along one axis, or both are isotropic):

    bound = predicted + sqrt(r_parameters^2 + (1.95996 sqrt(3) s)^2)

and the 1-sigma figure sqrt(trace + 3 s^2). On the KR-270 twin with mismatched compliance
(tests/calib/test_program_filter_lack_of_fit.py, 12 campaigns, 216 targets): 92 % of targets within the bound so
taken, 87 % with the isotropic radius, 31 % without the lack of fit.
"""

from __future__ import annotations

import math

from trackcal.calib.errors import CalibError

KEYS = ("residual_rms_mm", "noise_floor_mm")  # model.json's entries (campaign.jobs.identify fit_quality)
ONE_AXIS_95 = 1.959964  # the normal law's 97.5 % point: |x| <= it with 95 % probability, x ~ N(0, 1)


class LackOfFitError(CalibError):
    """A model.json residual RMS or noise floor that is not a number the lack of fit can be read from."""


def lack_of_fit_variance(doc: dict) -> float | None:
    """s^2 (mm^2, per coordinate): the part of the model's residual variance beyond the tracker's noise floor (module
    docstring); None when the model does not record them (written before they were recorded)."""
    if any(doc.get(k) is None for k in KEYS):
        return None
    values = []
    for k in KEYS:
        v = doc[k]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
            raise LackOfFitError(f"{k}: expected a finite number >= 0 (mm), got {v!r}")
        values.append(float(v))
    rms, floor = values
    return max(rms * rms - floor * floor, 0.0)


def lack_of_fit_radius95(s2: float) -> float:
    """mm: the 95 % radius of a misfit of variance s2 per coordinate whose direction is unknown: the worst, all its
    3 s2 along one axis (module docstring)."""
    return ONE_AXIS_95 * math.sqrt(3.0 * s2)
