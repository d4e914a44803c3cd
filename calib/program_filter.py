"""Program filtering: a robot program's targets corrected for the calibrated robot, each with its predicted accuracy.

A Cartesian target is the pose P of the TCP in a user frame B with a tool T (4 x 4, mm): the programmer means the
flange pose F = B P T^-1 in the robot's base frame. The controller still runs its NOMINAL kinematics, so the filtered
target P' is the pose that, sent through the nominal inverse kinematics, makes the CALIBRATED robot reach F:

    q_nom = IK_nominal(F) in the target's configuration (`accepts`), the solution nearest the previous target's
    q_cal = the joints with which the calibrated model reaches F (calib.compensate.compensate from q_nom: the model's
            deviations and the static part of its extension, its refusals: limits, fitted ranges, max_correction)
    P'    = B^-1 FK_nominal(q_cal) T

The nominal IK is a multi-start Gauss-Newton on three points rigidly attached to the flange (calib.model.inverse
`reach_points`, the flange's origin and two points `LEVER_MM` along its x and y axes: position and orientation);
a start converges to one of the arm's solutions, the distinct ones are kept and the configuration's filter and the
nearest-to-previous rule choose (the controller's own rule where the language carries no configuration). A joint
target is corrected in joint space (`compensate`), the same way.

The base and tool frames are the controller's (read from the program): the calibration's tracker stations and
measurement tool do not enter; the deviations of the last link that the campaign merged into its tool points stay in
the controller's tool data.

The predicted accuracy of a target is the model's uncertainty at its TCP: the covariance of the model's parameters
(model.json's `covariance`) propagated through the TCP's parameter Jacobian at q_cal (first order, as
calib.tcp_figure does at the test pose), its 95 % radius the 0.95 quantile of the distance |x|, x ~ N(0, cov)
(from a table over the covariance's eigenvalue ratios, made once on a fixed scrambled Sobol sample of the normal:
deterministic). A target kept as it was carries the
model's predicted error there (the error the calibration found and could not correct) plus that radius. The
extension's statically compensated parameters enter with their covariance and their covariance with the geometric
ones (model.json's `extension_covariance`, calib.extension_uncertainty; a model written before it was recorded: the
geometric parameters' alone). A target outside the joint ranges the model's extension was fitted on
(`Model.outside`) is flagged.

The bound holds where the model was measured. Outside the space model.json records (calib.measured_space: the table's
joint ranges, the reflectors' radius and height about the base's axis) the parameters are extrapolated and what the
model does not model is not in its covariance: each target's distance outside is stated (`outside_joints_deg`,
`outside_volume_mm`, NaN when the model does not record its space) and such a target is `extrapolated`: its bound is
not covered, and the filter's report calls its pass/fail unknown, never a pass.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.special import ndtri
from scipy.stats import qmc

from trackcal.calib.compensate import NEAR_SINGULAR, compensate, rotation_angle
from trackcal.calib.errors import CalibError
from trackcal.calib.extension_uncertainty import ExtensionCovarianceError, extension_covariance, joint_features
from trackcal.calib.lack_of_fit import lack_of_fit_radius95, lack_of_fit_variance
from trackcal.calib.model.cell import MAX_CORRECTION_DEG, MAX_CORRECTION_MM
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.inverse import reach_points
from trackcal.calib.model.kinematics import Kinematics
from trackcal.calib.model_file import Model

LEVER_MM = 100.0  # the flange points' offset along its x and y axes (as calib.compensate's lever)
IK_TOL_MM = 1e-8  # each of the three flange points within this of its target: the pose to ~1e-10 rad
IK_STARTS = 24  # random starts of the nominal IK besides the reference (a 6R arm has up to 8 solutions at a pose)
IK_ITER = 40
RETRY_STARTS = 8 * IK_STARTS  # a target none of whose solutions is accepted: its IK again with these
SAME_SOLUTION_RAD = 1e-4  # two converged starts within this on every joint (modulo a turn) are one solution
SOBOL_POINTS = 2**16  # the normal sample of the 95 % radius's table (its quantile to ~1e-3 relative)
RATIO_GRID = 20  # the table's steps in each eigenvalue ratio (the quantile is smooth in them)
COVERAGE = 0.95
CHUNK = 500  # targets per batch of the nominal IK (memory: CHUNK x (IK_STARTS + 1) x 3 rows)


# a declared target no move of the given files uses: the tool and base it is used with are not known (a reader gives
# it the language's default frames), so correcting it could move it the wrong way
UNUSED = (
    "no move in the given files uses it: the tool and base frame it runs with are not known (give the files "
    "that use it)"
)


class FilterError(CalibError):
    """A request that cannot be filtered at all (shapes, frames); the message says why."""


class Target(Protocol):
    """What the filter needs of a program's target (drivers.program_text.ProgramTarget has it)."""

    joint: bool  # joint values (deg) or a Cartesian pose (4 x 4 mm of the TCP in `base`)
    value: np.ndarray
    base: np.ndarray  # 4 x 4 user frame in the robot's base frame, mm
    tool: np.ndarray  # 4 x 4 TCP in the flange (the chain's last joint frame), mm
    motion: str  # the moves that use it; "" when none of the given files' moves does

    def accepts(self, q_deg: np.ndarray) -> bool: ...


