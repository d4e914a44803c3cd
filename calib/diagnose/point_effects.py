"""Three physical candidates of real cells (issue 36): two act on the measured point, one on the wrist's joints.

- range_scale: one station's distances are scaled, x_measured = (1 + k_s) x, x the reflector in station s's frame
  (the tracker at its origin), one k_s per station, the first station measured the reference (k = 0: a scale common
  to every station is a scale of the whole cell, which the robot's lengths absorb). Cause: the tracker's
  interferometer and ADM measure an optical path; the distance is that path over the group refractive index of air,
  which the tracker computes from the air temperature, pressure and humidity its weather station gives (Ciddor,
  "Refractive index of air: new equations for the visible and near infrared", Applied Optics 35, 1996; Edlen,
  Metrologia 2, 1966). The group index changes by about -0.95 ppm per K, +0.27 ppm per hPa (1 ppm per 3.7 hPa) and
  -0.01 ppm per % relative humidity near 20 degC and 1013 hPa: a weather station mis-read, left in the sun, or
  missing at one set-up (the tracker then assumes its default air) scales that station's distances by a few to
  tens of ppm. Its physical range: `calib.diagnose.plausibility`.
- nest_sag: each reflector nest of the measurement tool is displaced along gravity by c_i (mm), whatever the flange's
  orientation: p_i = p_i,rigid + c_i g, g the gravity direction, fixed in the robot base frame (-z, as the robot's
  mass model has it: `calib.model.pinmodel`). Cause: the SMR (a steel ball of 50 to 200 g) sits in a magnetic nest
  on a stalk; the stalk or the nest's seat yields under the ball's weight (a cantilever's tip deflection F L^3 /
  (3 E I); the contact of a kinematic seat, Hertz: Johnson, "Contact Mechanics", 1985, ch. 4), and along gravity
  whatever the flange's orientation. A displacement common to every nest is a translation of the whole measured
  cell that each station's translation absorbs: one nest (the first measured) is the reference, c = 0, and the
  others' sags are relative to it.
- wrist_coupling: the wrist's gear train couples its axes (KUKA wrists drive A5 and A6 through A4's hollow shaft: a
  motor turning A4 turns A5 and A6 unless the controller's coupling factors, machine data $AXIS_CPL / the coupling
  ratios of the wrist, compensate it exactly; KUKA System Software 5.x, "Configuration of the kinematic system").
  A coupling ratio off by c leaves a joint error linear in the driving axis: dq5 = c54 q4, dq6 = c64 q4 + c65 q5
  (joint features, q_true = q_read + Phi theta, the last three joints the wrist A4, A5, A6). The ratios are ratios of
  tooth counts; an error is a mis-set factor of a fraction of a percent.

All three are linear in their parameters (`calib.model.extension`: range features, displacement features, joint
features).
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.extension import UNIT_FACTORS, Extension, ExtensionError, Ranges, select_columns

RANGE_SCALE, NEST_SAG, WRIST_COUPLING = "range_scale", "nest_sag", "wrist_coupling"
POINT_CAUSES = (RANGE_SCALE, NEST_SAG)
GRAVITY = np.array([0.0, 0.0, -1.0])  # unit gravity direction in the robot base frame (pinmodel's gravity)
# (driven wrist axis, driving wrist axis), as offsets from the first wrist joint (A4): A5 by A4, A6 by A4, A6 by A5
COUPLINGS = ((1, 0), (2, 0), (2, 1))


def _of_labels(cause: str, labels: list[str], prefix: str, names: list[str] | None) -> list[str]:
    """The parameter names of a per-label cause: every label but the first (the reference), or `names` (a fitted
    model's, which must be prefixed labels)."""
    if names is None:
        return [f"{prefix}{lab}" for lab in list(dict.fromkeys(labels))[1:]]
    bad = [nm for nm in names if not nm.startswith(prefix)]
    if bad:
        raise ExtensionError(f"unknown extension parameter(s) {', '.join(bad)} of {cause}")
    return list(names)


def range_scale_extension(
    table: MeasurementTable, names: list[str] | None = None, ranges: Ranges | None = None
) -> Extension:
    """range_scale for the rows of `table`: one parameter k_<station> per station but the reference (the first in
    the table), or those `names` list; rows of a station without a parameter (the reference, a station unknown to
    the model) have no range scale."""
    kept = _of_labels(RANGE_SCALE, table.station, "k_", names)
    stations = np.array(table.station)
    feats = np.zeros((len(table), len(kept)))
    for e, nm in enumerate(kept):
        feats[stations == nm.removeprefix("k_"), e] = 1.0
    return Extension(
        RANGE_SCALE,
        kept,
        ["ppm"] * len(kept),
        np.full(len(kept), UNIT_FACTORS["ppm"]),
        range_scale=feats,
        meta={"ranges": ranges},
    )


def nest_sag_extension(
    table: MeasurementTable, names: list[str] | None = None, ranges: Ranges | None = None
) -> Extension:
    """nest_sag for the rows of `table`: one parameter c_<point> (mm along gravity) per reference point but the
    reference (the first in the table), or those `names` list."""
    kept = _of_labels(NEST_SAG, table.point, "c_", names)
    points = np.array(table.point)
    feats = np.zeros((len(table), 3, len(kept)))
    for e, nm in enumerate(kept):
        feats[points == nm.removeprefix("c_"), :, e] = GRAVITY
    return Extension(
        NEST_SAG, kept, ["mm"] * len(kept), np.ones(len(kept)), displacement=feats, meta={"ranges": ranges}
    )


def wrist_coupling_extension(q: np.ndarray, names: list[str] | None = None, ranges: Ranges | None = None) -> Extension:
    """wrist_coupling for joint angles q (N, n) rad, clamped into `ranges` (held outside them, as every unbounded
    term): dq_driven = c q_driving for the couplings of the last three joints (COUPLINGS), c<driven><driving> named
    by the joints' numbers from 1 (c54, c64, c65 on a six-axis arm)."""
    n_rows, n = q.shape
    if n < 3:
        raise ExtensionError("wrist_coupling needs a wrist of three joints")
    q = q if ranges is None else ranges.clamp_q(q)
    wrist = n - 3
    feats = np.zeros((n_rows, n, len(COUPLINGS)))
    all_names = []
    for e, (driven, driving) in enumerate(COUPLINGS):
        feats[:, wrist + driven, e] = q[:, wrist + driving]
        all_names.append(f"c{wrist + driven + 1}{wrist + driving + 1}")
    feats, kept = select_columns(feats, all_names, names)
    return Extension(
        WRIST_COUPLING,
        kept,
        ["ppm"] * len(kept),
        np.full(len(kept), UNIT_FACTORS["ppm"]),
        feats,
        meta={"ranges": ranges},
    )
