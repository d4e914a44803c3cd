"""Non-geometric model extensions: physical causes with few parameters, added to the geometric model.

Joint-type causes perturb the joint angle the controller reports, q_true = q_read + Phi(row) theta,
linear in their parameters theta with features Phi computed from the rows:

- joint_compliance: dq_j = c_j tau_j(q), tau_j the gravity torque joint j holds (mass model of the
  robot config, pinocchio RNEA); one compliance per joint whose torque varies over the campaign;
- backlash: dq_j = (b_j / 2) s_j, s_j = +1 / -1 the direction joint j last moved in before the row (time
  order; 0 before it first moves): a dead band of width b_j;
- encoder_scale: dq_j = k_j q_j (gear-ratio / encoder gain error);
- cyclic_error: dq_j = sum_h a_jh sin(h q_j) + b_jh cos(h q_j), harmonics h = 1..H;

- thermal_drift: every link vector grows by (1 + e t), t the row's time since the campaign start: the arm
  (not the tool) is scaled about its base, linear in e;
- station_shift: a tracker station moved during the campaign; handled by re-labelling the station after
  the change point (calib.diagnose), not here.

Features are computed once on the whole table in time order (approach directions need the previous
pose), then subset with the rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .chain import Chain
from .pinmodel import gravity_torques
from .table import MeasurementTable

CAUSES = ("joint_compliance", "backlash", "encoder_scale", "cyclic_error", "thermal_drift", "station_shift")
JOINT_CAUSES = ("joint_compliance", "backlash", "encoder_scale", "cyclic_error")
# boundary unit -> factor from internal units (rad, N m, s)
UNIT_FACTORS = {"deg": float(np.degrees(1.0)), "deg/kNm": float(np.degrees(1.0)) * 1000.0, "ppm": 1e6,
                "ppm/h": 1e6 * 3600.0}  # fmt: skip


@dataclass
class Extension:
    cause: str
    names: list[str]
    units: list[str]  # boundary units
    to_boundary: np.ndarray  # internal value * to_boundary = boundary value
    joint_features: np.ndarray | None = None  # (N, n, e): dq = joint_features @ theta (rad)
    arm_scale: np.ndarray | None = None  # (N,): arm scaled by 1 + theta[0] * arm_scale
    meta: dict = field(default_factory=dict)

    @property
    def size(self) -> int:
        return len(self.names)

    def subset(self, rows: np.ndarray) -> Extension:
        return Extension(
            self.cause, self.names, self.units, self.to_boundary,
            None if self.joint_features is None else self.joint_features[rows],
            None if self.arm_scale is None else self.arm_scale[rows], dict(self.meta),
        )  # fmt: skip

    def joint_offsets(self, theta: np.ndarray) -> np.ndarray | None:
        if self.joint_features is None:
            return None
        return np.einsum("rje,e->rj", self.joint_features, theta)


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
            raise ValueError(f"unknown extension parameter(s) {', '.join(unknown)}")
        keep = np.array([n in wanted for n in names])
    else:
        col_std = features.std(axis=0).max(axis=0)
        keep = col_std > rel_tol * max(col_std.max(), 1e-300)
    return features[:, :, keep], [n for n, k in zip(names, keep, strict=True) if k]


def build_extension(
    cause: str, chain: Chain, table: MeasurementTable, harmonics: int = 2, names: list[str] | None = None
) -> Extension:
    """The extension `cause` for the rows of `table` (time order), in internal units (rad, N m, s).
    `names` selects the parameters (as a fitted model lists them) instead of keeping every varying one."""
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
        cols, all_names = [], []
        for j in range(n):
            for h in range(1, harmonics + 1):
                for fn, label in ((np.sin, "s"), (np.cos, "c")):
                    f = np.zeros((n_rows, n))
                    f[:, j] = fn(h * q[:, j])
                    cols.append(f)
                    all_names.append(f"{label}{h}_{j + 1}")
        feats, kept = _select(np.stack(cols, axis=2), all_names, names)
        return Extension(cause, kept, ["deg"] * len(kept), np.full(len(kept), UNIT_FACTORS["deg"]), feats)
    if cause == "thermal_drift":
        scale = np.array([UNIT_FACTORS["ppm/h"]])
        return Extension(cause, ["e"], ["ppm/h"], scale, arm_scale=np.asarray(table.t_s, float))
    raise ValueError(f"unknown model extension {cause!r}; choose from {', '.join(CAUSES)} or none")