@dataclass
class FilterResult:
    """Per target (the program's order): what the filter found, in boundary units (mm, deg)."""

    values: list[np.ndarray | None]  # the corrected value (joint deg / 4 x 4 pose mm) or None: kept as it was
    why: list[str]  # "" when corrected, else why it was kept
    q_nominal_deg: np.ndarray  # (N, n) the nominal joints (NaN when the nominal IK found none)
    q_calibrated_deg: np.ndarray  # (N, n) the commanded joints for the calibrated robot (NaN when kept)
    correction_mm: np.ndarray  # (N,) how far the filter moves the TCP (the nominal robot's, q_nom -> q_cal)
    correction_deg: np.ndarray  # (N,) and turns the tool
    predicted_mm: np.ndarray  # (N,) the model's error of the target as written (~0 when corrected), NaN unknown
    sigma_mm: np.ndarray  # (N,) 1-sigma 3-D uncertainty of the model's TCP there (sqrt of the trace)
    bound95_mm: np.ndarray  # (N,) predicted_mm + the 95 % radius of the model's uncertainty; NaN unknown
    outside: np.ndarray  # (N,) bool: outside the joint ranges the model's extension was fitted on
    warnings: list[str]  # the compensation's (e.g. fitted ranges) and the model's ignored effects
    # how far outside the space the model was measured in (calib.measured_space), NaN unknown (a model that does not
    # record it; the joints of a target the nominal IK found none for): per joint (N, n) deg, and the TCP (N,) mm
    outside_joints_deg: np.ndarray
    outside_volume_mm: np.ndarray
    # the model's lack of fit (calib.lack_of_fit): the RMS per coordinate of its error beyond the noise floor, in every
    # target's sigma and bound; NaN: the model does not record its residual and noise floor (not in the bound)
    lack_of_fit_mm: float = float("nan")

    @property
    def ok(self) -> np.ndarray:
        return np.array([not w for w in self.why], dtype=bool)

    @property
    def extrapolated(self) -> np.ndarray:
        """(N,) bool: known to lie outside the measured joint ranges or volume: its bound is not covered."""
        joints = np.nan_to_num(self.outside_joints_deg, nan=0.0).max(axis=1, initial=0.0)
        return (joints > 0.0) | (np.nan_to_num(self.outside_volume_mm, nan=0.0) > 0.0)

    @property
    def space_known(self) -> np.ndarray:
        """(N,) bool: whether the target's place against the measured space is known (see `extrapolated`)."""
        return ~np.isnan(self.outside_volume_mm) & ~np.isnan(self.outside_joints_deg).any(axis=1)


def homogeneous(r: np.ndarray, o: np.ndarray) -> np.ndarray:
    """(N, 4, 4) transforms of rotations (N, 3, 3) and origins (N, 3)."""
    out = np.zeros((len(r), 4, 4))
    out[:, :3, :3], out[:, :3, 3], out[:, 3, 3] = r, o, 1.0
    return out


def flange_poses(kin: Kinematics, q: np.ndarray, dev: np.ndarray | None = None) -> np.ndarray:
    """(N, 4, 4) the last joint frame (the flange) at joints q (N, n) rad."""
    r, o = kin.end_frames(np.atleast_2d(q), dev)
    return homogeneous(r, o)


