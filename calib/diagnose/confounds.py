"""Time causes the campaign order cannot tell from the reflectors measured at that time.

A campaign is measured station by station and, within a station, reflector by reflector (`calib.doe.order`). A
change over time is then also a change of which reflector is measured, unless the same reflector is measured on both
sides of it (a point block's reference pose is revisited at its start and its end for this):

- station_shift: a change point between two reflector blocks of its station splits the station's rows by reflector.
  Its two frames then absorb whatever differs between the reflectors before and after it (issue 36: a nest sagging
  under gravity, measured first at station S2, gave S2 a frame of its own; poses measured after the campaign saw
  that nest through the other frame, 100 um off). A move is seen when some reflector is measured at the station
  both before and after the change point; else only beyond a displacement of the reflectors measured after it, in
  the rows the shift moves: each reflector displaced in the flange frame (knocked or re-seated in its nest: 3
  parameters) and along gravity (its nest sagging: 1, as `calib.diagnose.point_effects`' nest_sag). A station moved
  along gravity is every such reflector sagging by as much, so beyond the displacements the shift adds 7 - 1
  parameters (its 6 and its change point, less that direction), which must pass the F test the shift passed.
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

from trackcal.calib.diagnose.changepoint import SHIFT
from trackcal.calib.diagnose.fits import Context, Fit, n_extra, whole_fit
from trackcal.calib.diagnose.point_effects import GRAVITY
from trackcal.calib.identify.solver import IdentificationError
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.extension import Extension
from trackcal.calib.model.kinematics import Kinematics

WITHIN = " within"  # ctx.features keys, after the growth cause: its parts tested (`growth_between_blocks`)
DISPLACED = " displaced"  # and after station_shift: the reflectors measured after it displaced (`shift_between_blocks`)
BESIDE = " beside the shift"  # the same less the first reflector's sag, fitted with the shift


def unrevisited(table: MeasurementTable, shift: dict | None) -> list[str]:
    """The reflectors measured at the shifted station after the change point when no reflector is measured there
    both before and after it; [] when one is, or without a shift."""
    if shift is None:
        return []
    at, cut = np.array(table.station) == shift["station"], shift["after_t_s"]
    points = np.array(table.point)
    before, after = set(points[at & (table.t_s <= cut)]), set(points[at & (table.t_s > cut)])
    return [] if before & after else sorted(str(p) for p in after)


def shift_between_blocks(ctx: Context, fitted: tuple[str, ...], fit: Fit, dof: float, alpha: float) -> list[str]:
    """[] when the shift of `fit` (the model `fitted` + station_shift, `dof` its degrees of freedom) is not between
    two reflector blocks, or is significant beyond a displacement of the reflectors measured after it; else one
    phrase (module docstring)."""
    after = unrevisited(ctx.table, fit.shift)
    if not after:
        return []
    sid, cut = fit.shift["station"], fit.shift["after_t_s"]
    moved = _displacements(ctx, sid, cut, after)
    # the first reflector's sag is the station's move along gravity: left out beside the shift (module docstring)
    cols = [i for i in range(moved.size) if i != 3]
    beside = Extension(
        f"{moved.cause}{BESIDE}",
        [moved.names[i] for i in cols],
        ["mm"] * len(cols),
        np.ones(len(cols)),
        displacement=moved.displacement[:, :, cols],
    )
    parts = {moved.cause: moved, beside.cause: beside}
    p = _f_pvalue(ctx, parts, (*fitted, moved.cause), (*fitted, beside.cause, SHIFT), dof - beside.size)
    if p < alpha:
        return []
    return [
        f"station_shift: no reflector is measured at station {sid} both before and after t = {cut:g} s, and beyond "
        f"a displacement of the reflectors measured after it the move is not significant (F test p = {p:.2g}): it "
        "cannot be told from such a displacement (revisit a pose with the same reflector across the change)"
    ]


def _displacements(ctx: Context, sid: str, cut: float, after: list[str]) -> Extension:
    """Each reflector of `after` displaced in the rows of station `sid` after `cut`: along the flange frame's 3 axes
    (at each row's orientation in the geometric fit) and along gravity, in that order."""
    rot, _ = Kinematics(ctx.chain, ctx.params).end_frames(np.radians(ctx.table.q_deg), ctx.geo.dev)
    rows = (np.array(ctx.table.station) == sid) & (ctx.table.t_s > cut)
    points = np.array(ctx.table.point)
    feats = np.zeros((len(ctx.table), 3, 4 * len(after)))
    for i, pid in enumerate(after):
        mine = rows & (points == pid)
        feats[mine, :, 4 * i : 4 * i + 3] = rot[mine]
        feats[mine, :, 4 * i + 3] = GRAVITY
    names = [f"{pid} {axis}" for pid in after for axis in ("flange x", "flange y", "flange z", "gravity")]
    return Extension(
        f"{SHIFT}{DISPLACED} {sid} {cut:g}", names, ["mm"] * len(names), np.ones(len(names)), displacement=feats
    )


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
        part = Extension(ext.cause, ext.names, ext.units, ext.to_boundary, growth=g, pivot=ext.pivot)
        p = _f_pvalue(ctx, {f"{cause}{WITHIN} {pid}": part}, fitted, (*fitted, f"{cause}{WITHIN} {pid}"), dof, current)
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


def _f_pvalue(
    ctx: Context,
    parts: dict[str, Extension],
    base: tuple[str, ...],
    model: tuple[str, ...],
    dof: float,
    current: Fit | None = None,
) -> float:
    """The F test's p-value of the model `model` against the model `base` (`current`, its fit, when already fitted),
    whose columns it spans; `dof` the degrees of freedom of `model`; `parts` held in ctx.features for the fits
    (1.0 when a model cannot be identified)."""
    ctx.features.update(parts)
    try:
        small = current if current is not None else whole_fit(ctx, base)
        fit = whole_fit(ctx, model)
        added = n_extra(ctx, model) - n_extra(ctx, base)
    except IdentificationError:
        return 1.0
    finally:
        for key in parts:
            del ctx.features[key]
    f = ((small.rss - fit.rss) / added) / (fit.rss / dof) if fit.rss > 0 else 0.0
    return float(fdtrc(added, dof, f)) if f > 0 else 1.0
