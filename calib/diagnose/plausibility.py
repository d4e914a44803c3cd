"""Physical ranges of the causes' parameters: a fit outside them is not the cause it is named after.

A cause of few parameters fitted to residuals it does not explain can take any value the residuals ask for: on a
real ABB IRB 120 an encoder scale of -49 % on joint 2 and a 39 deg first harmonic cancelled each other inside the
fitted range (issue 36). No reducer, encoder, link or tracker does that. A candidate whose whole-table fit leaves
these ranges is refused as a cause and named in the verdict (`implausible`); every limit is generous, a few times the
datasheet-level magnitudes of the literature, so that a real effect of an unusual cell still passes:

- encoder_scale |k| <= 0.5 %: a gear-ratio or encoder-gain error. Reducer ratios are ratios of tooth counts, exact;
  what is left is a fraction of a percent (a mis-set ratio of percents would move a joint by degrees over its
  range: a commissioning fault seen by eye, not a calibration residual).
- cyclic_error (any order, the joint error map) |e_j(q)| <= 0.5 deg over the rows: a transmission error. Robot
  reducers are specified at about 1 arcmin of angular transmission error (Nabtesco RV-N, Harmonic Drive CSG
  catalogues: 1 to 1.5 arcmin); 0.5 deg is 30 arcmin.
- backlash b_j <= 0.2 deg: lost motion of robot reducers is about 1 arcmin new (the same catalogues), a few arcmin
  worn; 0.2 deg is 12 arcmin.
- joint_compliance |c_j tau_j| <= 0.25 deg over the rows: the deflection gravity gives a joint. Joint stiffnesses of
  heavy arms are of order 1e6 N m/rad (Dumas et al., "Joint stiffness identification of industrial serial robots",
  Robotica 30, 2012, a KUKA KR 240: the paper's ref. [59]); at the ~10 kN m a KR 270's shoulder holds at full payload
  that is a few mrad, a few mm at its 2.7 m reach. 0.25 deg (4.4 mrad, 12 mm at 2.7 m) is above any of them.
- thermal_drift |g| <= 500 ppm over the campaign: 11.5 um/m/K for steel, 23 for aluminium links, warming by a few
  K over a campaign and some 10 to 20 K near the motors: 23 um/m/K x 20 K is 460 ppm.
- thermal_warmup |e_inf| <= 500 ppm (the saturated growth, the same physics as thermal_drift) and its time constant
  tau in [5 min, 8 h]: robot warm-up curves reach their steady state in one to a few hours (Gong, Yuan, Ni,
  IJMTM 40(14), 2000: time constants of tens of minutes; ISO 230-3 thermal tests of machine tools run 4 h and more
  for the same first-order behaviour); a tau of seconds is a settling transient, one of days no warm-up.
- payload_compliance: the deflection |c_j tau_j| <= 0.25 deg over the rows as joint_compliance, and |c_j| <=
  10 urad/(N m): joint stiffnesses of heavy six-revolute robots are 1e6 to 1e7 N m/rad (Dumas, Caro, Garnier,
  Furet, Robotics and Computer-Integrated Manufacturing 27(4), 2011, a KUKA KR 240-2: compliances of 0.1 to
  1 urad/(N m)); ten times the softest.
- range_scale |k_s| <= 100 ppm: a station's air data wrong (`calib.diagnose.point_effects`: the group refractive
  index of air moves by ~0.95 ppm/K and 0.27 ppm/hPa, Ciddor 1996, Edlen 1966). A weather station a few K off gives a
  few ppm; a set-up with no air data at all (the tracker's default 20 degC, 1013.25 hPa) in a plant 1500 m up (845 hPa)
  and 10 K warmer is 45 + 10 ppm; 100 ppm is a plant 2500 m up (750 hPa: 71 ppm) 20 K off (19 ppm), a few K to spare.
- nest_sag |c_i| <= 0.5 mm: a reflector nest's displacement along gravity relative to the reference nest. A 1.5 in
  SMR (170 g, 1.67 N) at the end of a stalk 10 mm across deflects F L^3 / (3 E I) (I = pi d^4 / 64 = 491 mm^4): on
  50 mm of steel (E = 210 GPa) 0.7 um, on 100 mm of aluminium (70 GPa) 16 um, on 100 mm of a polymer extension
  (POM, E ~ 3 GPa) 0.38 mm; a magnetic nest's seat adds microns. 0.5 mm is above the softest of them.
- wrist_coupling |c| <= 0.5 %: a coupling ratio of the wrist's gear train is a ratio of tooth counts, like a
  reducer's (encoder_scale): a mis-set factor is a fraction of a percent.
- station_shift has no parameter of its own (a station's pose after the change point, as free as before it).
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.model.extension import FORMS, Extension

ENCODER_SCALE_MAX = 5e-3  # |k|, dimensionless (0.5 %)
CYCLIC_MAX_RAD = float(np.radians(0.5))  # |e_j(q)| of the joint error map over the rows
BACKLASH_MAX_RAD = float(np.radians(0.2))  # dead band width b_j
DEFLECTION_MAX_RAD = float(np.radians(0.25))  # |c_j tau_j| over the rows
GROWTH_MAX = 500e-6  # |fractional growth| over the campaign's time span
WARMUP_TAU_MIN_S, WARMUP_TAU_MAX_S = 300.0, 8 * 3600.0  # the warm-up's time constant
COMPLIANCE_MAX = 1e-5  # |c_j| rad per N m under a payload
RANGE_SCALE_MAX = 100e-6  # |k_s|, dimensionless (100 ppm)
NEST_SAG_MAX_MM = 0.5  # |c_i| along gravity, relative to the reference nest
COUPLING_MAX = 5e-3  # |c| of a wrist coupling ratio, dimensionless (0.5 %)


def implausible(ext: Extension | None, theta: np.ndarray) -> list[str]:
    """One phrase per parameter (or joint) of a fitted extension outside its physical range (module docstring);
    [] when every part is inside. `ext` carries the rows it was fitted on, `theta` its values (internal units)."""
    if ext is None:
        return []
    theta = np.asarray(theta, dtype=float)
    out, at = [], 0
    for cause, names in ext.parts():
        cols = np.arange(at, at + len(names))
        at += len(names)
        values = theta[cols]
        if cause == "encoder_scale":
            out += [
                f"encoder_scale {nm} = {100 * v:+.3g} % (physical: |k| <= {100 * ENCODER_SCALE_MAX:g} %)"
                for nm, v in zip(names, values, strict=True)
                if abs(v) > ENCODER_SCALE_MAX
            ]
        elif cause in ("range_scale", "wrist_coupling"):
            limit = RANGE_SCALE_MAX if cause == "range_scale" else COUPLING_MAX
            out += [
                f"{cause} {nm} = {1e6 * v:+.3g} ppm (physical: |{nm[0]}| <= {1e6 * limit:g} ppm)"
                for nm, v in zip(names, values, strict=True)
                if abs(v) > limit
            ]
        elif cause == "nest_sag":
            out += [
                f"nest_sag {nm} = {1e3 * v:+.3g} um (physical: |c| <= {1e3 * NEST_SAG_MAX_MM:g} um)"
                for nm, v in zip(names, values, strict=True)
                if abs(v) > NEST_SAG_MAX_MM
            ]
        elif cause == "backlash":
            out += [
                f"backlash {nm} = {np.degrees(v):.3g} deg (physical: 0 .. {np.degrees(BACKLASH_MAX_RAD):g} deg)"
                for nm, v in zip(names, values, strict=True)
                if abs(v) > BACKLASH_MAX_RAD
            ]
        elif cause in ("joint_compliance", "cyclic_error", "payload_compliance"):
            limit = CYCLIC_MAX_RAD if cause == "cyclic_error" else DEFLECTION_MAX_RAD
            peak = np.max(np.abs(ext.joint_features.columns(cols).offsets(values)), axis=0)
            what = "joint error" if cause == "cyclic_error" else "deflection"
            out += [
                f"{cause} {what} of joint {j + 1} up to {np.degrees(p):.3g} deg (physical: <= "
                f"{np.degrees(limit):g} deg)"
                for j, p in enumerate(peak)
                if p > limit
            ]
            if cause == "payload_compliance":
                out += [
                    f"payload_compliance {nm} = {1e6 * v:.3g} urad/(N m) (physical: <= {1e6 * COMPLIANCE_MAX:g})"
                    for nm, v in zip(names, values, strict=True)
                    if abs(v) > COMPLIANCE_MAX
                ]
        elif cause == "thermal_warmup":
            tau = ext.meta.get(FORMS, {}).get(cause, {}).get("tau_s", WARMUP_TAU_MIN_S)
            if abs(values[0]) > GROWTH_MAX:
                out.append(
                    f"thermal_warmup e_inf = {1e6 * values[0]:.3g} ppm (physical: |e_inf| <= {1e6 * GROWTH_MAX:g} ppm)"
                )
            if not WARMUP_TAU_MIN_S <= tau <= WARMUP_TAU_MAX_S:
                out.append(
                    f"thermal_warmup tau = {tau / 60:.3g} min (physical: {WARMUP_TAU_MIN_S / 60:g} to "
                    f"{WARMUP_TAU_MAX_S / 3600:g} h)"
                )
        elif cause == "thermal_drift":
            growth = np.max(np.abs(ext.growth[:, cols] @ values))
            if growth > GROWTH_MAX:
                out.append(
                    f"thermal_drift growth up to {1e6 * growth:.3g} ppm over the campaign (physical: <= "
                    f"{1e6 * GROWTH_MAX:g} ppm)"
                )
    return out