def flange_points(flange: np.ndarray) -> np.ndarray:
    """(N, 3, 3) the three flange points (origin, LEVER_MM along x and y) of flange poses (N, 4, 4)."""
    local = np.array([[0.0, 0.0, 0.0], [LEVER_MM, 0.0, 0.0], [0.0, LEVER_MM, 0.0]])
    return flange[:, None, :3, 3] + np.einsum("nij,kj->nki", flange[:, :3, :3], local)


def _wrap(q: np.ndarray) -> np.ndarray:
    return (q + np.pi) % (2.0 * np.pi) - np.pi


def ik_candidates(chain: Chain, flange: np.ndarray, starts: int = IK_STARTS, seed: int = 0) -> list[np.ndarray]:
    """Per flange pose (N, 4, 4) the distinct solutions (k, n) rad in (-pi, pi] of the nominal chain's IK (none:
    (0, n)); `starts` random starts (seeded) and the zero pose per target, converged to IK_TOL_MM."""
    n = chain.dof
    lim = np.clip(chain.limits_array(), -np.pi, np.pi)
    rng = np.random.default_rng(seed)
    kin = Kinematics(chain, [])
    tools = np.array([[0.0, 0.0, 0.0], [LEVER_MM, 0.0, 0.0], [0.0, LEVER_MM, 0.0]])
    out: list[np.ndarray] = []
    for lo in range(0, len(flange), CHUNK):
        part = flange[lo : lo + CHUNK]
        m, k = len(part), starts + 1
        q0 = np.concatenate([np.zeros((m, 1, n)), rng.uniform(lim[:, 0], lim[:, 1], (m, starts, n))], axis=1)
        target = np.repeat(flange_points(part), k, axis=0)
        q, _, conv = reach_points(kin, tools, target, q0.reshape(m * k, n), None, None, IK_TOL_MM, IK_ITER)
        q, conv = _wrap(q).reshape(m, k, n), conv.reshape(m, k)
        for i in range(m):
            sols = q[i][conv[i]]
            keys = np.round(sols / SAME_SOLUTION_RAD).astype(np.int64)
            _, first = np.unique(keys, axis=0, return_index=True)
            out.append(sols[np.sort(first)])
    return out


def nearest_solution(candidates: np.ndarray, limits: np.ndarray, reference: np.ndarray, accepts) -> np.ndarray | None:
    """The solution (n,) rad nearest `reference` among `candidates` (k, n) in (-pi, pi], each joint taken at any
    whole turn that stays in its limits, that `accepts(q_deg)`; None when none does."""
    options = []
    for c in candidates:
        turns = [
            [v + 2.0 * np.pi * t for t in (-2, -1, 0, 1, 2) if lo <= v + 2.0 * np.pi * t <= hi]
            for v, (lo, hi) in zip(c, limits, strict=True)
        ]
        options.append(np.array(list(itertools.product(*turns))).reshape(-1, len(c)))
    every = np.concatenate(options) if options else np.zeros((0, len(reference)))
    for i in np.argsort(np.sum((every - reference) ** 2, axis=1), kind="stable"):
        if accepts(np.degrees(every[i])):
            return every[i]
    return None


def sobol_normal(points: int = SOBOL_POINTS) -> np.ndarray:
    """(points, 3) a fixed standard normal sample (scrambled Sobol, seed 0, through the normal quantile)."""
    u = qmc.Sobol(3, scramble=True, seed=0).random(points)
    return ndtri(np.clip(u, 1e-12, 1.0 - 1e-12))


@functools.lru_cache(maxsize=1)
def _quantile_table() -> RegularGridInterpolator:
    """(a, b) -> the 0.95 quantile of z1^2 + a z2^2 + b z3^2 (z standard normal), a, b in [0, 1] on a grid of
    RATIO_GRID steps: |x|^2 of x ~ N(0, cov) is lam1 (that) with a, b the eigenvalues' ratios to the largest."""
    z2 = sobol_normal() ** 2
    grid = np.linspace(0.0, 1.0, RATIO_GRID + 1)
    table = np.array([np.quantile(z2[:, 0] + a * z2[:, 1] + grid[:, None] * z2[:, 2], COVERAGE, axis=1) for a in grid])
    return RegularGridInterpolator((grid, grid), table)


