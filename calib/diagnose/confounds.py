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
  translation; a growth constant over one reflector's block at a station is a displacement of that reflector
  (issue 36: the same sagging nest, measured last at every station, was a growth within each station's time, and
  poses measured after the campaign were predicted grown at every reflector, 57 % worse). The growth's part within
  each reflector block (each block's mean growth removed) must pass the F test the whole growth passed.
"""

from __future__ import annotations

import numpy as np
from scipy.special import fdtrc  # the F survival function (scipy.stats: ~1 s to import)

from trackcal.calib.diagnose.features import Extension
from trackcal.calib.diagnose.fits import Context, Fit, whole_fit
from trackcal.calib.identify.solver import IdentificationError
from trackcal.calib.io.table import MeasurementTable

WITHIN = "thermal_drift within blocks"  # ctx.features key of the growth's part within each reflector block


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
    return [f"station_shift: no reflector is measured at station {sid} both before and after t = {cut:g} s: a move "
            "of the station cannot be told from a displacement of the reflectors measured after it (revisit a pose "
            "with the same reflector across the change)"]


def growth_between_blocks(ctx: Context, fitted: tuple[str, ...], current: Fit, dof: float, alpha: float) -> list[str]:
    """[] when the arm's growth is significant within each reflector block (a station's rows of one reflector), else
    one phrase (module docstring). One block: the growth is judged as it is."""
    ext = ctx.features["thermal_drift"]
    blocks = np.array([f"{s}\x00{p}" for s, p in zip(ctx.table.station, ctx.table.point, strict=True)])
    names = sorted(set(blocks))
    if len(names) < 2:
        return []
    g = ext.growth.copy()
    for b in names:
        g[blocks == b] -= g[blocks == b].mean(axis=0)
    ctx.features[WITHIN] = Extension(ext.cause, ext.names, ext.units, ext.to_boundary, growth=g, pivot=ext.pivot)
    try:
        fit = whole_fit(ctx, (*fitted, WITHIN))
    except IdentificationError:
        return ["thermal_drift: its growth within each reflector block cannot be identified"]
    finally:
        del ctx.features[WITHIN]
    f = (current.rss - fit.rss) / (fit.rss / dof) if fit.rss > 0 else 0.0
    p = float(fdtrc(1, dof, f)) if f > 0 else 1.0
    if p < alpha:
        return []
    return [f"thermal_drift: within each reflector block (a station's rows of one reflector) the growth is not "
            f"significant (F test p = {p:.2g}); between blocks measured one after the other it is one station's range "
            "scale (its air data) or one reflector's displacement as well"]
