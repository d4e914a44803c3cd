"""Design of experiments: the test-pose criterion rho0 (paper section 6) and the classic criteria.

Planning assumption of section 7.2: base (stations) and tool known, so only the chosen robot parameters
are estimated (dq1 is then identifiable and may be chosen). For a plan Q = {q_i} the information matrix
is M = sum_i sum_j sum_s J_ij^T Sigma_ijs^-1 J_ij over every reference point j seen from station s, and

    rho0^2 = trace(J0 M^-1 J0^T)                                       (eq. 34, sigma inside Sigma)

with J0 the Jacobian of the cell's TCP at the test pose q0. The classic criteria use the parameter
covariance C = M^-1 with angles expressed as millimetres at a lever arm L (default 1 m) so that traces and
eigenvalues add like units: D = log det C (unit-free up to a constant), A = trace C, E = lambda_max C.

Optimisation (`optimize_plan`), in three stages:
1. screening: a pool of random feasible poses (joint limits, every reference point in the box, visible from
   a station; tested on the end frames only) and the information matrix of each pose; random plans of the
   pool are scored from sums of those matrices (Cholesky forms, `Design.criterion_values`);
2. exchange: the best screened plans are improved by the modified Fedorov exchange over the pool;
3. refinement: SLSQP in the continuous joint angles with the analytic gradient (each criterion is a smooth
   f(M) with df = trace(G dM), so df/dq_ij = sum_rows 2 <W J G, dJ/dq_ij> from the analytic derivative of
   the identification Jacobian, `Kinematics.d_params_dq`), joint limits as bounds, box and visibility as
   smooth inequality constraints with their exact Jacobians.
Exchange and refinement of each start run in parallel through any `concurrent.futures` executor (processes:
BLAS stays on one thread each).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np

from trackcal.calib.errors import CalibError
from trackcal.calib.identify.noise import TrackerNoise
from trackcal.calib.model.cell import plan_joint_bounds
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.kinematics import Kinematics, cross3
from trackcal.calib.model.params import Param

CRITERIA = ("rho0", "D", "A", "E")
CRITERION_KEY = {"rho0": "rho0_mm", "D": "D_logdet_cov", "A": "A_trace_cov_mm2", "E": "E_max_eig_cov_mm2"}


class DesignError(CalibError):
    """A plan that cannot be made: an unknown criterion, too few feasible poses, no test pose."""


@dataclass(frozen=True)
class Tracker:
    """A tracker placement for planning: tracker frame in the robot base frame."""

    rotation: np.ndarray  # base <- tracker
    position: np.ndarray  # mm


@dataclass
class Design:
    chain: Chain
    params: list[Param]
    tool: np.ndarray  # (P, 3) reference points in the last joint frame
    q0: np.ndarray  # test pose, rad
    tcp: np.ndarray  # TCP in the last joint frame
    sigma_mm: float = 0.01
    noise: TrackerNoise | None = None  # anisotropic noise model; None = i.i.d. sigma_mm
    trackers: list[Tracker] = field(default_factory=list)  # empty = every point always visible
    normals: np.ndarray | None = None  # (P, 3) reflector nest directions, last joint frame
    acceptance_deg: float = 90.0
    box_min: np.ndarray | None = None
    box_max: np.ndarray | None = None
    length_scale_mm: float = 1000.0
    joint_bounds: np.ndarray | None = None  # (n, 2) rad; default the chain's joint limits

    def __post_init__(self) -> None:
        self.kin = Kinematics(self.chain, self.params)
        self.tool = np.atleast_2d(np.asarray(self.tool, dtype=float))
        if self.normals is None:
            self.normals = np.tile([1.0, 0.0, 0.0], (len(self.tool), 1))
        lim = self.chain.limits_array() if self.joint_bounds is None else np.asarray(self.joint_bounds, dtype=float)
        self.limits = np.where(np.isfinite(lim), lim, np.array([-np.pi, np.pi]))
        self.j0 = self.kin.jacobian(self.q0[None], self.tcp).d_params[0]
        self.scale = np.array([1.0 if p.is_length else self.length_scale_mm for p in self.params])
        self.cos_accept = float(np.cos(np.radians(self.acceptance_deg)))

    # ------------------------------------------------------------------ rows of a plan
    def _rows(self, q: np.ndarray):
        m, n_pt = len(q), len(self.tool)
        return self.kin.jacobian(np.repeat(q, n_pt, axis=0), np.tile(self.tool, (m, 1)))

    def _points_and_normals(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(m*P, 3) reference points and nest directions in the base frame, from the end frames only."""
        r, o = self.kin.end_frames(np.atleast_2d(q))
        p = (o[:, None, :] + np.einsum("mij,pj->mpi", r, self.tool)).reshape(-1, 3)
        nw = np.einsum("mij,pj->mpi", r, self.normals).reshape(-1, 3)
        return p, nw

    def _margins(self, p: np.ndarray, nw: np.ndarray) -> np.ndarray:
        if not self.trackers:
            return np.ones((len(p), 1))
        d = np.stack([t.position for t in self.trackers])[None] - p[:, None, :]  # (rows, S, 3)
        return np.einsum("ri,rsi->rs", nw, d) / np.linalg.norm(d, axis=2) - self.cos_accept

    def visibility_margins(self, q: np.ndarray) -> np.ndarray:
        """(m*P, S) cos(angle to station) - cos(acceptance); >= 0 means visible."""
        return self._margins(*self._points_and_normals(q))

    def box_violation(self, p: np.ndarray) -> np.ndarray:
        if self.box_min is None:
            return np.zeros_like(p)
        return np.maximum(p - self.box_max, 0.0) - np.maximum(self.box_min - p, 0.0)

    def feasible(self, q: np.ndarray) -> np.ndarray:
        """(m,) every point of the pose in the box and seen by at least one station; within limits."""
        q = np.atleast_2d(q)
        p, nw = self._points_and_normals(q)
        ok = np.all(np.abs(self.box_violation(p)) <= 1e-9, axis=1)
        ok &= np.max(self._margins(p, nw), axis=1) >= 0.0
        ok = ok.reshape(len(q), len(self.tool)).all(axis=1)
        return ok & np.all((q >= self.limits[:, 0]) & (q <= self.limits[:, 1]), axis=1)

    def _weights(self, p: np.ndarray, nw: np.ndarray) -> np.ndarray:
        """(m*P, 3, 3) summed inverse noise covariance over the stations that see each row."""
        vis = self._margins(p, nw) >= 0.0
        if self.noise is None:
            return vis.sum(axis=1)[:, None, None] * np.eye(3) / self.sigma_mm**2
        w = np.zeros((len(p), 3, 3))
        for s, t in enumerate(self.trackers or [Tracker(np.eye(3), np.zeros(3))]):
            x = (p - t.position) @ t.rotation  # point in the tracker frame
            cov = t.rotation @ self.noise.covariance(x) @ t.rotation.T  # back in the base frame
            w += vis[:, s, None, None] * np.linalg.inv(cov)
        return w

    def pose_information(self, q: np.ndarray) -> np.ndarray:
        """(m, k, k) information matrix of each pose on its own (its points, every station that sees them)."""
        q = np.atleast_2d(q)
        j = self._rows(q).d_params
        w = self._weights(*self._points_and_normals(q))
        return np.einsum("rak,rab,rbl->rkl", j, w, j).reshape(len(q), len(self.tool), *j.shape[2:] * 2).sum(axis=1)

    def information(self, q: np.ndarray, repeat: int = 1) -> np.ndarray:
        return repeat * self.pose_information(q).sum(axis=0)

    # ------------------------------------------------------------------ criteria
    def criteria(self, q: np.ndarray, repeat: int = 1) -> dict[str, float]:
        """Every criterion of the plan q (m, n) rad measured `repeat` times."""
        m_info = self.information(q, repeat)
        k = len(self.params)
        s = np.linalg.eigvalsh(m_info / np.outer(self.scale, self.scale))  # angles at the lever arm, as below
        if s[0] <= 1e-12 * max(s[-1], 1e-300):
            return {"rho0_mm": float("inf"), "identifiable": False}
        cov = np.linalg.inv(m_info)
        cov_s = cov * np.outer(self.scale, self.scale)
        ev = np.linalg.eigvalsh(cov_s)
        # observability indices on the singular values of the weighted, scaled stacked Jacobian
        sv = np.sqrt(np.linalg.eigvalsh(np.linalg.inv(cov_s)))[::-1]
        n_meas = len(q) * repeat
        return {
            "identifiable": True,
            "rho0_mm": float(np.sqrt(np.trace(self.j0 @ cov @ self.j0.T))),
            "D_logdet_cov": float(np.linalg.slogdet(cov_s)[1]),
            "A_trace_cov_mm2": float(np.trace(cov_s)),
            "E_max_eig_cov_mm2": float(ev[-1]),
            "condition_number": float(sv[0] / sv[-1]),
            "O1": float(np.exp(np.mean(np.log(sv))) / np.sqrt(n_meas)),
            "O2": float(sv[-1] / sv[0]),
            "O3": float(sv[-1]),
            "O4": float(sv[-1] ** 2 / sv[0]),
            "O5": float(1.0 / sv[0]),
            "n_parameters": k,
        }

    def rho0(self, q: np.ndarray, repeat: int = 1) -> float:
        return self.criteria(q, repeat)["rho0_mm"]

    def criterion_values(self, infos: np.ndarray, criterion: str) -> np.ndarray:
        """The criterion (smaller is better) of a stack of information matrices (N, k, k), for screening and
        exchange: rho0^2 = trace(J0 M^-1 J0^T), A = trace C_s, D = the geometric mean of the eigenvalues of C_s,
        E = lambda_max C_s (C_s the covariance with angles at the lever arm, as in `criteria`).

        Through a Cholesky factor L of the scaled information (a ridge of 1e-12 of its trace keeps every
        factor defined; a singular plan gets a value near 1e12 times a regular one): rho0^2 = |L^-1 (J0 S^-1)^T|^2,
        trace C_s = |L^-1|^2, det C_s = prod(diag L)^-2."""
        s = self.scale
        ms = infos / np.outer(s, s)
        k = ms.shape[-1]
        ms = ms + (1e-12 * np.trace(ms, axis1=-2, axis2=-1))[:, None, None] * np.eye(k)
        if criterion == "E":
            return 1.0 / np.linalg.eigvalsh(ms)[:, 0]
        chol = np.linalg.cholesky(ms)
        if criterion == "D":
            return np.exp(-2.0 * np.mean(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1))
        if criterion not in ("rho0", "A"):
            raise DesignError(f"unknown criterion {criterion!r}; choose from {', '.join(CRITERIA)}")
        rhs = (self.j0 / s).T if criterion == "rho0" else np.eye(k)
        y = np.empty((len(ms), k, rhs.shape[1]))
        for i in range(k):  # forward substitution L y = rhs, vectorised over the stack
            y[:, i] = (rhs[i] - np.einsum("nj,njc->nc", chol[:, i, :i], y[:, :i])) / chol[:, i, i, None]
        return np.sum(y**2, axis=(1, 2))

    # ------------------------------------------------------------------ smooth problem for the refinement
    def objective(
        self, x: np.ndarray, m: int, criterion: str, w: np.ndarray, jac=None, d_weight: float = 0.0
    ) -> tuple[float, np.ndarray]:
        """log(criterion) of the plan x = (m*n,) rad with the row weights w (m*P, 3, 3) held fixed, and its
        gradient: with df = trace(G dM), df/dq_rj = 2 <W_r J_r G, dJ_r/dq_j>. Returns (inf, 0) if singular.
        `jac` is the plan's `_rows` when the caller has it. `d_weight` adds d_weight * log(D), D the geometric
        mean of the covariance eigenvalues, which keeps a plan away from losing a parameter where the
        criterion itself is flat (rho0 stays flat while poses gather at the test pose)."""
        n = self.chain.dof
        jac = self._rows(x.reshape(m, n)) if jac is None else jac
        j = jac.d_params
        wj = np.einsum("rab,rbk->rak", w, j)
        ms = np.einsum("rak,ral->kl", j, wj) / np.outer(self.scale, self.scale)
        lam, vec = np.linalg.eigh(ms)
        if not lam[0] > 1e-12 * max(lam[-1], 1e-300):
            return np.inf, np.zeros_like(x)
        vs = vec / self.scale[:, None]  # M^-1 = vs L^-1 vs^T
        if criterion == "rho0":
            a = (self.j0 @ vs) / lam
            f = float(np.sum(a * (self.j0 @ vs)))
            g = -(vs @ a.T) @ (a @ vs.T)  # -M^-1 J0^T J0 M^-1
        elif criterion == "A":
            f = float(np.sum(1.0 / lam))
            g = -(vs / lam) @ (vs.T * self.scale[None] ** 2) @ (vs / lam) @ vs.T  # -M^-1 S^2 M^-1
        elif criterion == "D":
            f = float(np.exp(-np.mean(np.log(lam))))
            g = -(vs / lam) @ vs.T * f / len(lam)
        elif criterion == "E":
            v = vs[:, 0]
            f = float(1.0 / lam[0])
            g = -np.outer(v, v) * f**2
        else:
            raise DesignError(f"unknown criterion {criterion!r}; choose from {', '.join(CRITERIA)}")
        value, g = float(np.log(f)), g / f
        if d_weight:  # d log D = -(1/k) trace(M^-1 dM)
            value -= d_weight * float(np.mean(np.log(lam)))
            g = g - d_weight * (vs / lam) @ vs.T / len(lam)
        dd = self.kin.d_params_dq(jac)
        grad_rows = 2.0 * np.einsum("rak,kl,ralj->rj", wj, g, dd)
        return value, grad_rows.reshape(m, len(self.tool), n).sum(axis=1).ravel()

    def constraints(self, x: np.ndarray, m: int, seen: np.ndarray, jac=None, inset=(1e-3, 1e-6)):
        """Smooth inequality constraints g(x) >= 0 of a plan and their Jacobian (c, m*n): every reference
        point inside the box and every (row, station) pair marked in `seen` (m*P, S) visible, both by a small
        `inset` (mm, cosine) that keeps a solver's last rounding on the feasible side."""
        inset_mm, inset_cos = inset
        n, n_pt = self.chain.dof, len(self.tool)
        jac = self._rows(x.reshape(m, n)) if jac is None else jac
        rows = np.arange(m * n_pt)
        pose = rows // n_pt
        values, grads = [], []

        def block(d: np.ndarray) -> np.ndarray:  # (rows, n) derivatives of one value per row -> (rows, m*n)
            out = np.zeros((len(d), m, n))
            out[rows, pose] = d
            return out.reshape(len(d), m * n)

        if self.box_min is not None:
            for a in range(3):
                values += [self.box_max[a] - inset_mm - jac.p[:, a], jac.p[:, a] - self.box_min[a] - inset_mm]
                grads += [block(-jac.d_q[:, a]), block(jac.d_q[:, a])]
        if self.trackers:
            nw = np.einsum("rij,rj->ri", jac.d_point, np.tile(self.normals, (m, 1)))
            dnw = cross3(jac.joint_axes, nw[:, :, None])  # (rows, 3, n): w_j x n
            for s, t in enumerate(self.trackers):
                use = np.flatnonzero(seen[:, s])
                d = t.position - jac.p[use]
                dn = np.linalg.norm(d, axis=1)
                nd = np.einsum("ri,ri->r", nw[use], d)
                dd = -jac.d_q[use]
                dcos = (
                    np.einsum("rij,ri->rj", dnw[use], d) / dn[:, None]
                    + np.einsum("ri,rij->rj", nw[use], dd) / dn[:, None]
                    - (nd / dn**3)[:, None] * np.einsum("ri,rij->rj", d, dd)
                )
                values.append(nd / dn - self.cos_accept - inset_cos)
                full = np.zeros((len(rows), n))
                full[use] = dcos
                grads.append(block(full)[use])
        if not values:
            return np.zeros(0), np.zeros((0, m * n))
        return np.concatenate(values), np.concatenate(grads)


