"""A model extension: features linear in its parameters, computed from the rows of a table. It sits with the model,
below the solver that fits it (calib.identify), the causes that build it (calib.diagnose) and the model file that
stores it (calib.model_file).

Two kinds of features (`calib.diagnose.extensions` lists the causes, `calib.diagnose.joint_map` the joint error map):

- joint features Phi (N, n, e): the joint angle the controller reports is off, q_true = q_read + Phi theta (held in
  per-joint block form, `JointFeatures`: each parameter moves one joint);
- growth features G (N, e): the arm grows by the fraction g = G theta about a pivot (robot base frame),
  p_true = pivot + (1 + g) (p - pivot), p the reflector position of the rigid model;
- point features, on the measured point rather than the arm: a displacement D (N, 3, e) of the reflector in the robot
  base frame, p_true = p + D theta (after any growth: a nest that sags, `calib.diagnose.point_effects`), and a range
  scale S (N, e) of the row's station, x_measured = (1 + S theta) x (x the reflector in the station frame: the
  station's distances scaled about its origin, wrong air data). Both are linear in theta; the solver's Jacobian of
  them is exact (`calib.identify.solver.Problem`).

Several causes at once: `combine` stacks extensions into one (parameters in order, features padded with
zeros); `Extension.parts` lists the (cause, parameter names) it carries.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackcal.calib.errors import CalibError

# boundary unit -> factor from internal units (rad, N m, s)
UNIT_FACTORS = {
    "deg": float(np.degrees(1.0)),
    "deg/kNm": float(np.degrees(1.0)) * 1000.0,
    "ppm": 1e6,
    "ppm/h": 1e6 * 3600.0,
    "mm": 1.0,
}
FORMS = "forms"  # Extension.meta key: {cause: what its features need beyond the table} (model.json: extension.forms)


@dataclass(frozen=True)
class Ranges:
    """What an extension was fitted on: each joint's range of angles (rad) and the span of the rows' times (s).
    Outside them every extension is held at its value at the nearest fitted point, all its unbounded terms alike
    (the features are computed at the angles and times clamped into the ranges; backlash and gravity compliance are
    bounded by their physics, `calib.diagnose.extensions.build_extension`): no term is extrapolated against a
    held one (issue 36: an encoder scale kept linear beyond a joint's range while the joint map was held broke a
    cancellation inside it, and an unseen ABB IRB 120 was 7x worse than with the geometric model)."""

    joints_rad: tuple[tuple[float, float], ...]  # (low, high) per joint
    time_s: tuple[float, float]

    @staticmethod
    def of(q: np.ndarray, t_s: np.ndarray) -> Ranges:
        """The ranges of joint angles q (N, n) rad and times t_s (N,)."""
        t = np.asarray(t_s, dtype=float)
        return Ranges(
            tuple((float(lo), float(hi)) for lo, hi in zip(q.min(axis=0), q.max(axis=0), strict=True)),
            (float(t.min()), float(t.max())) if len(t) else (0.0, 0.0),
        )

    def clamp_q(self, q: np.ndarray) -> np.ndarray:
        lim = np.array(self.joints_rad)
        return np.clip(q, lim[:, 0], lim[:, 1])

    def clamp_t(self, t_s: np.ndarray) -> np.ndarray:
        return np.clip(np.asarray(t_s, dtype=float), *self.time_s)

    def outside(self, q: np.ndarray) -> np.ndarray:
        """(N, n) bool: the angles outside their joint's range (beyond 1e-9 rad of rounding)."""
        lim = np.array(self.joints_rad)
        return (q < lim[:, 0] - 1e-9) | (q > lim[:, 1] + 1e-9)

    def to_doc(self) -> dict:
        return {
            "joints": {
                f"joint_{j + 1}": {"from_deg": float(np.degrees(lo)), "to_deg": float(np.degrees(hi))}
                for j, (lo, hi) in enumerate(self.joints_rad)
            },
            "time_s": {"from": self.time_s[0], "to": self.time_s[1]},
        }

    @staticmethod
    def from_doc(doc: dict, n: int) -> Ranges:
        """From model.json's extension.valid, `n` joints (ExtensionError, or KeyError / TypeError / ValueError of the
        document's access, when malformed)."""
        joints = doc["joints"]
        rows = [joints[f"joint_{j + 1}"] for j in range(n)]
        lims = tuple((float(np.radians(float(r["from_deg"]))), float(np.radians(float(r["to_deg"])))) for r in rows)
        if any(not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi) for lo, hi in lims):
            raise ExtensionError("a joint range must be two finite angles, from <= to")
        t0, t1 = float(doc["time_s"]["from"]), float(doc["time_s"]["to"])
        if not (np.isfinite(t0) and np.isfinite(t1) and t0 <= t1):
            raise ExtensionError("time_s must be two finite times, from <= to")
        return Ranges(lims, (t0, t1))