def radius95(cov: np.ndarray) -> np.ndarray:
    """(N,) the radius r with P(|x| <= r) = 0.95 for x ~ N(0, cov), cov (N, 3, 3) mm^2."""
    lam = np.clip(np.linalg.eigvalsh(cov), 0.0, None)[:, ::-1]  # descending; |x|^2 = sum lam_i z_i^2
    top = lam[:, 0]
    ratios = np.divide(lam[:, 1:], top[:, None], out=np.zeros((len(lam), 2)), where=top[:, None] > 0)
    return np.sqrt(top * _quantile_table()(np.clip(ratios, 0.0, 1.0))) if len(lam) else np.zeros(0)


def _param_rows(model: Model) -> tuple[list[int | None], np.ndarray]:
    """(each of model.params' row in covariance_order, None when absent; its boundary -> internal factor)."""
    idx = {name: i for i, name in enumerate(model.doc.get("covariance_order") or [])}
    return (
        [idx.get(p.name) for p in model.params],
        np.array([1.0 if p.is_length else np.pi / 180.0 for p in model.params]),
    )


def model_covariance(model: Model) -> np.ndarray:
    """(k + e, k + e) the covariance of model.params (mm, rad) from model.json's (mm, deg; zeros without one), then of
    its extension's statically compensated parameters with them (calib.extension_uncertainty; e = 0 without)."""
    k = len(model.params)
    sel, scale = _param_rows(model)
    cov = model.doc.get("covariance")
    out = np.zeros((k, k))
    if cov is not None and model.doc.get("covariance_order") is not None:
        have = [i for i, s in enumerate(sel) if s is not None]
        src = np.asarray(cov, dtype=float)[np.ix_([sel[i] for i in have], [sel[i] for i in have])]
        out[np.ix_(have, have)] = src
        out *= np.outer(scale, scale)
    try:
        ext = extension_covariance(model, scale, sel)
    except ExtensionCovarianceError as exc:
        raise FilterError(f"the model's {exc}") from None
    if ext is None:
        return out
    c_ee, c_pe = ext
    return np.block([[out, c_pe], [c_pe.T, c_ee]])


def tcp_covariance(model: Model, q: np.ndarray, tcp: np.ndarray) -> np.ndarray:
    """(N, 3, 3) mm^2: the covariance of the model's TCP `tcp` (N, 3; last joint frame) at joints q (N, n) rad,
    propagated from the parameters' covariance through the TCP's parameter Jacobian, and from the extension's through
    its joint Jacobian times the extension's joint features (calib.extension_uncertainty)."""
    if len(q) == 0:
        return np.zeros((0, 3, 3))
    cov = model_covariance(model)
    jac = Kinematics(model.chain, model.params).jacobian(q, tcp, model.dev)
    full = jac.d_params
    if len(cov) > full.shape[2]:
        full = np.concatenate([full, np.einsum("nij,nje->nie", jac.d_q, joint_features(model, q))], axis=2)
    return np.einsum("nik,kl,njl->nij", full, cov, full)


def _checked(targets: list[Target], n: int) -> None:
    for i, t in enumerate(targets):
        v = np.asarray(t.value, dtype=float)
        shape = (n,) if t.joint else (4, 4)
        if v.shape != shape or not np.all(np.isfinite(v)):
            raise FilterError(f"target {i + 1}: expected {shape} finite values, got shape {v.shape}")
        for what, m in (("base", t.base), ("tool", t.tool)):
            m = np.asarray(m, dtype=float)
            if m.shape != (4, 4) or not np.all(np.isfinite(m)):
                raise FilterError(f"target {i + 1}: its {what} frame is not a finite 4 x 4 transform")