# ---------------------------------------------------------------------- search
@dataclass
class Plan:
    poses: np.ndarray  # (m, n) rad, the distinct configurations
    repeat: int
    criterion: str
    criteria: dict[str, float]
    starts: int
    refined: int


def random_feasible_poses(design: Design, count: int, rng: np.random.Generator, max_tries: int = 200) -> np.ndarray:
    """`count` random poses within the joint limits that pass `Design.feasible`, drawn in bounded chunks."""
    out: list[np.ndarray] = []
    lim = design.limits
    for _ in range(max_tries):
        cand = rng.uniform(lim[:, 0], lim[:, 1], size=(min(max(4 * count, 64), 4096), design.chain.dof))
        out.extend(cand[design.feasible(cand)])
        if len(out) >= count:
            return np.array(out[:count])
    raise DesignError(f"found only {len(out)} of {count} feasible poses (limits, cell box, visibility)")


def exchange(design: Design, infos: np.ndarray, plan: np.ndarray, criterion: str, max_passes: int = 100) -> np.ndarray:
    """Modified Fedorov exchange (Cook and Nachtsheim, Technometrics 22, 1980) over a candidate pool: `infos`
    (N, k, k) the pool's pose information matrices, `plan` (m,) distinct pool indices. Each plan pose in turn
    is swapped for the pool pose that lowers the criterion most, if any does; passes repeat until one changes
    nothing. Returns the plan's indices."""
    plan = np.array(plan)
    total = infos[plan].sum(axis=0)
    best = design.criterion_values(total[None], criterion)[0]
    for _ in range(max_passes):
        improved = False
        for i in range(len(plan)):
            outside = np.setdiff1d(np.arange(len(infos)), plan)
            values = design.criterion_values(total - infos[plan[i]] + infos[outside], criterion)
            c = int(np.argmin(values))
            if values[c] < best * (1 - 1e-12):
                total = total - infos[plan[i]] + infos[outside[c]]
                plan[i], best, improved = outside[c], values[c], True
        if not improved:
            break
    return plan