class ExtensionError(CalibError):
    """A model extension that does not exist or cannot be built: an unknown cause or parameter, parts that do not
    fit together."""


@dataclass(frozen=True, eq=False)
class JointFeatures:
    """Joint features Phi (N, n, e) in per-joint block form: every parameter moves one joint (a map harmonic, a
    compliance, a backlash, a wrist coupling), so Phi[r, joint[c], c] = values[r, c] and every other entry is zero.
    The block form holds N e values where the dense array holds N n e, most of them zeros (issue 41: a diagnosis of
    the UR10's Series B held two dense maps of 650 columns, 62 KB per row). What is computed from it is what the dense
    array gave: the same values (the Jacobian's columns, bit for bit) or the same sums in another order (to
    rounding)."""

    values: np.ndarray  # (N, e): each row's feature of each parameter on the joint it moves
    joint: np.ndarray  # (e,) int: the joint (0-based) each parameter moves
    n: int  # joints of the arm

    @staticmethod
    def of(feats: np.ndarray) -> JointFeatures:
        """From dense features (N, n, e) (ExtensionError when a parameter moves two joints)."""
        moves = np.abs(feats).max(axis=0, initial=0.0) > 0  # (n, e)
        if np.any(moves.sum(axis=0) > 1):
            raise ExtensionError("a joint feature parameter moves more than one joint")
        joint = np.argmax(moves, axis=0)
        return JointFeatures(np.take_along_axis(feats, joint[None, None, :], axis=1)[:, 0, :], joint, feats.shape[1])

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.values.shape[0], self.n, self.values.shape[1]

    def take(self, rows) -> JointFeatures:
        return JointFeatures(self.values[rows], self.joint, self.n)

    def columns(self, cols) -> JointFeatures:
        return JointFeatures(self.values[:, cols], self.joint[cols], self.n)

    def dense(self, rows=slice(None)) -> np.ndarray:
        """The dense features (len(rows), n, e) of `rows` (a slice or indices)."""
        vals = self.values[rows]
        out = np.zeros((len(vals), self.n, vals.shape[1]))
        out[:, self.joint, np.arange(vals.shape[1])] = vals
        return out

    def lever_columns(self, lever: np.ndarray, out: np.ndarray) -> None:
        """out (N, 3, e) = lever (N, 3, n) @ Phi row by row (the Jacobian's columns of the parameters through the joint
        angles), Phi never dense: a parameter moves one joint, so its column is that joint's lever times its feature,
        the one non-zero term of the product's sum and so its value (a zero's sign aside), formed for each run of
        parameters on one joint (issue 41: the dense features and their product, a piece of rows at a time, were 3 %
        of a diagnosis of the UR10's Series B; these products take 60-70 % of their time)."""
        for sa, j in self._runs():
            np.multiply(lever[:, :, j, None], self.values[:, None, sa], out=out[:, :, sa])

    def _runs(self) -> list[tuple[slice, int]]:
        """(columns, joint) of each run of parameters on one joint."""
        bounds = np.flatnonzero(np.diff(self.joint, prepend=-1, append=-1) != 0)
        return [(slice(a, b), int(self.joint[a])) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]

    def gram(self, lever: np.ndarray) -> np.ndarray:
        """C^T C (e, e) of the columns C (3 N, e) `lever_columns(lever)` gives, never formed: two parameters' columns
        multiply, summed over a row's coordinates, to their features times the product of their joints' levers
        (a_r = lever_r^T lever_r, n x n), so C^T C is N e^2 multiply-adds where the dense product is 3 N e^2 (issue
        41: the joint error map's ~650 columns on Series B, summed again for every fold and fit)."""
        a = np.einsum("rci,rcj->rij", lever, lever)
        runs = self._runs()
        out = np.empty((len(self.joint), len(self.joint)))
        for i, (sa, ja) in enumerate(runs):
            va = self.values[:, sa]
            w = va * np.sqrt(a[:, ja, ja])[:, None]  # a_r[j, j] = |lever_j|^2: a product of a matrix with itself
            out[sa, sa] = w.T @ w
            for sb, jb in runs[i + 1 :]:  # a product per pair of runs (one for every later run took 1.3x as long)
                out[sa, sb] = (va * a[:, ja, jb, None]).T @ self.values[:, sb]
                out[sb, sa] = out[sa, sb].T
        return out

    def cross(self, lever: np.ndarray, other: np.ndarray) -> np.ndarray:
        """O^T C (o, e) of other columns O (N, 3, o) of the same rows with the columns C `lever_columns(lever)`
        gives, never formed (`gram`)."""
        b = np.einsum("rco,rcj->jor", other, lever)  # (n, o, N): each joint's lever against every other column
        out = np.empty((other.shape[2], len(self.joint)))
        for sa, ja in self._runs():
            out[:, sa] = b[ja] @ self.values[:, sa]
        return out

    def offsets(self, theta: np.ndarray) -> np.ndarray:
        """(N, n) joint offsets Phi theta (rad), or (N, n, k) for k sets of values theta (e, k): each run of parameters
        on one joint adds its features times their values to that joint's (issue 41: the dense features' product a
        piece of rows at a time was 6 % of a diagnosis of the UR10's Series B)."""
        out = np.zeros((len(self.values), self.n, *np.shape(theta)[1:]))
        for sa, j in self._runs():
            out[:, j] += self.values[:, sa] @ theta[sa]
        return out

    def moves(self) -> np.ndarray:
        """(n, e) bool: the joint each parameter moves where its features are not all zero."""
        out = np.zeros((self.n, len(self.joint)), dtype=bool)
        out[self.joint, np.arange(len(self.joint))] = np.abs(self.values).max(axis=0, initial=0.0) > 0
        return out