def nominal_joints(
    chain: Chain, targets: list[Target], reference_deg, starts: int = IK_STARTS, seed: int = 0
) -> tuple[np.ndarray, list[str]]:
    """((N, n) rad, why): each target's joints on the nominal chain, NaN with the reason where there are none. A joint
    target is its own; a Cartesian one is the nominal IK's solution in its configuration nearest the previous
    target's joints (the first: `reference_deg`), the controller's rule."""
    n = chain.dof
    limits = chain.limits_array()
    cart = [i for i, t in enumerate(targets) if not t.joint]
    flanges = np.array([targets[i].base @ targets[i].value @ np.linalg.inv(targets[i].tool) for i in cart])
    cands = dict(zip(cart, ik_candidates(chain, flanges.reshape(-1, 4, 4), starts, seed), strict=True))
    q_nom, why = np.full((len(targets), n), np.nan), [""] * len(targets)
    ref = np.radians(np.asarray(reference_deg, dtype=float))
    for i, t in enumerate(targets):
        if not t.motion:
            why[i] = UNUSED
            continue
        if t.joint:
            q_nom[i] = ref = np.radians(np.asarray(t.value, dtype=float))
            continue
        if len(cands[i]) == 0:
            why[i] = "unreachable: the nominal kinematics has no solution for it (outside the workspace)"
            continue
        q = nearest_solution(cands[i], limits, ref, t.accepts)
        if q is None:  # random starts may miss a branch: once more with many (only for these, so cheap overall)
            cands[i] = ik_candidates(chain, flanges[cart.index(i)][None], RETRY_STARTS, seed + 1 + i)[0]
            q = nearest_solution(cands[i], limits, ref, t.accepts)
        if q is None:
            why[i] = (
                f"none of the nominal kinematics' {len(cands[i])} solutions is in the target's configuration "
                "within the joint limits"
            )
            continue
        q_nom[i] = ref = q
    return q_nom, why


