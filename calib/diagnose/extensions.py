"""Non-geometric model extensions: physical causes with few parameters, added to the geometric model.

Every extension is linear in its parameters theta (`calib.diagnose.features`: joint features, the reported joint
angles are off by Phi theta; growth features, the arm grows by the fraction G theta about a pivot).

Joint-type causes:
- joint_compliance: dq_j = c_j tau_j(q), tau_j the gravity torque joint j holds (mass model of the
  robot config, pinocchio RNEA); one compliance per joint whose torque varies over the campaign;
- backlash: dq_j = (b_j / 2) s_j, s_j = +1 / -1 the direction joint j last moved in before the row (time
  order; 0 before it first moves): a dead band of width b_j;
- encoder_scale: dq_j = k_j q_j (gear-ratio / encoder gain error);
- cyclic_error: the joint error map, a Fourier series per joint in its own angle of any order; its form, its
  features and its ridge fit are `calib.diagnose.joint_map`, which `build_extension` calls for it.

Growth cause:
- thermal_drift: uniform thermal growth of every length, g = e t (t the row's time since the campaign
  start). A rigid chain whose translations (tool included) all grow by the same fraction scales every
  point about the chain's first frame exactly. Two forms, named by their parameter (THERMAL_FORMS): `e`,
  the arm and the tool grow about the first joint's frame (the base column does not); `e_base`, the base
  column grows too (pivot: the robot base frame's origin, a robot warming as a whole). Both have one
  parameter: the data choose (fit both, the lower residual wins).

station_shift (a tracker station moved during the campaign) is handled by re-labelling the station after
the change point (calib.diagnose), not here.

Several causes at once: `features.combine` stacks extensions into one; `build_parts` builds them by name.

Features are computed once on the whole table in time order (approach directions need the previous
pose), then subset with the rows.
"""

from __future__ import annotations

import numpy as np

from trackcal.calib.diagnose.features import UNIT_FACTORS, Extension, ExtensionError, Ranges, combine, select_columns
from trackcal.calib.diagnose.joint_map import CAUSE as MAP
from trackcal.calib.diagnose.joint_map import Arc, map_extension
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.pinmodel import gravity_torques

CAUSES = ("joint_compliance", "backlash", "encoder_scale", "cyclic_error", "thermal_drift", "station_shift")
JOINT_CAUSES = ("joint_compliance", "backlash", "encoder_scale", "cyclic_error")
THERMAL_FORMS = ("e", "e_base")  # arm + tool about the first joint's frame; base column too, about the base origin


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
    cause: str, chain: Chain, table: MeasurementTable, harmonics: int = 2, names: list[str] | None = None,
    arcs: dict[int, Arc] | None = None, ranges: Ranges | None = None,
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
    `calib.diagnose.plausibility`'s range)."""
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
    if cause == "thermal_drift":
        forms = names or [THERMAL_FORMS[0]]
        if len(forms) != 1 or forms[0] not in THERMAL_FORMS:
            raise ExtensionError(f"unknown extension parameter(s) {', '.join(forms)}; thermal_drift has one of "
                             f"{', '.join(THERMAL_FORMS)}")  # fmt: skip
        pivot = np.zeros(3) if forms[0] == "e_base" else np.array(chain.base[:3, 3], dtype=float)
        return Extension(cause, list(forms), ["ppm/h"], np.array([UNIT_FACTORS["ppm/h"]]),
                         growth=ranges.clamp_t(table.t_s)[:, None], pivot=pivot, meta={"ranges": ranges})  # fmt: skip
    raise ExtensionError(f"unknown model extension {cause!r}; choose from {', '.join(CAUSES)} or none")


def build_parts(
    parts: list[tuple[str, list[str]]], chain: Chain, table: MeasurementTable, arcs: dict[int, Arc] | None = None,
    cause: str | None = None, ranges: Ranges | None = None,
) -> Extension:
    """The extension made of `parts` ((cause, parameter names), as `Extension.parts` lists them) for the rows of
    `table`; `arcs` are the joint error map's fitted arcs, `cause` the main cause (default: the first part's),
    `ranges` those it was fitted on (default: the table's own)."""
    return combine([build_extension(c, chain, table, names=list(n), arcs=arcs if c == "cyclic_error" else None,
                                    ranges=ranges) for c, n in parts], cause)  # fmt: skip


def rebuild(ext: Extension, chain: Chain, table: MeasurementTable) -> Extension:
    """A fitted extension's features for the rows of another table (same parameters, same fitted arcs and ranges)."""
    return build_parts(ext.parts(), chain, table, ext.meta.get("arcs"), ext.cause, ext.meta.get("ranges"))
