"""Time causes the campaign order cannot tell from the reflectors measured at that time.

A campaign is measured station by station and, within a station, reflector by reflector (`calib.doe.order`). A
change over time is then also a change of which reflector is measured, unless the same reflector is measured on both
sides of it (a point block's reference pose is revisited at its start and its end for this):

- station_shift: a change point between two reflector blocks of its station splits the station's rows by reflector.
  Its two frames then absorb whatever differs between the reflectors before and after it (issue 36: a nest sagging
  under gravity, measured first at station S2, gave S2 a frame of its own; poses measured after the campaign saw
  that nest through the other frame, 100 um off). A move is seen only when some reflector is measured at the station
  both before and after the change point.
- thermal_drift: a growth constant over one station's rows is that station's range scale (its air data) and a
  translation; a growth that is a step between one reflector's rows and the others' at a station is a displacement
  of that reflector (issue 36: the same sagging nest, measured last at every station, was a growth within each
  station's time, and poses measured after the campaign were predicted grown at every reflector, 57 % worse). The
  growth's part within each station (each station's mean removed), and for each reflector its part beyond such a
  step, must pass the F test the whole growth passed. A warm-up seen across the reflectors passes (the independent
  twin's seed 36001: 106 -> 32 um on poses measured after the campaign).
"""

from __future__ import annotations

import numpy as np
from scipy.special import fdtrc  # the F survival function (scipy.stats: ~1 s to import)

from trackcal.calib.diagnose.fits import Context, Fit, whole_fit
from trackcal.calib.identify.solver import IdentificationError
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.extension import Extension

WITHIN = " within"  # ctx.features keys, after the growth cause: its parts tested (`growth_between_blocks`)


def shift_between_blocks(table: MeasurementTable, shift: dict | None) -> list[str]:
    """[] when some reflector is measured at the shifted station both before and after the change point, else one
    phrase (module docstring)."""
    if shift is None:
        return []
    sid, cut = shift["station"], shift["after_t_s"]
    at = np.array(table.station) == sid
    points = np.array(table.point)
    before, after = set(points[at & (table.t_s <= cut)]), set(points[at & (table.t_s > cut)])
    if before & after:
        return []
    return [
        f"station_shift: no reflector is measured at station {sid} both before and after t = {cut:g} s: a move "
        "of the station cannot be told from a displacement of the reflectors measured after it (revisit a pose "
        "with the same reflector across the change)"
    ]


def growth_between_blocks(
    ctx: Context, fitted: tuple[str, ...], current: Fit, dof: float, alpha: float, cause: str = "thermal_drift"
) -> list[str]:
    """[] when the arm's growth is significant within each station's time and not carried by one reflector alone,
    else one phrase (module docstring). Each station's mean growth removed, what is left must pass the F test the
    whole growth passed; and, for each reflector in turn, with the mean growth of its rows and of the other
    reflectors' rows removed at each station (a step between that reflector and the others is its displacement)."""
    ext = ctx.features[cause]
    stations, points = np.array(ctx.table.station), np.array(ctx.table.point)
    within = ext.growth.copy()
    for sid in sorted(set(stations)):
        within[stations == sid] -= within[stations == sid].mean(axis=0)
    tests = [("", within)] if len(set(stations)) > 1 else []
    for pid in sorted(set(points)) if len(set(points)) > 1 else []:
        g = ext.growth.copy()
        for sid in sorted(set(stations)):
            for at in ((stations == sid) & (points == pid), (stations == sid) & (points != pid)):
                g[at] -= g[at].mean(axis=0) if at.any() else 0.0
        tests.append((pid, g))
    for pid, g in tests:
        p = _within_pvalue(
            ctx,
            fitted,
            current,
            dof,
            f"{cause}{WITHIN} {pid}",
            Extension(ext.cause, ext.names, ext.units, ext.to_boundary, growth=g, pivot=ext.pivot),
        )
        if p >= alpha and not pid:
            return [
                f"{cause}: within each station's own time the growth is not significant (F test p = "
                f"{p:.2g}); between stations measured one after the other it is one station's range scale (its "
                "air data) as well"
            ]
        if p >= alpha:
            return [
                f"{cause}: beyond a step between reflector {pid} and the others at each station the growth "
                f"is not significant (F test p = {p:.2g}): measured one reflector after the other, it is a "
                f"displacement of reflector {pid} as well"
            ]
    return []


def _within_pvalue(ctx: Context, fitted: tuple[str, ...], current: Fit, dof: float, key: str, part: Extension) -> float:
    """The F test's p-value of the growth's part `part` (1.0 when it cannot be identified)."""
    ctx.features[key] = part
    try:
        fit = whole_fit(ctx, (*fitted, key))
    except IdentificationError:
        return 1.0
    finally:
        del ctx.features[key]
    f = (current.rss - fit.rss) / (fit.rss / dof) if fit.rss > 0 else 0.0
    return float(fdtrc(1, dof, f)) if f > 0 else 1.0