def _compensated(
    model: Model, q_nom: np.ndarray, tcps: np.ndarray, why: list[str], max_correction, allow_outside: bool
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(q_cal (N, n) rad, NaN where kept; the model's TCP error of each target as it will be written (mm, NaN where
    unknown); warnings), compensating by groups of the same TCP; `why` gets the refusals."""
    q_cal, predicted, warnings = np.full_like(q_nom, np.nan), np.full(len(q_nom), np.nan), []
    found = ~np.isnan(q_nom).any(axis=1)
    keys = [tuple(np.round(tcp, 9)) for tcp in tcps]
    for key in dict.fromkeys(keys[i] for i in np.flatnonzero(found)):
        idx = np.array([i for i in np.flatnonzero(found) if keys[i] == key])
        qc, rep = compensate(
            model, q_nom[idx], np.array(key), max_correction=max_correction, allow_outside=allow_outside
        )
        for j, i in enumerate(idx):
            failure = rep.failures[j]
            if not failure and rep.conditioning[j] < NEAR_SINGULAR:
                failure = (
                    f"near a singularity (conditioning {rep.conditioning[j]:.1e} < {NEAR_SINGULAR:g}): small "
                    "errors need large joint corrections"
                )
            why[i] = failure
            q_cal[i] = np.nan if failure else qc[j]
            predicted[i] = rep.uncompensated_position_mm[j] if failure else rep.position_error_mm[j]
        warnings += [w for w in [*rep.ignored, *rep.warnings] if w not in warnings]
    return q_cal, predicted, warnings


def filter_targets(
    model: Model,
    targets: list[Target],
    reference_deg,
    max_correction: tuple[float, float] = (MAX_CORRECTION_MM, MAX_CORRECTION_DEG),
    allow_outside: bool = False,
    starts: int = IK_STARTS,
) -> FilterResult:
    """Every target corrected for the calibrated `model` (module docstring), or kept with the reason; each with its
    predicted accuracy. `reference_deg`: the joints the robot is at before the first target."""
    chain = model.chain
    _checked(targets, chain.dof)
    q_nom, why = nominal_joints(chain, targets, reference_deg, starts)
    tcps = np.array([np.asarray(t.tool, dtype=float)[:3, 3] for t in targets]).reshape(-1, 3)
    q_cal, predicted, warnings = _compensated(model, q_nom, tcps, why, max_correction, allow_outside)
    kin = Kinematics(chain, [])
    found, ok = ~np.isnan(q_nom).any(axis=1), ~np.isnan(q_cal).any(axis=1)
    values: list[np.ndarray | None] = [None] * len(targets)
    corr_mm, corr_deg = np.zeros(len(targets)), np.zeros(len(targets))
    if ok.any():
        f_nom, f_cal = flange_poses(kin, q_nom[ok]), flange_poses(kin, q_cal[ok])
        tcp_nom = f_nom[:, :3, 3] + np.einsum("nij,nj->ni", f_nom[:, :3, :3], tcps[ok])
        tcp_cal = f_cal[:, :3, 3] + np.einsum("nij,nj->ni", f_cal[:, :3, :3], tcps[ok])
        corr_mm[ok] = np.linalg.norm(tcp_cal - tcp_nom, axis=1)
        corr_deg[ok] = np.degrees(rotation_angle(f_nom[:, :3, :3], f_cal[:, :3, :3]))
        for j, i in enumerate(np.flatnonzero(ok)):
            t = targets[i]
            values[i] = np.degrees(q_cal[i]) if t.joint else np.linalg.inv(t.base) @ f_cal[j] @ t.tool
    q_eval = np.where(ok[:, None], q_cal, q_nom)
    sigma, bound, outside = np.full(len(targets), np.nan), np.full(len(targets), np.nan), np.zeros(len(targets), bool)
    misfit = lack_of_fit_variance(model.doc)  # what the model's form misses (calib.lack_of_fit); None: not recorded
    lof = misfit or 0.0
    if found.any():
        cov = tcp_covariance(model, q_eval[found], tcps[found])
        sigma[found] = np.sqrt(np.clip(np.trace(cov, axis1=1, axis2=2), 0.0, None) + 3.0 * lof)
        bound[found] = predicted[found] + np.sqrt(radius95(cov) ** 2 + lack_of_fit_radius95(lof) ** 2)
        outside[found] = model.outside(q_eval[found])
    if model.doc.get("covariance") is None:
        warnings.append(
            "the model carries no covariance: the 95 % bounds hold its predicted error (and its lack "
            "of fit) alone, not its parameters' uncertainty"
        )
    if misfit is None:
        warnings.append(
            "the model does not record its residual RMS and noise floor: the 95 % bounds do not hold what "
            "its form misses of the robot (its lack of fit)"
        )
    res = FilterResult(
        values,
        why,
        np.degrees(q_nom),
        np.degrees(q_cal),
        corr_mm,
        corr_deg,
        predicted,
        sigma,
        bound,
        outside,
        warnings,
        *outside_measured(model, targets, q_eval),
        lack_of_fit_mm=float("nan") if misfit is None else float(np.sqrt(misfit)),
    )
    warnings += space_warnings(model, res)
    return res


def intended_tcp(chain: Chain, targets: list[Target]) -> np.ndarray:
    """(N, 3) mm: where each target means the TCP to be, in the robot's base frame (a joint target: the nominal
    robot's TCP at its joints)."""
    kin = Kinematics(chain, [])
    out = np.zeros((len(targets), 3))
    for i, t in enumerate(targets):
        pose = (
            flange_poses(kin, np.radians(np.asarray(t.value, dtype=float)))[0] @ t.tool if t.joint else t.base @ t.value
        )
        out[i] = pose[:3, 3]
    return out


def outside_measured(model: Model, targets: list[Target], q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((N, n) deg, (N,) mm): how far each target's joints q (N, n) rad (NaN: none found) lie outside the model's
    measured joint ranges, and its intended TCP outside the measured volume; NaN where unknown."""
    space = model.measured()
    joints, volume = np.full(q.shape, np.nan), np.full(len(targets), np.nan)
    if space is None or not targets:
        return joints, volume
    found = ~np.isnan(q).any(axis=1)
    joints[found] = space.joint_excess_deg(q[found])
    return joints, space.volume_excess_mm(intended_tcp(model.chain, targets))


def space_warnings(model: Model, res: FilterResult) -> list[str]:
    """The lines saying where the bounds are not covered: targets outside the measured space, or a model that does
    not record it."""
    if model.measured() is None:
        return [
            "the model does not record where it was measured (written before trackcal recorded its joint ranges "
            "and volume): whether a target lies outside them, where its bound is an extrapolation, is unknown"
        ]
    n = int(res.extrapolated.sum())
    if n == 0:
        return []
    return [
        f"{n} of {len(res.why)} target(s) lie outside the joint ranges or the volume the model was measured in: "
        "their 95 % bounds are extrapolations (not covered: the model's uncertainty there says nothing of what "
        "it does not model), their pass/fail unknown"
    ]
