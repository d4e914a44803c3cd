"""Off-line error compensation (paper section 3, step 5): joint targets corrected for the identified model.

For every nominal joint target q_nom the nominal model (nominal chain, all deviations zero) says where the
programmer meant the tool to be: the TCP and the orientation of the last joint frame. The identified model
(the deviations of model.json, plus a joint-type extension q_true = q_cmd + Phi(q_cmd) theta when it has
one) puts the tool elsewhere at q_nom. `compensate` finds the commanded angles q_c with which the
identified model reaches the intended pose:

    g_id(q_c + Phi(q_c) theta, x_k) = g_nom(q_nom, x_k)   for three points x_k rigidly attached to the tool

x_0 the TCP, x_1 and x_2 the TCP offset by `lever_mm` along the x and y axes of the last joint frame: three
non-collinear points fix position and orientation (9 equations). Gauss-Newton on these points with the
analytic joint Jacobians of `calib.model.kinematics` (times dq_true/dq_cmd for an extension) converges
quadratically; the corrections are small (deviations of tenths of a mm), so two to four iterations reach
rounding level.

Extensions with a static compensation: joint_compliance (the gravity torque at the commanded pose), payload_compliance
(the gravity torque at the commanded pose with the payload the fitted campaign ended with: model.json's
extension.forms),
encoder_scale, cyclic_error (the joint error map; outside the angles it was fitted over it keeps its value
at the nearest fitted angle, and the report warns: `CompensationReport.warnings`). backlash depends on the
approach direction and thermal_drift on time: no static correction exists for them; they are ignored and
reported in `CompensationReport.ignored`.
thermal_warmup is compensated for the warm robot: its growth saturates at e_inf (within a few time constants of
power-on: the robot in production), a uniform scale about its pivot, so the identified model reaches the intended
TCP when its own (unscaled) TCP reaches it scaled by 1 / (1 + e_inf) about the pivot (the three tool points moved
with it, rigidly); the orientation is unchanged by a uniform scale. A note says so (a cold robot is off by up to
that growth).
wrist_coupling (the wrist's coupling ratios, a joint error linear in the driving axis) is static: corrected.
station_shift, range_scale (a station's air data) and nest_sag (a reflector nest sagging in its seat) are matters of
the measurement, not of the robot: the TCP is where the geometric model puts it, and they leave the compensation
geometric (a note says so).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from trackcal.calib.diagnose.extensions import build_parts, warmup_pivot
from trackcal.calib.errors import CalibError
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import MAX_CORRECTION_DEG, MAX_CORRECTION_MM
from trackcal.calib.model.inverse import reach_points
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model_file import Model

STATIC_JOINT_CAUSES = ("joint_compliance", "encoder_scale", "cyclic_error", "payload_compliance", "wrist_coupling")
WARM_GROWTH = "thermal_warmup"  # compensated at its saturated growth (`warm_growth`)
NO_STATIC_COMPENSATION = {
    "backlash": "backlash depends on the direction each joint approaches the target from; it has no static "
    "compensation and is ignored (approach every target from the same side to make it repeatable)",
    "thermal_drift": "thermal drift depends on the time since the campaign start; it has no static compensation "
    "and is ignored (compensate a warm robot, or re-measure)",
}
GEOMETRIC_ONLY = {
    "station_shift": "station_shift concerns a tracker station, not the robot: the compensation is geometric",
    "range_scale": "range_scale concerns a tracker station's air data (its distances), not the robot: nothing of it "
    "to compensate",
    "nest_sag": "nest_sag concerns the reflector's nest on the measurement tool, not the robot's TCP: nothing of it "
    "to compensate",
}
# below this conditioning a pose is close to a singularity: small Cartesian errors need large joint corrections
# (on the KR-270 ~1e-3 is where corrections of Table 8 size deviations exceed one degree)
NEAR_SINGULAR = 2e-3
FD_STEP_RAD = 1e-6  # central differences of the extension's joint offsets (smooth in q)

OUTSIDE_RANGES = "outside the joint ranges the model's extension was fitted on"


class CompensationError(CalibError):
    """A request that cannot be compensated at all (shapes, TCP, lever); the message says why."""


@dataclass
class CompensationReport:
    position_error_mm: np.ndarray  # (N,) TCP distance between the identified model at q_c and the intended pose
    orientation_error_deg: np.ndarray  # (N,) angle between the identified and the intended last-frame orientation
    iterations: np.ndarray  # (N,) Gauss-Newton iterations to convergence
    correction_rad: np.ndarray  # (N, n) q_c - q_nom
    uncompensated_position_mm: np.ndarray  # (N,) TCP error of the identified model at q_nom (what is corrected)
    uncompensated_orientation_deg: np.ndarray  # (N,)
    conditioning: np.ndarray  # (N,) smallest / largest singular value of the 9 x n tool-point Jacobian at q_c
    cause: str  # the model's extension (its main cause), "none" if purely geometric
    failures: list[str]  # (N,) why a target could not be compensated, "" when it was (its angles are then valid)
    ignored: list[str] = field(default_factory=list)  # effects without a static compensation (warnings)
    warnings: list[str] = field(default_factory=list)  # e.g. targets outside the joint error map's fitted range
    notes: list[str] = field(default_factory=list)
    tcp_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    lever_mm: float = 100.0
    causes: list[str] = field(default_factory=list)  # every cause the model carries, the main one first

    def to_doc(self) -> dict:
        """Summary in boundary units (mm, deg), over the targets that were compensated."""
        ok = self.ok
        return {
            "cause": self.cause,
            "causes": list(self.causes),
            "ignored": list(self.ignored),
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "tcp_mm": self.tcp_mm.tolist(),
            "targets": len(self.iterations),
            "compensated": int(np.sum(ok)),
            "max_position_error_mm": float(self.position_error_mm[ok].max(initial=0.0)),
            "max_orientation_error_deg": float(self.orientation_error_deg[ok].max(initial=0.0)),
            "max_iterations": int(self.iterations[ok].max(initial=0)),
            "max_correction_deg": float(np.degrees(np.abs(self.correction_rad[ok])).max(initial=0.0)),
            "max_uncompensated_position_mm": float(self.uncompensated_position_mm.max(initial=0.0)),
            "near_singular_targets": int(np.sum(ok & (self.conditioning < NEAR_SINGULAR))),
        }

    @property
    def ok(self) -> np.ndarray:
        """(N,) True for the targets that were compensated."""
        return np.array([not f for f in self.failures], dtype=bool)


def rotation_angle(ra: np.ndarray, rb: np.ndarray) -> np.ndarray:
    """(N,) angle (rad) of ra^T rb, accurate near zero (atan2 of the skew and symmetric parts)."""
    r = np.einsum("nji,njk->nik", ra, rb)
    s = 0.5 * np.linalg.norm(
        np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1), axis=1
    )
    c = 0.5 * (np.trace(r, axis1=1, axis2=2) - 1.0)
    return np.arctan2(s, c)


def joint_error_function(model: Model) -> tuple[Callable[[np.ndarray], np.ndarray] | None, list[str], list[str]]:
    """(offsets(q_cmd) -> (N, n) rad or None, ignored warnings, notes) for the model's extension.

    The offsets are computed by `Model.extension_for` from the causes with a static compensation, the same
    features identification and `predict` use, so the compensated targets agree with the model exactly."""
    cause = model.cause
    if cause in ("none", "unexplained"):
        return None, [], []
    if cause in GEOMETRIC_ONLY and not model.parts():
        return None, [], [GEOMETRIC_ONLY[cause]]
    parts = model.parts()
    unknown = [
        c for c, _ in parts if c not in (*STATIC_JOINT_CAUSES, WARM_GROWTH, *NO_STATIC_COMPENSATION, *GEOMETRIC_ONLY)
    ]
    if unknown:
        raise CompensationError(f"model extension {unknown[0]!r} is unknown; cannot compensate it")
    ignored = [NO_STATIC_COMPENSATION[c] for c, _ in parts if c in NO_STATIC_COMPENSATION]
    g, _ = warm_growth(model)
    notes = (
        [
            f"thermal_warmup: compensated for the warm robot (its growth saturated at {1e6 * g:+.3g} ppm, reached "
            f"within a few of its time constant of {model.forms()[WARM_GROWTH]['tau_s'] / 60:.3g} min after "
            "power-on); a cold robot is off by up to that growth"
        ]
        if g
        else []
    )
    notes += [GEOMETRIC_ONLY[c] for c, _ in parts if c in GEOMETRIC_ONLY]
    names, theta = model.extension_values()
    static = [(c, n) for c, n in parts if c in STATIC_JOINT_CAUSES]
    if not static:
        return None, ignored, notes
    keep = np.array([names.index(nm) for _, n in static for nm in n], dtype=int)
    chain, arcs, forms = model.chain, model.arcs(), model.forms()

    def offsets(q: np.ndarray) -> np.ndarray:
        n_rows = len(q)
        rows = MeasurementTable(
            seq=np.arange(n_rows),
            t_s=np.zeros(n_rows),
            pose=["c"] * n_rows,
            station=["-"] * n_rows,
            point=["-"] * n_rows,
            q_deg=np.degrees(q),
            xyz=None,
            source="compensation targets",
        )
        return build_parts(static, chain, rows, arcs, forms=forms).joint_offsets(theta[keep])

    return offsets, ignored, notes


def warm_growth(model: Model) -> tuple[float, np.ndarray]:
    """(g, pivot mm): the fractional growth of the warm robot (thermal_warmup's e_inf, the saturated warm-up) and the
    point it keeps fixed; (0, 0) without a warm-up."""
    for cause, names in model.parts():
        if cause == WARM_GROWTH:
            all_names, theta = model.extension_values()
            return float(theta[all_names.index(names[0])]), warmup_pivot(model.chain, names[0])
    return 0.0, np.zeros(3)


def _true_joints(offsets, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q_true (N, n) and dq_true/dq_cmd (N, n, n)."""
    n_rows, n = q.shape
    eye = np.broadcast_to(np.eye(n), (n_rows, n, n))
    if offsets is None:
        return q, eye
    # one batched call: the rows, then each joint stepped up and down
    steps = FD_STEP_RAD * np.eye(n)
    stacked = np.concatenate([q, *(q + s for s in steps), *(q - s for s in steps)])
    off = offsets(stacked).reshape(2 * n + 1, n_rows, n)
    deriv = (off[1 : n + 1] - off[n + 1 :]) / (2.0 * FD_STEP_RAD)  # (n_step, N, n_out)
    return q + off[0], eye + np.transpose(deriv, (1, 2, 0))


def _limit_violations(q: np.ndarray, limits: np.ndarray, joint_names: list[str]) -> list[str]:
    """(N,) the joints of each row outside the limits, "" for a row inside them."""
    out = [""] * len(q)
    for i, j in zip(*np.nonzero((q < limits[:, 0]) | (q > limits[:, 1])), strict=True):
        lo, hi = np.degrees(limits[j])
        out[i] += ("; " if out[i] else "") + f"{joint_names[j]} = {np.degrees(q[i, j]):.4f} deg not in [{lo:g}, {hi:g}]"
    return out


def _bound_corrections(
    failures: list[str], dq: np.ndarray, tcp_mm: np.ndarray, bound: tuple[float, float], joint_names: list[str]
) -> None:
    """Mark (in `failures`) every target not yet failed whose joint correction dq (N, n) rad or TCP correction
    tcp_mm (N,) exceeds `bound` (mm, deg)."""
    mm, deg = bound
    for i in range(len(failures)):
        if failures[i]:
            continue
        d = np.degrees(np.abs(dq[i]))
        j = int(np.argmax(d))
        if d[j] > deg:
            failures[i] = (
                f"its correction of {joint_names[j]}, {np.degrees(dq[i, j]):+.4f} deg, exceeds the cell's "
                f"max_correction of {deg:g} deg: not written (a singular pose or a model far from the "
                "robot: check it)"
            )
        elif tcp_mm[i] > mm:
            failures[i] = (
                f"the model moves its TCP by {tcp_mm[i]:.3f} mm, more than the cell's max_correction of "
                f"{mm:g} mm: not written (a model far from the robot: check it)"
            )


def pose_error(
    model: Model, q_cmd: np.ndarray, q_nominal: np.ndarray, tcp_mm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(N,) TCP distance (mm) and (N,) orientation angle (deg) between the identified model commanded to q_cmd
    (extension honoured) and the nominal model at q_nominal: e.g. the cost of rounding compensated targets."""
    q_cmd, q_nominal = np.atleast_2d(q_cmd), np.atleast_2d(q_nominal)
    offsets, _, _ = joint_error_function(model)
    kin = Kinematics(model.chain, model.params)
    qt, _ = _true_joints(offsets, q_cmd)
    r_id, o_id = kin.end_frames(qt, model.dev)
    r_nom, o_nom = kin.end_frames(q_nominal)
    tcp = np.asarray(tcp_mm, dtype=float)
    g, pivot = warm_growth(model)
    d = (pivot + (1.0 + g) * (o_id + r_id @ tcp - pivot)) - (o_nom + r_nom @ tcp)
    return np.linalg.norm(d, axis=1), np.degrees(rotation_angle(r_nom, r_id))


def _checked_request(chain, q_nominal_rad, tcp_mm, lever_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(q0 (N, n) rad, tcp (3,) mm) of a compensation request, or CompensationError for one that cannot be run."""
    n = chain.dof
    q0 = np.atleast_2d(np.asarray(q_nominal_rad, dtype=float))
    if q0.ndim != 2 or q0.shape[1] != n:
        raise CompensationError(f"expected joint targets with {n} angles per row, got shape {q0.shape}")
    if not np.all(np.isfinite(q0)):
        raise CompensationError("joint targets must be finite numbers")
    tcp = np.asarray(tcp_mm, dtype=float)
    if tcp.shape != (3,) or not np.all(np.isfinite(tcp)):
        raise CompensationError(f"the TCP must be 3 finite coordinates (mm), got {tcp_mm!r}")
    if not lever_mm > 0:
        raise CompensationError("lever_mm must be positive")
    return q0, tcp


def _refuse_outside(model: Model, q0: np.ndarray, joint_names: list[str], failures: list[str]) -> None:
    """Marks in `failures` the targets outside the joint ranges the model's extension was fitted on."""
    ranges = model.ranges()
    if ranges is None:
        return
    out = ranges.outside(q0)
    for i in np.flatnonzero(out.any(axis=1)):
        joints = "; ".join(
            f"{joint_names[j]} = {np.degrees(q0[i, j]):.4f} deg not in [{np.degrees(lo):.4f}, {np.degrees(hi):.4f}]"
            for j, (lo, hi) in enumerate(ranges.joints_rad)
            if out[i, j]
        )
        failures[i] = failures[i] or (
            f"{OUTSIDE_RANGES}: {joints} (compensating it must be asked for: the "
            "extension is then held at the nearest fitted angle)"
        )


def compensate(
    model: Model,
    q_nominal_rad: np.ndarray,
    tcp_mm: np.ndarray,
    lever_mm: float = 100.0,
    tol_mm: float = 1e-10,
    max_iter: int = 20,
    max_correction: tuple[float, float] = (MAX_CORRECTION_MM, MAX_CORRECTION_DEG),
    allow_outside: bool = False,
) -> tuple[np.ndarray, CompensationReport]:
    """Joint targets (N, n) rad with which `model` reaches the pose the nominal model reaches at q_nominal.

    Converged when each of the three tool points is within `tol_mm` of its intended position. Each target is
    compensated on its own: one outside the joint limits, one whose compensated angles leave them, and one that
    does not converge (a singular pose such as the KUKA HOME with A5 = 0, a chain that cannot reach the pose) keeps
    its nominal angles and its reason in `report.failures`; the others are compensated. So does one whose correction
    exceeds `max_correction` (mm of TCP displacement the model asks to correct, deg of any joint's correction; the
    cell's `max_correction`, calib.model.cell): it is never written. CompensationError only for a request that cannot
    be run at all (shapes, TCP, lever). A target outside the joint ranges the model's extension
    was fitted on (`Model.outside`) is refused likewise unless `allow_outside` (it is then compensated with the
    extension held at the nearest fitted angle, and the report warns)."""
    chain = model.chain
    n = chain.dof
    q0, tcp = _checked_request(chain, q_nominal_rad, tcp_mm, lever_mm)
    n_rows = len(q0)
    limits = chain.limits_array()
    joint_names = [j.name for j in chain.joints]
    failures = [
        f"nominal target outside the joint limits: {v}" if v else "" for v in _limit_violations(q0, limits, joint_names)
    ]
    offsets, ignored, notes = joint_error_function(model)
    if offsets is not None and not allow_outside:  # the extension is known only where it was fitted
        _refuse_outside(model, q0, joint_names, failures)

    tools = tcp + np.array([[0.0, 0.0, 0.0], [lever_mm, 0.0, 0.0], [0.0, lever_mm, 0.0]])  # last joint frame
    tool_rows = np.tile(tools, (n_rows, 1))
    kin = Kinematics(chain, model.params)
    target = kin.points(np.repeat(q0, 3, axis=0), tool_rows).reshape(n_rows, 3, 3)
    g, pivot = warm_growth(model)  # the warm robot's TCP grows by 1 + g about the pivot: aim it short (orientation:
    target = target - (g / (1.0 + g)) * (target[:, :1] - pivot)  # unchanged by a uniform scale; tool points rigid)

    outside = np.array([bool(f) for f in failures])  # targets outside the limits are not iterated
    true_joints = None if offsets is None else partial(_true_joints, offsets)
    q, iterations, converged = reach_points(kin, tools, target, q0, model.dev, true_joints, tol_mm, max_iter, outside)
    for i in np.flatnonzero(~converged & ~outside):
        failures[i] = (
            f"did not converge in {max_iter} iterations: a singular pose or a chain that cannot reach the "
            "intended pose (move the target away from the singularity)"
        )
    for i, v in enumerate(_limit_violations(q, limits, joint_names)):
        if v and not failures[i]:
            failures[i] = f"the compensated target leaves the joint limits: {v}"
    pos_err0, ori_err0 = pose_error(model, q0, q0, tcp)
    _bound_corrections(failures, q - q0, pos_err0, max_correction, joint_names)
    failed = np.array([bool(f) for f in failures])
    q[failed] = q0[failed]

    pos_err, ori_err = pose_error(model, q, q0, tcp)
    qt, dqt = _true_joints(offsets, q)
    d_q = kin.jacobian(np.repeat(qt, 3, axis=0), tool_rows, model.dev).d_q.reshape(n_rows, 9, n)
    jq = np.einsum("nij,njk->nik", d_q, dqt)
    sv = np.linalg.svd(jq, compute_uv=False)
    report = CompensationReport(
        position_error_mm=pos_err,
        orientation_error_deg=ori_err,
        iterations=iterations,
        correction_rad=q - q0,
        uncompensated_position_mm=pos_err0,
        uncompensated_orientation_deg=ori_err0,
        conditioning=sv[:, -1] / sv[:, 0],
        cause=model.cause,
        causes=model.causes,
        failures=failures,
        ignored=ignored,
        warnings=[w for w in [model.range_warning(q)] if w],  # the map is evaluated at the commanded angles
        notes=notes,
        tcp_mm=tcp,
        lever_mm=float(lever_mm),
    )
    return q, report
