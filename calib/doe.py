"""Design of experiments: the test-pose criterion rho0 (paper section 6) and the classic criteria.

Planning assumption of section 7.2: base (stations) and tool known, so only the chosen robot parameters
are estimated (dq1 is then identifiable and may be chosen). For a plan Q = {q_i} the information matrix
is M = sum_i sum_j sum_s J_ij^T Sigma_ijs^-1 J_ij over every reference point j seen from station s, and

    rho0^2 = trace(J0 M^-1 J0^T)                                       (eq. 34, sigma inside Sigma)

with J0 the Jacobian of the cell's TCP at the test pose q0. The classic criteria use the parameter
covariance C = M^-1 with angles expressed as millimetres at a lever arm L (default 1 m) so that traces and
eigenvalues add like units: D = log det C (unit-free up to a constant), A = trace C, E = lambda_max C.

Optimisation (`optimize_plan`): each criterion is a smooth function f(M) with df = trace(G dM), so its
gradient in the joint angles follows from the analytic derivative of the identification Jacobian
(`Kinematics.d_params_dq`): df/dq_ij = sum_rows 2 <W J G, dJ/dq_ij>. Constraints: joint limits (bounds),
every reference point inside the cell box and visible from at least one station (smooth exact
penalties). Many cheap random feasible starts are scored; the best are refined by L-BFGS-B with the
analytic gradient, in parallel through any `concurrent.futures` executor.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from .cell import plan_joint_bounds
from .chain import Chain
from .kinematics import Kinematics
from .noise import TrackerNoise
from .params import Param

CRITERIA = ("rho0", "D", "A", "E")
CRITERION_KEY = {"rho0": "rho0_mm", "D": "D_logdet_cov", "A": "A_trace_cov_mm2", "E": "E_max_eig_cov_mm2"}


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
        jac = self.kin.jacobian(np.repeat(q, n_pt, axis=0), np.tile(self.tool, (m, 1)))
        return jac

    def visibility_margins(self, q: np.ndarray, jac=None) -> np.ndarray:
        """(m*P, S) cos(angle to station) - cos(acceptance); >= 0 means visible."""
        jac = self._rows(q) if jac is None else jac
        if not self.trackers:
            return np.ones((len(jac.p), 1))
        nw = np.einsum("rij,rj->ri", jac.d_point, np.tile(self.normals, (len(q), 1)))
        out = []
        for t in self.trackers:
            d = t.position - jac.p
            out.append(np.einsum("ri,ri->r", nw, d) / np.linalg.norm(d, axis=1) - self.cos_accept)
        return np.stack(out, axis=1)

    def box_violation(self, p: np.ndarray) -> np.ndarray:
        if self.box_min is None:
            return np.zeros_like(p)
        return np.maximum(p - self.box_max, 0.0) - np.maximum(self.box_min - p, 0.0)

    def feasible(self, q: np.ndarray) -> np.ndarray:
        """(m,) every point of the pose in the box and seen by at least one station; within limits."""
        q = np.atleast_2d(q)
        jac = self._rows(q)
        n_pt = len(self.tool)
        ok = np.all(np.abs(self.box_violation(jac.p)) <= 1e-9, axis=1)
        ok &= np.max(self.visibility_margins(q, jac), axis=1) >= 0.0
        ok = ok.reshape(len(q), n_pt).all(axis=1)
        return ok & np.all((q >= self.limits[:, 0]) & (q <= self.limits[:, 1]), axis=1)

    def _weights(self, q: np.ndarray, jac) -> np.ndarray:
        """(m*P, 3, 3) summed inverse noise covariance over the stations that see each row."""
        n_rows = len(jac.p)
        vis = self.visibility_margins(q, jac) >= 0.0
        if self.noise is None:
            return vis.sum(axis=1)[:, None, None] * np.eye(3) / self.sigma_mm**2
        w = np.zeros((n_rows, 3, 3))
        for s, t in enumerate(self.trackers or [Tracker(np.eye(3), np.zeros(3))]):
            x = (jac.p - t.position) @ t.rotation  # point in the tracker frame
            cov = t.rotation @ self.noise.covariance(x) @ t.rotation.T  # back in the base frame
            w += vis[:, s, None, None] * np.linalg.inv(cov)
        return w

    def information(self, q: np.ndarray, repeat: int = 1) -> np.ndarray:
        q = np.atleast_2d(q)
        jac = self._rows(q)
        w = self._weights(q, jac)
        return repeat * np.einsum("rak,rab,rbl->kl", jac.d_params, w, jac.d_params)

    # ------------------------------------------------------------------ criteria
    def criteria(self, q: np.ndarray, repeat: int = 1) -> dict[str, float]:
        """Every criterion of the plan q (m, n) rad measured `repeat` times."""
        m_info = self.information(q, repeat)
        k = len(self.params)
        s, _ = np.linalg.eigh(m_info)
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

    # ------------------------------------------------------------------ smooth objective for the search
    def objective(self, x: np.ndarray, m: int, criterion: str, mu: float = 1e3) -> tuple[float, np.ndarray]:
        """log(criterion) + exact penalties, and its gradient; x = plan (m*n,) rad.

        For the search every (pose, point) counts once with i.i.d. noise (section 5.2: plans are designed
        under the i.i.d. assumption) and must be visible from at least one station (penalty); `criteria`
        then evaluates the plan exactly, counting every station that sees each point.
        """
        n = self.chain.dof
        q = x.reshape(m, n)
        jac = self._rows(q)
        j = jac.d_params
        info = np.einsum("rak,ral->kl", j, j)
        try:
            minv = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            return 1e6, np.zeros_like(x)
        if criterion == "rho0":
            a = self.j0 @ minv
            f = float(np.trace(a @ self.j0.T))
            g = -a.T @ a
        elif criterion == "A":
            b = minv * self.scale
            f = float(np.trace(self.scale[:, None] * b))
            g = -b @ b.T
        elif criterion == "D":
            sign, logdet = np.linalg.slogdet(minv)
            f = float(np.exp(logdet / len(self.params)))  # geometric mean keeps log(f) well scaled
            g = -minv * f / len(self.params)
        elif criterion == "E":
            ms = info / np.outer(self.scale, self.scale)
            lam, vec = np.linalg.eigh(ms)
            v = vec[:, 0] / self.scale
            f = float(1.0 / lam[0])
            g = -np.outer(v, v) * f**2
        else:
            raise ValueError(f"unknown criterion {criterion!r}; choose from {', '.join(CRITERIA)}")
        if not np.isfinite(f) or f <= 0:
            return 1e6, np.zeros_like(x)
        # d f / d q_rj = 2 <J_r G, dJ_r/dq_j>; we minimise log f
        dd = self.kin.d_params_dq(jac)
        grad_rows = 2.0 * np.einsum("rak,kl,ralj->rj", j, g, dd) / f
        value = float(np.log(f))
        # box penalty
        viol = self.box_violation(jac.p)
        value += mu * float(np.sum(viol**2)) / 1e2
        grad_rows += 2.0 * mu / 1e2 * np.einsum("ra,raj->rj", viol, jac.d_q)
        # visibility penalty on the best station of each row, with a small safety margin
        if self.trackers:
            v_val, v_grad = self._visibility_penalty(q, jac)
            value += mu * v_val
            grad_rows += mu * v_grad
        grad = grad_rows.reshape(m, len(self.tool), n).sum(axis=1).ravel()
        return value, grad

    def _visibility_penalty(self, q: np.ndarray, jac, margin: float = 0.02) -> tuple[float, np.ndarray]:
        m_all = self.visibility_margins(q, jac)
        best = np.argmax(m_all, axis=1)
        short = np.maximum(margin - m_all[np.arange(len(best)), best], 0.0)
        if not np.any(short > 0):
            return 0.0, np.zeros(jac.d_q.shape[::2])
        nw = np.einsum("rij,rj->ri", jac.d_point, np.tile(self.normals, (len(q), 1)))
        pos = np.array([self.trackers[s].position for s in best])
        d = pos - jac.p
        dn = np.linalg.norm(d, axis=1)
        dnw = np.cross(jac.joint_axes, nw[:, :, None], axis=1)  # (r, 3, n): w_j x n
        dd = -jac.d_q
        nd = np.einsum("ri,ri->r", nw, d)
        dcos = (
            np.einsum("rij,ri->rj", dnw, d) / dn[:, None]
            + np.einsum("ri,rij->rj", nw, dd) / dn[:, None]
            - (nd / dn**3)[:, None] * np.einsum("ri,rij->rj", d, dd)
        )
        return float(np.sum(short**2)), -2.0 * short[:, None] * dcos


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
    out: list[np.ndarray] = []
    lim = design.limits
    for _ in range(max_tries):
        cand = rng.uniform(lim[:, 0], lim[:, 1], size=(max(4 * count, 64), design.chain.dof))
        out.extend(cand[design.feasible(cand)])
        if len(out) >= count:
            return np.array(out[:count])
    raise ValueError(f"found only {len(out)} of {count} feasible poses (limits, cell box, visibility)")


def refine(design: Design, q: np.ndarray, criterion: str, maxiter: int = 300) -> np.ndarray:
    """Local L-BFGS-B refinement of one plan with the analytic gradient; returns the refined poses."""
    m, n = q.shape
    bounds = np.tile(design.limits, (m, 1))
    res = minimize(
        design.objective, q.ravel(), args=(m, criterion), jac=True, method="L-BFGS-B",
        bounds=bounds, options={"maxiter": maxiter},
    )  # fmt: skip
    return res.x.reshape(m, n)


def _refine_task(args):
    design, q, criterion = args
    return refine(design, q, criterion)


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
) -> Plan:
    """Multi-start search: `starts` random feasible plans scored by the criterion, the best `refined`
    refined by L-BFGS-B (in `executor` when given), the best feasible result evaluated exactly.
    `initial` plans (m, n) rad are always refined too (e.g. a repeated smaller plan)."""
    if criterion not in CRITERIA:
        raise ValueError(f"unknown criterion {criterion!r}; choose from {', '.join(CRITERIA)}")
    rng = np.random.default_rng(seed)
    pool = random_feasible_poses(design, starts * m, rng).reshape(starts, m, design.chain.dof)
    scores = np.array([design.objective(q.ravel(), m, criterion)[0] for q in pool])
    best = list(pool[np.argsort(scores)[:refined]]) + [np.asarray(q, dtype=float) for q in initial or []]
    tasks = [(design, q, criterion) for q in best]
    results = []
    it = executor.map(_refine_task, tasks) if executor is not None else map(_refine_task, tasks)
    for i, q in enumerate(it):
        results.append(q)
        if progress:
            progress(i + 1, len(tasks))
    candidates = [q for q in results + best if design.feasible(q).all()]
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
    """A Design from a `calib.cell.Cell`: its tool, TCP, test pose, box and (optionally) stations."""
    if q0 is None:
        if cell.test_pose is None:
            raise ValueError(f"cell {cell.name} has no test_pose_deg: give the test pose")
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


def monte_carlo_rho0(design: Design, q: np.ndarray, repeat: int, runs: int, rng: np.random.Generator) -> np.ndarray:
    """Simulate `runs` campaigns of the plan (truth at nominal, base and tool known, the design's noise),
    identify the parameters by Gauss-Newton, and return the TCP error (mm) at the test pose of each run."""
    q = np.atleast_2d(q)
    qr = np.repeat(np.tile(q, (repeat, 1)), len(design.tool), axis=0)
    tool = np.tile(design.tool, (len(q) * repeat, 1))
    jac = design.kin.jacobian(qr, tool)
    vis = design.visibility_margins(q, design._rows(q)) >= 0.0
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
            ys.append(x + noise.sample(x, rng))
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