# Weight of log(D) in the refinement of the other criteria: rho0 is flat along plans whose poses gather at the
# test pose, where the parameters that do not act there become inseparable and a campaign measured with the
# plan cannot be identified; a small D term keeps the refinement off that valley.
D_WEIGHT = 0.02


def refine(design: Design, q: np.ndarray, criterion: str, maxiter: int = 200) -> np.ndarray:
    """Local refinement of one feasible plan by SLSQP with the analytic gradient: joint limits as bounds, the
    box and the visibility of every (point, station) pair seen at the start as smooth constraints, the row
    weights of the start held fixed. Returns the refined poses if they are feasible and better, else q."""
    from scipy.optimize import minimize  # lazy: ~0.3 s at start-up of every command that imports calib.doe

    m, n = q.shape
    x0 = q.ravel()
    p, nw = design._points_and_normals(q)
    w, seen = design._weights(p, nw), design._margins(p, nw) >= 0.0
    last: dict[bytes, tuple] = {}

    def evaluated(x: np.ndarray) -> tuple:  # SLSQP asks for the objective and the constraints at the same x
        key = x.tobytes()
        if key not in last:
            jac = design._rows(x.reshape(m, n))
            last.clear()
            value = design.objective(x, m, criterion, w, jac, 0.0 if criterion == "D" else D_WEIGHT)
            last[key] = (value, design.constraints(x, m, seen, jac=jac))
        return last[key]

    res = minimize(
        lambda x: evaluated(x)[0], x0, jac=True, method="SLSQP", bounds=np.tile(design.limits, (m, 1)),
        constraints={"type": "ineq", "fun": lambda x: evaluated(x)[1][0], "jac": lambda x: evaluated(x)[1][1]},
        options={"maxiter": maxiter, "ftol": 1e-10},
    )  # fmt: skip
    out = np.clip(res.x, np.tile(design.limits[:, 0], m), np.tile(design.limits[:, 1], m)).reshape(m, n)
    if not design.feasible(out).all():
        return q
    start, end = design.criterion_values(np.stack([design.information(p) for p in (q, out)]), criterion)
    return out if end < start else q


