"""Non-geometric model extensions: physical causes with few parameters, added to the geometric model.

Every extension is linear in its parameters theta (`calib.model.extension`: joint features, the reported joint
angles are off by Phi theta; growth features, the arm grows by the fraction G theta about a pivot).

Joint-type causes:
- joint_compliance: dq_j = c_j tau_j(q), tau_j the gravity torque joint j holds (mass model of the
  robot config, pinocchio RNEA); one compliance per joint whose torque varies over the campaign;
- backlash: dq_j = (b_j / 2) s_j, s_j = +1 / -1 the direction joint j last moved in before the row (time
  order; 0 before it first moves): a dead band of width b_j;
- encoder_scale: dq_j = k_j q_j (gear-ratio / encoder gain error);
- cyclic_error: the joint error map, a Fourier series per joint in its own angle of any order; its form and
  features are `calib.diagnose.joint_map`, which `build_extension` calls for it (its search and ridge fit:
  `calib.diagnose.joint_map_fit`).

Growth cause:
- thermal_drift: uniform thermal growth of every length, g = e t (t the row's time since the campaign
  start). A rigid chain whose translations (tool included) all grow by the same fraction scales every
  point about the chain's first frame exactly. Two forms, named by their parameter (THERMAL_FORMS): `e`,
  the arm and the tool grow about the first joint's frame (the base column does not); `e_base`, the base
  column grows too (pivot: the robot base frame's origin, a robot warming as a whole). Both have one
  parameter: the data choose (fit both, the lower residual wins).

Time-dependent causes of the campaign's own history (`calib.diagnose.warmup` fits the warm-up's time constant):
- thermal_warmup: a first-order warm-up of every length, g = e_inf (1 - exp(-(t - t0) / tau)), t0 the start of the
  fitted time span: the robot heated by its motors approaches a steady temperature with a time constant of tens of
  minutes to hours (Gong, Yuan, Ni, "Nongeometric error identification and compensation for robotic system by
  inverse calibration", IJMTM 40(14), 2000: a robot's thermal errors follow first-order warm-up curves; ISO 230-3
  and Heisel et al.'s thermal tests of machine tools model warm-up the same way). One parameter e_inf (ppm, the
  saturated growth) per form (WARMUP_FORMS: the pivots of THERMAL_FORMS); tau (s) is profiled (the growth is linear
  in e_inf at a given tau) and carried in `Extension.meta[FORMS]`. Before the fitted span the growth is held at its
  start; after it the curve saturates by itself at e_inf (bounded by `calib.diagnose.plausibility`), which is the
  point of the form: unlike the linear drift it does not keep growing after the campaign.
- payload_compliance: joint compliance under a payload that changes during the campaign, dq_j = c_j tau_j(q, m_r),
  tau_j the gravity torque joint j holds with the arm and the payload of mass m_r mounted at row r (the table's
  optional `load_kg` column, LOAD_COLUMN), the payload's centre of mass at the last link's (the robot config's
  com_mm of the last joint: a tool or load bolted to the flange). Joint stiffness of heavy serial robots (Dumas,
  Caro, Garnier, Furet, "Joint stiffness identification of six-revolute industrial serial robots", Robotics and
  Computer-Integrated Manufacturing 27(4), 2011): a candidate only when the load changes over the rows (else it is
  joint_compliance). Rows without the column (predict, compensate) carry the load the fitted campaign ended with.
Physical candidates of real cells, forms and sources in `calib.diagnose.point_effects`: range_scale (one station's
distances scaled: its air data), nest_sag (a reflector nest displaced along gravity) and wrist_coupling (a joint cause:
the wrist's coupling ratios, dq5 = c54 q4, dq6 = c64 q4 + c65 q5).

station_shift (a tracker station moved during the campaign) is handled by re-labelling the station after
the change point (calib.diagnose), not here.

Several causes at once: `features.combine` stacks extensions into one; `build_parts` builds them by name.

Features are computed once on the whole table in time order (approach directions need the previous
pose), then subset with the rows.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from trackcal.calib.diagnose.joint_map import CAUSE as MAP
from trackcal.calib.diagnose.joint_map import Arc, map_extension
from trackcal.calib.diagnose.point_effects import (
    NEST_SAG,
    POINT_CAUSES,
    RANGE_SCALE,
    WRIST_COUPLING,
    nest_sag_extension,
    range_scale_extension,
    wrist_coupling_extension,
)
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.extension import (
    FORMS,
    UNIT_FACTORS,
    Extension,
    ExtensionError,
    Ranges,
    combine,
    select_columns,
)
from trackcal.calib.model.pinmodel import gravity_torques

CAUSES = (
    "joint_compliance",
    "backlash",
    "encoder_scale",
    "cyclic_error",
    "thermal_drift",
    "station_shift",
    "thermal_warmup",
    "payload_compliance",
    WRIST_COUPLING,
    *POINT_CAUSES,
)
JOINT_CAUSES = ("joint_compliance", "backlash", "encoder_scale", "cyclic_error", WRIST_COUPLING)
THERMAL_FORMS = ("e", "e_base")  # arm + tool about the first joint's frame; base column too, about the base origin
WARMUP_FORMS = ("e_inf", "e_inf_base")  # the same pivots, the saturated growth
LOAD_COLUMN = "load_kg"  # the payload mounted at each row (optional table column)


def warmup_growth(t_s: np.ndarray, tau_s: float, t0_s: float) -> np.ndarray:
    """(N,) the first-order warm-up's shape 1 - exp(-(t - t0) / tau), held at 0 before t0."""
    return -np.expm1(-np.maximum(np.asarray(t_s, dtype=float) - t0_s, 0.0) / tau_s)


