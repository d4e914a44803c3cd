"""Non-geometric model extensions: physical causes with few parameters, added to the geometric model.

Every extension is linear in its parameters theta, through two kinds of features computed from the rows:

- joint features Phi (N, n, e): the joint angle the controller reports is off, q_true = q_read + Phi theta;
- growth features G (N, e): the arm grows by the fraction g = G theta about a pivot (robot base frame),
  p_true = pivot + (1 + g) (p - pivot), p the reflector position of the rigid model.

Joint-type causes:
- joint_compliance: dq_j = c_j tau_j(q), tau_j the gravity torque joint j holds (mass model of the
  robot config, pinocchio RNEA); one compliance per joint whose torque varies over the campaign;
- backlash: dq_j = (b_j / 2) s_j, s_j = +1 / -1 the direction joint j last moved in before the row (time
  order; 0 before it first moves): a dead band of width b_j;
- encoder_scale: dq_j = k_j q_j (gear-ratio / encoder gain error);
- cyclic_error: the joint error map of `calib.diagnose.joint_map`, a Fourier series per joint in its own angle of
  any order (`calib.diagnose.error_map` fits it and chooses order and ridge); here its features for given
  coefficient names and fitted arcs, or for harmonics 1..H over the table's own arcs.

Growth cause:
- thermal_drift: uniform thermal growth of every length, g = e t (t the row's time since the campaign
  start). A rigid chain whose translations (tool included) all grow by the same fraction scales every
  point about the chain's first frame exactly. Two forms, named by their parameter (THERMAL_FORMS): `e`,
  the arm and the tool grow about the first joint's frame (the base column does not); `e_base`, the base
  column grows too (pivot: the robot base frame's origin, a robot warming as a whole). Both have one
  parameter: the data choose (fit both, the lower residual wins).

station_shift (a tracker station moved during the campaign) is handled by re-labelling the station after
the change point (calib.diagnose), not here.

Several causes at once: `combine` stacks extensions into one (parameters in order, features padded with
zeros); `Extension.parts` lists the (cause, parameter names) it carries.

Features are computed once on the whole table in time order (approach directions need the previous
pose), then subset with the rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackcal.calib.diagnose.joint_map import Arc, JointMapError, harmonic_names, map_features, parse_name
from trackcal.calib.errors import CalibError
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.pinmodel import gravity_torques

CAUSES = ("joint_compliance", "backlash", "encoder_scale", "cyclic_error", "thermal_drift", "station_shift")
JOINT_CAUSES = ("joint_compliance", "backlash", "encoder_scale", "cyclic_error")
THERMAL_FORMS = ("e", "e_base")  # arm + tool about the first joint's frame; base column too, about the base origin
# boundary unit -> factor from internal units (rad, N m, s)
UNIT_FACTORS = {"deg": float(np.degrees(1.0)), "deg/kNm": float(np.degrees(1.0)) * 1000.0, "ppm": 1e6,
                "ppm/h": 1e6 * 3600.0}  # fmt: skip


class ExtensionError(CalibError):
    """A model extension that does not exist or cannot be built: an unknown cause or parameter, parts that do not
    fit together."""


@dataclass
class Extension:
    cause: str
    names: list[str]
    units: list[str]  # boundary units
    to_boundary: np.ndarray  # internal value * to_boundary = boundary value
    joint_features: np.ndarray | None = None  # (N, n, e): dq = joint_features @ theta (rad)
    growth: np.ndarray | None = None  # (N, e): the arm grows by the fraction growth @ theta about `pivot`
    pivot: np.ndarray = field(default_factory=lambda: np.zeros(3))  # mm, robot base frame
    meta: dict = field(default_factory=dict)  # cyclic_error: "arcs" {joint: Arc}; combined: "parts"

    @property
    def size(self) -> int:
        return len(self.names)

    def subset(self, rows: np.ndarray) -> Extension:
        return Extension(
            self.cause, self.names, self.units, self.to_boundary,
            None if self.joint_features is None else self.joint_features[rows],
            None if self.growth is None else self.growth[rows], self.pivot, dict(self.meta),
        )  # fmt: skip

    def joint_offsets(self, theta: np.ndarray) -> np.ndarray | None:
        if self.joint_features is None:
            return None
        return np.einsum("rje,e->rj", self.joint_features, theta)

    def growth_of(self, theta: np.ndarray) -> np.ndarray | None:
        """(N,) fractional growth of the arm, or None without growth features."""
        return None if self.growth is None else self.growth @ theta

    def parts(self) -> list[tuple[str, list[str]]]:
        """(cause, parameter names) of every extension combined into this one, in parameter order."""
        return self.meta.get("parts", [(self.cause, list(self.names))])


def combine(extensions: list[Extension], cause: str | None = None) -> Extension:
    """One extension carrying all of `extensions` (parameters in order); `cause` names the main one (default:
    the first's). Growth extensions must share their pivot."""
    if len(extensions) == 1 and cause in (None, extensions[0].cause):
        return extensions[0]
    rows = {len(x.joint_features if x.joint_features is not None else x.growth) for x in extensions}
    if len(rows) != 1:
        raise ExtensionError("extensions of tables with different rows cannot be combined")
    pivots = {tuple(x.pivot) for x in extensions if x.growth is not None}
    if len(pivots) > 1:
        raise ExtensionError("two growth extensions with different pivots cannot be combined")
    (n_rows,) = rows
    n = next((x.joint_features.shape[1] for x in extensions if x.joint_features is not None), 0)
    e = sum(x.size for x in extensions)
    jf = np.zeros((n_rows, n, e)) if n else None
    gr = np.zeros((n_rows, e)) if pivots else None
    at = 0
    for x in extensions:
        if x.joint_features is not None:
            jf[:, :, at : at + x.size] = x.joint_features
        if x.growth is not None:
            gr[:, at : at + x.size] = x.growth
        at += x.size
    meta = {k: v for x in extensions for k, v in x.meta.items() if k != "parts"}
    meta["parts"] = [part for x in extensions for part in x.parts()]
    return Extension(
        cause or extensions[0].cause, [nm for x in extensions for nm in x.names],
        [u for x in extensions for u in x.units], np.concatenate([x.to_boundary for x in extensions]), jf, gr,
        np.array(pivots.pop()) if pivots else np.zeros(3), meta,
    )  # fmt: skip


def approach_signs(q: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """(N, n): the direction (+1 / -1) each joint last moved in before each row, 0 before its first move."""
    out = np.zeros_like(q)
    state = np.zeros(q.shape[1])
    for r in range(1, len(q)):
        d = q[r] - q[r - 1]
        moved = np.abs(d) > tol
        state = np.where(moved, np.sign(d), state)
        out[r] = state
    return out


def _select(features: np.ndarray, names: list[str], wanted: list[str] | None, rel_tol: float = 1e-6):
    """Keep the wanted columns by name, or (None) those that vary over the rows: a constant feature is a
    joint offset, not a cause."""
    if wanted is not None:
        unknown = [w for w in wanted if w not in names]
        if unknown:
            raise ExtensionError(f"unknown extension parameter(s) {', '.join(unknown)}")
        keep = np.array([n in wanted for n in names])
    else:
        col_std = features.std(axis=0).max(axis=0)
        keep = col_std > rel_tol * max(col_std.max(), 1e-300)
    return features[:, :, keep], [n for n, k in zip(names, keep, strict=True) if k]


def _map_names(wanted: list[str], arcs: dict[int, Arc]) -> list[str]:
    """The wanted cyclic_error coefficient names, checked against the joints the arcs cover."""
    bad = []
    for nm in wanted:
        try:
            kind, h, j = parse_name(nm)
        except JointMapError:
            bad.append(nm)
            continue
        if kind not in "sc" or h < 1 or j not in arcs:
            bad.append(nm)
    if bad:
        raise ExtensionError(f"unknown extension parameter(s) {', '.join(bad)}")
    return list(wanted)


def build_extension(
    cause: str, chain: Chain, table: MeasurementTable, harmonics: int = 2, names: list[str] | None = None,
    arcs: dict[int, Arc] | None = None,
) -> Extension:
    """The extension `cause` for the rows of `table` (time order), in internal units (rad, N m, s).
    `names` selects the parameters (as a fitted model lists them) instead of keeping every varying one;
    for cyclic_error `arcs` are the joints' fitted arcs (default: the table's own), for thermal_drift the
    name picks the form (THERMAL_FORMS; default `e`)."""
    q = np.radians(table.q_deg)
    n_rows, n = q.shape
    if cause in ("joint_compliance", "backlash", "encoder_scale"):
        signature = {
            "joint_compliance": lambda: gravity_torques(chain, q),  # N m
            "backlash": lambda: 0.5 * approach_signs(q),
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
        feats, kept = _select(feats, [f"{letter}{j + 1}" for j in range(n)], names)
        return Extension(cause, kept, [unit] * len(kept), np.full(len(kept), factor), feats)
    if cause == "cyclic_error":
        arcs = {j: Arc.covering(q[:, j]) for j in range(n)} if arcs is None else arcs
        if names is None:
            candidates = [nm for j in sorted(arcs) for nm in harmonic_names(j, harmonics)]
            feats, kept = _select(map_features(q, candidates, arcs), candidates, None)
        else:
            kept = _map_names(names, arcs)
            feats = map_features(q, kept, arcs)
        return Extension(cause, kept, ["deg"] * len(kept), np.full(len(kept), UNIT_FACTORS["deg"]), feats,
                         meta={"arcs": {j: arcs[j] for j in sorted({parse_name(nm)[2] for nm in kept})}})  # fmt: skip
    if cause == "thermal_drift":
        forms = names or [THERMAL_FORMS[0]]
        if len(forms) != 1 or forms[0] not in THERMAL_FORMS:
            raise ExtensionError(f"unknown extension parameter(s) {', '.join(forms)}; thermal_drift has one of "
                             f"{', '.join(THERMAL_FORMS)}")  # fmt: skip
        pivot = np.zeros(3) if forms[0] == "e_base" else np.array(chain.base[:3, 3], dtype=float)
        return Extension(cause, list(forms), ["ppm/h"], np.array([UNIT_FACTORS["ppm/h"]]),
                         growth=np.asarray(table.t_s, float)[:, None], pivot=pivot)  # fmt: skip
    raise ExtensionError(f"unknown model extension {cause!r}; choose from {', '.join(CAUSES)} or none")


def build_parts(
    parts: list[tuple[str, list[str]]], chain: Chain, table: MeasurementTable, arcs: dict[int, Arc] | None = None,
    cause: str | None = None,
) -> Extension:
    """The extension made of `parts` ((cause, parameter names), as `Extension.parts` lists them) for the rows of
    `table`; `arcs` are the joint error map's fitted arcs, `cause` the main cause (default: the first part's)."""
    return combine([build_extension(c, chain, table, names=list(n), arcs=arcs if c == "cyclic_error" else None)
                    for c, n in parts], cause)  # fmt: skip


def rebuild(ext: Extension, chain: Chain, table: MeasurementTable) -> Extension:
    """A fitted extension's features for the rows of another table (same parameters, same fitted arcs)."""
    return build_parts(ext.parts(), chain, table, ext.meta.get("arcs"), ext.cause)