def _task(args):
    design, pool, infos, plan, criterion = args
    start = pool[exchange(design, infos, plan, criterion)] if pool is not None else plan
    return start, refine(design, start, criterion)


def optimize_plan(
    design: Design,
    m: int,
    repeat: int = 1,
    criterion: str = "rho0",
    starts: int = 1000,
    refined: int = 16,
    seed: int = 0,
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
    initial: list[np.ndarray] | None = None,
    pool_size: int = 2000,
) -> Plan:
    """Screening, exchange, refinement: `pool_size` random feasible poses form the candidate pool, `starts`
    random plans of m distinct pool poses are scored, the best `refined` improved by Fedorov exchange over
    the pool and then refined continuously (`refine`, in `executor` when given); the best feasible result is
    evaluated exactly. `initial` plans (m, n) rad are refined too (e.g. a repeated smaller plan)."""
    if criterion not in CRITERIA:
        raise DesignError(f"unknown criterion {criterion!r}; choose from {', '.join(CRITERIA)}")
    rng = np.random.default_rng(seed)
    pool = random_feasible_poses(design, max(pool_size, m + 1), rng)
    infos = design.pose_information(pool)
    screened = np.array([rng.choice(len(pool), m, replace=False) for _ in range(starts)])
    scores = design.criterion_values(infos[screened].sum(axis=1), criterion)
    tasks = [(design, pool, infos, plan, criterion) for plan in screened[np.argsort(scores)[:refined]]]
    tasks += [(design, None, None, np.asarray(q, dtype=float), criterion) for q in initial or []]
    candidates = []
    it = executor.map(_task, tasks) if executor is not None else map(_task, tasks)
    for i, pair in enumerate(it):
        candidates.extend(q for q in pair if design.feasible(q).all())
        if progress:
            progress(i + 1, len(tasks))
    key = CRITERION_KEY[criterion]
    values = [design.criteria(q, repeat).get(key, np.inf) for q in candidates]
    q_best = candidates[int(np.argmin(values))]
    return Plan(q_best, repeat, criterion, design.criteria(q_best, repeat), starts, refined)