def warmup_pivot(chain: Chain, form: str) -> np.ndarray:
    """The point (mm, robot base frame) thermal_warmup's form (WARMUP_FORMS) keeps fixed."""
    return np.zeros(3) if form == "e_inf_base" else np.array(chain.base[:3, 3], dtype=float)


def row_loads(table: MeasurementTable, default: float | None = None) -> np.ndarray | None:
    """(N,) the payload (kg) mounted at each row: the table's LOAD_COLUMN, else `default` at every row; None when
    neither is known (ExtensionError for a load that is not a finite number >= 0)."""
    if LOAD_COLUMN not in table.extra:
        return None if default is None else np.full(len(table), float(default))
    try:
        loads = table.extra[LOAD_COLUMN].astype(float)
    except ValueError:
        raise ExtensionError(f"{table.source}: column {LOAD_COLUMN} must hold numbers (kg)") from None
    if not np.all(np.isfinite(loads) & (loads >= 0)):
        raise ExtensionError(f"{table.source}: column {LOAD_COLUMN} must hold finite loads >= 0 kg")
    return loads


def payload_torques(chain: Chain, q: np.ndarray, loads: np.ndarray, com_mm: np.ndarray) -> np.ndarray:
    """(N, n) gravity torques (N m) of the arm holding at row r the payload loads[r] (kg) at com_mm (last link's
    frame): the last link's mass and centre of mass with the payload's added, one pinocchio model per load."""
    out = np.zeros_like(q)
    last = chain.joints[-1]
    for load in np.unique(loads):
        rows = loads == load
        mass = last.mass_kg + load
        com = (last.mass_kg * np.asarray(last.com, dtype=float) + load * com_mm) / mass if mass > 0 else last.com
        joints = (*chain.joints[:-1], replace(last, mass_kg=mass, com=com))
        out[rows] = gravity_torques(replace(chain, joints=joints), q[rows])
    return out