@dataclass
class Extension:
    cause: str
    names: list[str]
    units: list[str]  # boundary units
    to_boundary: np.ndarray  # internal value * to_boundary = boundary value
    joint_features: JointFeatures | None = None  # Phi (N, n, e): dq = Phi theta (rad); dense (N, n, e) taken too
    growth: np.ndarray | None = None  # (N, e): the arm grows by the fraction growth @ theta about `pivot`
    pivot: np.ndarray = field(default_factory=lambda: np.zeros(3))  # mm, robot base frame
    displacement: np.ndarray | None = None  # (N, 3, e): the reflector moves by displacement @ theta (mm, base frame)
    range_scale: np.ndarray | None = None  # (N, e): the row's station measures (1 + range_scale @ theta) x
    meta: dict = field(default_factory=dict)  # cyclic_error: "arcs" {joint: Arc}; combined: "parts"; "ranges": Ranges;
    # FORMS: {cause: form} (thermal_warmup's time constant, payload_compliance's payload)

    def __post_init__(self):
        if isinstance(self.joint_features, np.ndarray):  # the causes with a few parameters build them dense
            self.joint_features = JointFeatures.of(self.joint_features)

    @property
    def size(self) -> int:
        return len(self.names)

    @property
    def n_rows(self) -> int:
        return next(f.shape[0] for f in self._features() if f is not None)

    def _features(self) -> tuple:
        return self.joint_features, self.growth, self.displacement, self.range_scale

    def subset(self, rows: np.ndarray) -> Extension:
        gr, dp, rs = (None if f is None else f[rows] for f in self._features()[1:])
        jf = None if self.joint_features is None else self.joint_features.take(rows)
        return Extension(
            self.cause, self.names, self.units, self.to_boundary, jf, gr, self.pivot, dp, rs, dict(self.meta)
        )

    def joint_offsets(self, theta: np.ndarray) -> np.ndarray | None:
        if self.joint_features is None:
            return None
        return self.joint_features.offsets(theta)

    def growth_of(self, theta: np.ndarray) -> np.ndarray | None:
        """(N,) fractional growth of the arm, or None without growth features."""
        return None if self.growth is None else self.growth @ theta

    def displacement_of(self, theta: np.ndarray) -> np.ndarray | None:
        """(N, 3) displacement of the reflector (mm, robot base frame), or None without displacement features."""
        return None if self.displacement is None else np.einsum("rke,e->rk", self.displacement, theta)

    def range_of(self, theta: np.ndarray) -> np.ndarray | None:
        """(N,) fractional range scale of each row's station, or None without range features."""
        return None if self.range_scale is None else self.range_scale @ theta

    def parts(self) -> list[tuple[str, list[str]]]:
        """(cause, parameter names) of every extension combined into this one, in parameter order."""
        return self.meta.get("parts", [(self.cause, list(self.names))])