# Plans are written at the controller's precision (4 decimals of a degree) and optimal poses sit on the box
# boundary. Rounding moves each joint by at most 5e-5 deg; a point up to 3.5 m from every axis (KR 270 reach
# 2.7 m plus the tool) moves by at most 6 * 5e-5 * pi/180 * 3500 mm = 0.018 mm. Planning in a box 0.1 mm
# smaller keeps every rounded pose inside the real one (the robot client refuses targets outside it).
PLAN_BOX_MARGIN_MM = 0.1


def design_for_cell(
    cell,
    params: list[Param],
    q0: np.ndarray | None = None,
    sigma_mm: float = 0.01,
    noise: TrackerNoise | None = None,
    visibility: bool = True,
) -> Design:
    """A Design from a `calib.model.cell.Cell`: its tool, TCP, test pose, box and (optionally) stations."""
    if q0 is None:
        if cell.test_pose is None:
            raise DesignError(f"cell {cell.name} has no test_pose_deg: give the test pose")
        q0 = cell.test_pose
    pids = sorted(cell.tool_points)
    trackers = [Tracker(s.rotation, s.position) for s in cell.stations.values()] if visibility else []
    return Design(
        chain=cell.chain, params=params, tool=np.array([cell.tool_points[p] for p in pids]), q0=np.asarray(q0),
        tcp=cell.tcp, sigma_mm=sigma_mm, noise=noise, trackers=trackers,
        normals=np.array([cell.tool_normals[p] for p in pids]), acceptance_deg=cell.acceptance_deg,
        box_min=None if cell.box_min is None else cell.box_min + PLAN_BOX_MARGIN_MM,
        box_max=None if cell.box_max is None else cell.box_max - PLAN_BOX_MARGIN_MM,
        joint_bounds=plan_joint_bounds(cell),
    )  # fmt: skip