def approach_signs(q: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """(N, n): the direction (+1 / -1) each joint last moved in before each row, 0 before its first move."""
    out = np.zeros_like(q)
    if len(q) < 2:
        return out
    d = np.diff(q, axis=0)
    moved = np.abs(d) > tol
    # forward fill, the whole array at once: the last row (of the differences) where each joint moved
    last = np.maximum.accumulate(np.where(moved, np.arange(len(d))[:, None], -1), axis=0)
    out[1:] = np.where(last >= 0, np.sign(np.take_along_axis(d, np.maximum(last, 0), axis=0)), 0.0)
    return out


def build_extension(
    cause: str,
    chain: Chain,
    table: MeasurementTable,
    harmonics: int = 2,
    names: list[str] | None = None,
    arcs: dict[int, Arc] | None = None,
    ranges: Ranges | None = None,
    form: dict | None = None,
) -> Extension:
    """The extension `cause` for the rows of `table` (time order), in internal units (rad, N m, s).
    `names` selects the parameters (as a fitted model lists them) instead of keeping every varying one;
    for cyclic_error `arcs` are the joints' fitted arcs (default: the table's own), for thermal_drift the
    name picks the form (THERMAL_FORMS; default `e`). `ranges`: the joint angles and times the extension was
    fitted on (default: the table's own); features are computed at the rows' angles and times clamped into them
    (`Ranges`: held outside, every unbounded term alike); the joint error map is periodic and held outside its
    fitted arcs instead (an angle beyond a joint's range but inside its arc modulo 360 deg is inside the map); two
    are bounded by their physics and defined everywhere: backlash (+-b/2 by the approach direction) and
    joint_compliance (a gravity torque, at most the arm's weight times its reach, and its deflection within
    `calib.diagnose.plausibility`'s range). `form`: what thermal_warmup ({"tau_s"}; default a third of the fitted
    time span) and payload_compliance ({"com_mm", "final_load_kg"}; default the last link's centre of mass and the
    table's last load) need beyond the table, as `Extension.meta[FORMS]` carries it."""
    q_read = np.radians(table.q_deg)
    ranges = Ranges.of(q_read, table.t_s) if ranges is None else ranges
    q = ranges.clamp_q(q_read)
    n_rows, n = q.shape
    if cause in ("joint_compliance", "backlash", "encoder_scale"):
        signature = {
            "joint_compliance": lambda: gravity_torques(chain, q_read),  # N m
            "backlash": lambda: 0.5 * approach_signs(q_read),
            "encoder_scale": lambda: q,
        }[cause]()
        feats = np.zeros((n_rows, n, n))
        for j in range(n):
            feats[:, j, j] = signature[:, j]
        letter, unit, factor = {
            "joint_compliance": ("c", "deg/kNm", UNIT_FACTORS["deg/kNm"]),
            "backlash": ("b", "deg", UNIT_FACTORS["deg"]),
            "encoder_scale": ("k", "ppm", UNIT_FACTORS["ppm"]),
        }[cause]
        feats, kept = select_columns(feats, [f"{letter}{j + 1}" for j in range(n)], names)
        return Extension(cause, kept, [unit] * len(kept), np.full(len(kept), factor), feats, meta={"ranges": ranges})
    if cause == MAP:
        ext = map_extension(q_read, harmonics, names, arcs)  # periodic: held outside its arcs (`Arc.clamp`)
        ext.meta["ranges"] = ranges
        return ext
    if cause == WRIST_COUPLING:
        return wrist_coupling_extension(q_read, names, ranges)
    if cause == RANGE_SCALE:
        return range_scale_extension(table, names, ranges)
    if cause == NEST_SAG:
        return nest_sag_extension(table, names, ranges)
    if cause == "thermal_drift":
        forms = names or [THERMAL_FORMS[0]]
        if len(forms) != 1 or forms[0] not in THERMAL_FORMS:
            raise ExtensionError(
                f"unknown extension parameter(s) {', '.join(forms)}; thermal_drift has one of "
                f"{', '.join(THERMAL_FORMS)}"
            )
        pivot = np.zeros(3) if forms[0] == "e_base" else np.array(chain.base[:3, 3], dtype=float)
        return Extension(
            cause,
            list(forms),
            ["ppm/h"],
            np.array([UNIT_FACTORS["ppm/h"]]),
            growth=ranges.clamp_t(table.t_s)[:, None],
            pivot=pivot,
            meta={"ranges": ranges},
        )
    if cause == "thermal_warmup":
        return _warmup(chain, table, names, ranges, form)
    if cause == "payload_compliance":
        return _payload(chain, table, q_read, names, ranges, form)
    raise ExtensionError(f"unknown model extension {cause!r}; choose from {', '.join(CAUSES)} or none")


def _warmup(
    chain: Chain, table: MeasurementTable, names: list[str] | None, ranges: Ranges, form: dict | None
) -> Extension:
    forms = names or [WARMUP_FORMS[0]]
    if len(forms) != 1 or forms[0] not in WARMUP_FORMS:
        raise ExtensionError(
            f"unknown extension parameter(s) {', '.join(forms)}; thermal_warmup has one of {', '.join(WARMUP_FORMS)}"
        )
    t0, t1 = ranges.time_s
    tau = float((form or {}).get("tau_s", max(t1 - t0, 1.0) / 3.0))
    if not (np.isfinite(tau) and tau > 0):
        raise ExtensionError(f"thermal_warmup: the time constant tau_s must be a positive number, got {tau!r}")
    pivot = warmup_pivot(chain, forms[0])
    doc = {"tau_s": tau, **{k: v for k, v in (form or {}).items() if k != "tau_s"}}
    return Extension(
        "thermal_warmup",
        list(forms),
        ["ppm"],
        np.array([UNIT_FACTORS["ppm"]]),
        growth=warmup_growth(table.t_s, tau, t0)[:, None],
        pivot=pivot,
        meta={"ranges": ranges, FORMS: {"thermal_warmup": doc}},
    )


def _payload(
    chain: Chain,
    table: MeasurementTable,
    q_read: np.ndarray,
    names: list[str] | None,
    ranges: Ranges,
    form: dict | None,
) -> Extension:
    form = form or {}
    loads = row_loads(table, form.get("final_load_kg"))
    n_rows, n = q_read.shape
    com = np.asarray(form.get("com_mm", chain.joints[-1].com), dtype=float)
    if loads is None or (names is None and (len(loads) == 0 or np.ptp(loads) <= 0)):  # no change: joint_compliance
        return Extension("payload_compliance", [], [], np.zeros(0), np.zeros((n_rows, n, 0)), meta={"ranges": ranges})
    tau = payload_torques(chain, q_read, loads, com)  # N m, bounded by the arm's and payload's weight
    feats = np.zeros((n_rows, n, n))
    for j in range(n):
        feats[:, j, j] = tau[:, j]
    feats, kept = select_columns(feats, [f"c{j + 1}" for j in range(n)], names)
    doc = {"com_mm": com.tolist(), "final_load_kg": float(form.get("final_load_kg", loads[-1] if n_rows else 0.0))}
    return Extension(
        "payload_compliance",
        kept,
        ["deg/kNm"] * len(kept),
        np.full(len(kept), UNIT_FACTORS["deg/kNm"]),
        feats,
        meta={"ranges": ranges, FORMS: {"payload_compliance": doc}},
    )


def build_parts(
    parts: list[tuple[str, list[str]]],
    chain: Chain,
    table: MeasurementTable,
    arcs: dict[int, Arc] | None = None,
    cause: str | None = None,
    ranges: Ranges | None = None,
    forms: dict | None = None,
) -> Extension:
    """The extension made of `parts` ((cause, parameter names), as `Extension.parts` lists them) for the rows of
    `table`; `arcs` are the joint error map's fitted arcs, `cause` the main cause (default: the first part's),
    `ranges` those it was fitted on (default: the table's own), `forms` {cause: form} (`build_extension`'s)."""
    forms = forms or {}
    return combine(
        [
            build_extension(
                c,
                chain,
                table,
                names=list(n),
                arcs=arcs if c == "cyclic_error" else None,
                ranges=ranges,
                form=forms.get(c),
            )
            for c, n in parts
        ],
        cause,
    )


def rebuild(ext: Extension, chain: Chain, table: MeasurementTable) -> Extension:
    """A fitted extension's features for the rows of another table (same parameters, same fitted arcs, ranges and
    forms)."""
    return build_parts(
        ext.parts(), chain, table, ext.meta.get("arcs"), ext.cause, ext.meta.get("ranges"), ext.meta.get(FORMS)
    )