def combine(extensions: list[Extension], cause: str | None = None) -> Extension:
    """One extension carrying all of `extensions` (parameters in order); `cause` names the main one (default:
    the first's). Growth extensions must share their pivot."""
    if len(extensions) == 1 and cause in (None, extensions[0].cause):
        return extensions[0]
    rows = {x.n_rows for x in extensions}
    if len(rows) != 1:
        raise ExtensionError("extensions of tables with different rows cannot be combined")
    pivots = {tuple(x.pivot) for x in extensions if x.growth is not None}
    if len(pivots) > 1:
        raise ExtensionError("two growth extensions with different pivots cannot be combined")
    (n_rows,) = rows
    n = next((x.joint_features.shape[1] for x in extensions if x.joint_features is not None), 0)
    e = sum(x.size for x in extensions)
    jv, jj = (np.zeros((n_rows, e)), np.zeros(e, dtype=int)) if n else (None, None)
    gr = np.zeros((n_rows, e)) if pivots else None
    dp = np.zeros((n_rows, 3, e)) if any(x.displacement is not None for x in extensions) else None
    rs = np.zeros((n_rows, e)) if any(x.range_scale is not None for x in extensions) else None
    at = 0
    for x in extensions:
        cols = slice(at, at + x.size)
        if x.joint_features is not None:
            jv[:, cols], jj[cols] = x.joint_features.values, x.joint_features.joint
        if x.growth is not None:
            gr[:, cols] = x.growth
        if x.displacement is not None:
            dp[:, :, cols] = x.displacement
        if x.range_scale is not None:
            rs[:, cols] = x.range_scale
        at += x.size
    meta = {k: v for x in extensions for k, v in x.meta.items() if k not in ("parts", FORMS)}
    forms = {c: f for x in extensions for c, f in x.meta.get(FORMS, {}).items()}
    if forms:
        meta[FORMS] = forms
    meta["parts"] = [part for x in extensions for part in x.parts()]
    return Extension(
        cause or extensions[0].cause,
        [nm for x in extensions for nm in x.names],
        [u for x in extensions for u in x.units],
        np.concatenate([x.to_boundary for x in extensions]),
        None if jv is None else JointFeatures(jv, jj, n),
        gr,
        np.array(pivots.pop()) if pivots else np.zeros(3),
        dp,
        rs,
        meta,
    )


def select_columns(features: np.ndarray, names: list[str], wanted: list[str] | None, rel_tol: float = 1e-6):
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