def monte_carlo_rho0(design: Design, q: np.ndarray, repeat: int, runs: int,
                     rng: np.random.Generator | list[np.random.Generator]) -> np.ndarray:  # fmt: skip
    """Simulate `runs` campaigns of the plan (truth at nominal, base and tool known, the design's noise),
    identify the parameters by Gauss-Newton, and return the TCP error (mm) at the test pose of each run. `rng`: one
    generator for all runs, or one per run (a run's result then does not depend on the runs computed with it)."""
    rngs = rng if isinstance(rng, list) else [rng] * runs
    if len(rngs) != runs:
        raise DesignError(f"{len(rngs)} generators for {runs} runs")
    q = np.atleast_2d(q)
    qr = np.repeat(np.tile(q, (repeat, 1)), len(design.tool), axis=0)
    tool = np.tile(design.tool, (len(q) * repeat, 1))
    jac = design.kin.jacobian(qr, tool)
    vis = design.visibility_margins(q) >= 0.0
    vis = np.tile(vis, (repeat, 1))  # (rows, S)
    trackers = design.trackers or [Tracker(np.eye(3), np.zeros(3))]
    exact = jac.p
    p0 = design.kin.points(design.q0[None], design.tcp)[0]
    noise = design.noise or TrackerNoise.isotropic(design.sigma_mm)
    errors = np.empty(runs)
    for k in range(runs):
        ys, qs, ts, ws = [], [], [], []
        for s, t in enumerate(trackers):
            rows = np.flatnonzero(vis[:, s])
            x = (exact[rows] - t.position) @ t.rotation  # tracker frame
            ys.append(x + noise.sample(x, rngs[k]))
            qs.append(rows)
            ws.append(noise.whitening(x))
            ts.append(np.full(len(rows), s))
        rows = np.concatenate(qs)
        y = np.concatenate(ys)
        wm = np.concatenate(ws)
        st = np.concatenate(ts)
        rot = np.array([t.rotation for t in trackers])[st]
        pos = np.array([t.position for t in trackers])[st]
        dev = np.zeros(len(design.params))
        for _ in range(3):  # the problem is nearly linear: 3 Gauss-Newton steps reach the optimum
            jj = design.kin.jacobian(qr[rows], tool[rows], dev)
            pred = np.einsum("rji,rj->ri", rot, jj.p - pos)
            jt = np.einsum("rji,rjk->rik", rot, jj.d_params)
            r = np.einsum("rij,rj->ri", wm, y - pred).ravel()
            a = np.einsum("rij,rjk->rik", wm, jt).reshape(-1, len(dev))
            dev = dev + np.linalg.lstsq(a, r, rcond=None)[0]
        errors[k] = np.linalg.norm(design.kin.points(design.q0[None], design.tcp, dev)[0] - p0)
    return errors
