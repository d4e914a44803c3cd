"""Design of experiments: the test-pose criterion rho0 (paper section 6) and the classic criteria.

A plan is scored for what the campaign will identify (calib.identify.unknowns): the robot parameters, every
tracker station's 6-dof transform and every reference point's coordinates, jointly. Each measurement row is one
(pose, reference point, station that sees it): y = R_s p(q, dev, t_j) + t_s in the station frame, with the
solver's station perturbation x' = Exp(w) x + v, so its Jacobian has the columns R_s dp/d(dev), I (v),
-[y]x (w) and R_s dp/dt_j (the point). For a plan Q = {q_i} the information matrix is
M = sum over rows A^T W A (W the inverse noise covariance in the station frame), and

    rho0^2 = trace(G M^-1 G^T)                                         (eq. 34, sigma inside W)

with G the Jacobian of the quantity a campaign's report states at the test pose q0: the centroid of the
reference points in the first station's frame (campaign/report/tcp.py:tcp_sigma propagates the identification's
covariance through the same G). rho0 is therefore the prediction of that figure for the planned poses. The
paper's planning assumption (section 7.2: base and tool known, rows summed over stations, G the TCP's Jacobian
J0) is `known=("stations", "points")`, kept for reproducing its tables.
The classic criteria use the covariance C = M^-1 with angles expressed as millimetres at a lever arm L (default
1 m) so that traces and eigenvalues add like units: D = log det C (unit-free up to a constant), A = trace C,
E = lambda_max C.

Optimisation (`optimize_plan`), in three stages:
1. screening: a pool of random feasible poses (joint limits, every reference point in the box, visible from
   a station; tested on the end frames only) and the information matrix of each pose; random plans of the
   pool are scored from sums of those matrices (Cholesky forms, `Design.criterion_values`);
2. exchange: the best screened plans are improved by the modified Fedorov exchange over the pool;
3. refinement: SLSQP in the continuous joint angles with the analytic gradient (each criterion is a smooth
   f(M) with df = trace(g dM), so df/dq_ij = sum_rows 2 <W A g, dA/dq_ij> from the analytic derivative of
   the rows' Jacobian, `Design.row_jacobian_dq` on `Kinematics.d_params_dq`), joint limits as bounds, box and
   visibility as smooth inequality constraints with their exact Jacobians.
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
from trackcal.calib.identify.solver import identify
from trackcal.calib.identify.unknowns import campaign_unknowns
from trackcal.calib.io.table import MeasurementTable
from trackcal.calib.model.cell import plan_joint_bounds
from trackcal.calib.model.chain import Chain
from trackcal.calib.model.kinematics import Kinematics, cross3
from trackcal.calib.model.params import Param
from trackcal.calib.model.rigid import skew

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
    params: list[Param]  # the robot parameters identified
    tool: np.ndarray  # (P, 3) reference points in the last joint frame
    q0: np.ndarray  # test pose, rad
    tcp: np.ndarray  # TCP in the last joint frame (the test-pose quantity when the points are known)
    sigma_mm: float = 0.01
    noise: TrackerNoise | None = None  # anisotropic noise model; None = i.i.d. sigma_mm
    trackers: list[Tracker] = field(default_factory=list)  # empty = one station at the base, seeing every point
    normals: np.ndarray | None = None  # (P, 3) reflector nest directions, last joint frame
    acceptance_deg: float = 90.0
    box_min: np.ndarray | None = None
    box_max: np.ndarray | None = None
    length_scale_mm: float = 1000.0
    joint_bounds: np.ndarray | None = None  # (n, 2) rad; default the chain's joint limits
    known: tuple[str, ...] = ()  # groups held at nominal (calib.identify.unknowns.KNOWABLE; the paper's section 7.2)
    # a (point, station) pair counts as seen only this far inside the acceptance cone, and a feasible pose has none
    # within this of its edge: where the nominal cell cannot tell whether the real station will see it
    visibility_margin_deg: float = 0.0

    def __post_init__(self) -> None:
        self.kin = Kinematics(self.chain, self.params)
        self.tool = np.atleast_2d(np.asarray(self.tool, dtype=float))
        if self.normals is None:
            self.normals = np.tile([1.0, 0.0, 0.0], (len(self.tool), 1))
        lim = self.chain.limits_array() if self.joint_bounds is None else np.asarray(self.joint_bounds, dtype=float)
        self.limits = np.where(np.isfinite(lim), lim, np.array([-np.pi, np.pi]))
        stations = self.trackers or [Tracker(np.eye(3), np.zeros(3))]
        self.r_st = np.array([t.rotation.T for t in stations])  # (S, 3, 3) station <- base
        self.t_st = -np.einsum("sij,sj->si", self.r_st, np.array([t.position for t in stations]))
        self.unknowns = campaign_unknowns(self.params, len(stations), len(self.tool), tuple(self.known))
        self.j0 = self.test_pose_jacobian()
        self.scale = self.unknowns.scale(self.length_scale_mm)
        self.cos_accept = float(np.cos(np.radians(self.acceptance_deg - self.visibility_margin_deg)))
        self.cos_reject = float(np.cos(np.radians(min(self.acceptance_deg + self.visibility_margin_deg, 180.0))))

    # ------------------------------------------------------------------ rows of a plan
    def _rows(self, q: np.ndarray):
        m, n_pt = len(q), len(self.tool)
        return self.kin.jacobian(np.repeat(q, n_pt, axis=0), np.tile(self.tool, (m, 1)))

    def test_pose_jacobian(self) -> np.ndarray:
        """G (3, K): the derivative, w.r.t. every unknown, of the test-pose quantity in the first station's frame:
        the centroid of the reference points (or, with the points known, the cell's TCP)."""
        u, n_pt = self.unknowns, len(self.tool)
        if u.n_points:
            jac = self.kin.jacobian(np.repeat(self.q0[None], n_pt, axis=0), self.tool)
            d_params, c = jac.d_params.mean(axis=0), jac.p.mean(axis=0)
        else:
            jac = self.kin.jacobian(self.q0[None], self.tcp)
            d_params, c = jac.d_params[0], jac.p[0]
        r0 = self.r_st[0]
        g = np.zeros((3, u.size))
        g[:, : u.k] = r0 @ d_params
        if u.n_stations:
            g[:, u.c_st : u.c_st + 3] = np.eye(3)
            g[:, u.c_st + 3 : u.c_st + 6] = -skew(r0 @ c + self.t_st[0])
        for j in range(u.n_points):
            g[:, u.c_pt + 3 * j : u.c_pt + 3 * j + 3] = r0 @ jac.d_point[j] / n_pt
        return g

    def row_jacobian(self, jac) -> tuple[np.ndarray, np.ndarray]:
        """(A (N, S, 3, K), y (N, S, 3)) of the rows `jac` (`_rows`: pose by pose, point by point) as seen from
        every station: the Jacobian of each row's station-frame position w.r.t. every unknown, and the position."""
        u, n_pt = self.unknowns, len(self.tool)
        rows, s_count = len(jac.p), len(self.r_st)
        a = np.zeros((rows, s_count, 3, u.size))
        a[..., : u.k] = np.einsum("sab,nbk->nsak", self.r_st, jac.d_params)
        y = np.einsum("sab,nb->nsa", self.r_st, jac.p) + self.t_st
        for s in range(u.n_stations):
            a[:, s, :, u.c_st + 6 * s : u.c_st + 6 * s + 3] = np.eye(3)
            a[:, s, :, u.c_st + 6 * s + 3 : u.c_st + 6 * s + 6] = -skew(y[:, s])
        if u.n_points:
            point = np.arange(rows) % n_pt
            rd = np.einsum("sab,nbc->nsac", self.r_st, jac.d_point)
            for j in range(n_pt):
                a[point == j, :, :, u.c_pt + 3 * j : u.c_pt + 3 * j + 3] = rd[point == j]
        return a, y

    def row_jacobian_dq(self, jac) -> np.ndarray:
        """dA/dq (N, S, 3, K, n) of `row_jacobian`: the robot columns turn with the chain (`Kinematics.d_params_dq`),
        a station's rotation columns -[y]x follow the point (-[R_s dp/dq_j]x), its translation columns are
        constant, a point's columns R_s R_end turn about every joint axis upstream of it (w_j x column)."""
        u, n_pt, n = self.unknowns, len(self.tool), self.chain.dof
        rows, s_count = len(jac.p), len(self.r_st)
        out = np.zeros((rows, s_count, 3, u.size, n))
        out[:, :, :, : u.k] = np.einsum("sab,nbkj->nsakj", self.r_st, self.kin.d_params_dq(jac))
        if u.n_stations:
            dy = np.einsum("sab,nbj->nsja", self.r_st, jac.d_q)  # (N, S, n, 3)
            sk = -skew(dy).transpose(0, 1, 3, 4, 2)  # (N, S, 3, 3, n)
            for s in range(u.n_stations):
                out[:, s, :, u.c_st + 6 * s + 3 : u.c_st + 6 * s + 6] = sk[:, s]
        if u.n_points:
            d_point = cross3(jac.joint_axes[:, :, None, :], jac.d_point[:, :, :, None])  # (N, 3, 3, n)
            rd = np.einsum("sab,ncbj->nsacj", self.r_st, d_point.transpose(0, 2, 1, 3))
            point = np.arange(rows) % n_pt
            for j in range(n_pt):
                out[point == j, :, :, u.c_pt + 3 * j : u.c_pt + 3 * j + 3] = rd[point == j]
        return out

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
        margins = self._margins(p, nw)
        ok &= np.max(margins, axis=1) >= 0.0
        if self.visibility_margin_deg > 0 and self.trackers:  # no pair at the cone's edge
            cos = margins + self.cos_accept
            ok &= ~np.any((cos < self.cos_accept) & (cos > self.cos_reject), axis=1)
        ok = ok.reshape(len(q), len(self.tool)).all(axis=1)
        return ok & np.all((q >= self.limits[:, 0]) & (q <= self.limits[:, 1]), axis=1)

    def _weights(self, p: np.ndarray, nw: np.ndarray) -> np.ndarray:
        """(m*P, S, 3, 3) inverse noise covariance of each row as seen from each station, in the station frame
        (zero where the station does not see it)."""
        vis = self._margins(p, nw) >= 0.0
        if self.noise is None:
            return vis[:, :, None, None] * np.eye(3) / self.sigma_mm**2
        y = np.einsum("sab,nb->nsa", self.r_st, p) + self.t_st  # the point in each station's frame
        cov = self.noise.covariance(y.reshape(-1, 3)).reshape(*y.shape, 3)
        return vis[:, :, None, None] * np.linalg.inv(cov)

    def pose_information(self, q: np.ndarray) -> np.ndarray:
        """(m, K, K) information matrix of each pose on its own (its points, every station that sees them)."""
        q = np.atleast_2d(q)
        a, _ = self.row_jacobian(self._rows(q))
        w = self._weights(*self._points_and_normals(q))
        size = self.unknowns.size
        info = np.einsum("nsak,nsab,nsbl->nkl", a, w, a, optimize=True)
        return info.reshape(len(q), len(self.tool), size, size).sum(axis=1)

    def pose_factors(self, q: np.ndarray) -> np.ndarray:
        """(m, 3 P S, K) B with B^T B = `pose_information`: each row block L^T A of a (point, station) pair, W = L L^T
        its weight (zero where the station does not see the point)."""
        q = np.atleast_2d(q)
        a, _ = self.row_jacobian(self._rows(q))
        w = self._weights(*self._points_and_normals(q))
        lower = np.linalg.cholesky(w + (np.abs(w).sum(axis=(-2, -1)) == 0)[..., None, None] * np.eye(3))
        lower = lower * (np.abs(w).sum(axis=(-2, -1)) > 0)[..., None, None]  # unseen: zero rows
        b = np.einsum("nsba,nsbk->nsak", lower, a)
        return b.reshape(len(q), -1, self.unknowns.size)

    def information(self, q: np.ndarray, repeat: int = 1) -> np.ndarray:
        return repeat * self.pose_information(q).sum(axis=0)

    # ------------------------------------------------------------------ criteria
    def criteria(self, q: np.ndarray, repeat: int = 1) -> dict[str, float]:
        """Every criterion of the plan q (m, n) rad measured `repeat` times."""
        m_info = self.information(q, repeat)
        k = self.unknowns.size
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
            "n_parameters": len(self.params),
            "n_unknowns": k,
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
        """log(criterion) of the plan x = (m*n,) rad with the row weights w (m*P, S, 3, 3) held fixed, and its
        gradient: with df = trace(g dM), df/dq_rj = 2 sum_s <W_rs A_rs g, dA_rs/dq_j>. Returns (inf, 0) if singular.
        `jac` is the plan's `_rows` when the caller has it. `d_weight` adds d_weight * log(D), D the geometric
        mean of the covariance eigenvalues, which keeps a plan away from losing a parameter where the
        criterion itself is flat (rho0 stays flat while poses gather at the test pose)."""
        n = self.chain.dof
        jac = self._rows(x.reshape(m, n)) if jac is None else jac
        rows, _ = self.row_jacobian(jac)
        wa = np.einsum("nsab,nsbk->nsak", w, rows)
        ms = np.einsum("nsak,nsal->kl", rows, wa) / np.outer(self.scale, self.scale)
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
        grad_rows = 2.0 * np.einsum("nsak,kl,nsalj->nj", wa, g, self.row_jacobian_dq(jac), optimize=True)
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


def _swap_base(design: Design, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(A^-1, G S^-1, rho0^2 of A) of the scaled `rest` A = rest / (s s^T) for `_rho0_swaps`; None when the rest
    alone is singular (the exact form is used then)."""
    s = design.scale
    a = rest / np.outer(s, s)
    try:
        chol = np.linalg.cholesky(a)
    except np.linalg.LinAlgError:
        return None
    lam = np.diagonal(chol) ** 2
    if lam.min() <= 1e-10 * lam.max():
        return None
    ainv = np.linalg.inv(a)
    gs = design.j0 / s
    return ainv, gs, float(np.sum(gs * (gs @ ainv)))


def _swap_gains(ainv: np.ndarray, gs: np.ndarray, bs: np.ndarray) -> np.ndarray:
    """trace(U^T S^-1 U) of every candidate factor in `bs` (N, r, K): what adding it takes off rho0^2."""
    n, r, k = bs.shape
    t = (bs.reshape(-1, k) @ ainv).reshape(n, r, k)  # one matrix product for every candidate
    u = (t.reshape(-1, k) @ gs.T).reshape(n, r, 3)
    sm = t @ np.swapaxes(bs, 1, 2) + np.eye(r)
    return np.sum(u * np.linalg.solve(sm, u), axis=(1, 2))


def _rho0_swaps(design: Design, rest: np.ndarray, bs: np.ndarray) -> np.ndarray | None:
    """rho0^2 of the plans rest + B_c^T B_c for every candidate factor B_c (N, r, K; `bs` = B / scale, the
    unknowns' scale), by the Woodbury identity on the scaled matrices (A = rest, T = B A^-1, S = I + T B^T,
    U = T G^T): trace(G A^-1 G^T) - trace(U^T S^-1 U). One K x K inverse and an r x r solve per candidate
    (r = 3 P S <= K) where `criterion_values` factors a K x K matrix per candidate. None when the rest alone is
    singular (the exact form is used then)."""
    base = _swap_base(design, rest)
    if base is None:
        return None
    ainv, gs, value = base
    return value - _swap_gains(ainv, gs, bs)


# candidates whose exact gain `_best_rho0_swap` computes at a time, in the order of their bounds
SWAP_CHUNK = 64


def _best_rho0_swap(design: Design, rest: np.ndarray, bs: np.ndarray, allowed: np.ndarray) -> int | None:
    """The index of the `allowed` candidate factor (`bs` as in `_rho0_swaps`) whose addition to `rest` gives the
    lowest rho0, the same as the argmin of `_rho0_swaps`, found by branch and bound: S = I + T B^T >= I, so a
    candidate's gain trace(U^T S^-1 U) is at most |U|^2 = |B A^-1 G^T|^2, a product of r x 3 per candidate. Exact
    gains are computed in the order of these bounds, SWAP_CHUNK at a time, until the best gain found is at least the
    bound of every candidate left (most of the pool never needs its r x r solve). None when the rest is singular."""
    base = _swap_base(design, rest)
    if base is None:
        return None
    ainv, gs, _ = base
    n, r, k = bs.shape
    bound = np.sum(((bs.reshape(-1, k) @ (ainv @ gs.T)).reshape(n, r, 3)) ** 2, axis=(1, 2))
    order = np.flatnonzero(allowed)[np.argsort(-bound[allowed], kind="stable")]
    best, best_gain = None, -np.inf
    for i in range(0, len(order), SWAP_CHUNK):
        chunk = order[i : i + SWAP_CHUNK]
        if bound[chunk[0]] <= best_gain:
            break
        gains = _swap_gains(ainv, gs, bs[chunk])
        j = int(np.argmax(gains))
        if gains[j] > best_gain:
            best, best_gain = int(chunk[j]), float(gains[j])
    return best


def exchange(
    design: Design,
    infos: np.ndarray,
    plan: np.ndarray,
    criterion: str,
    max_passes: int = 100,
    factors: np.ndarray | None = None,
) -> np.ndarray:
    """Modified Fedorov exchange (Cook and Nachtsheim, Technometrics 22, 1980) over a candidate pool: `infos`
    (N, k, k) the pool's pose information matrices, `plan` (m,) distinct pool indices. Each plan pose in turn
    is swapped for the pool pose that lowers the criterion most, if any does; passes repeat until one changes
    nothing. Returns the plan's indices. With the pool's `factors` (`Design.pose_factors`), rho0 picks each
    swap by the Woodbury identity (`_rho0_swaps`, 4x faster at 39 unknowns) and confirms it exactly."""
    plan = np.array(plan)
    total = infos[plan].sum(axis=0)
    best = design.criterion_values(total[None], criterion)[0]
    bs = factors / design.scale if factors is not None and criterion == "rho0" else None
    for _ in range(max_passes):
        improved = False
        for i in range(len(plan)):
            outside = np.setdiff1d(np.arange(len(infos)), plan)
            rest = total - infos[plan[i]]
            fast = None
            if bs is not None:
                allowed = np.ones(len(infos), dtype=bool)
                allowed[plan] = False  # the plan's own poses are no candidates
                fast = _best_rho0_swap(design, rest, bs, allowed)
            if fast is None:
                values = design.criterion_values(rest + infos[outside], criterion)
                c = int(np.argmin(values))
            else:
                c = int(np.searchsorted(outside, fast))
                values = {c: design.criterion_values((rest + infos[outside[c]])[None], criterion)[0]}
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
        lambda x: evaluated(x)[0],
        x0,
        jac=True,
        method="SLSQP",
        bounds=np.tile(design.limits, (m, 1)),
        constraints={"type": "ineq", "fun": lambda x: evaluated(x)[1][0], "jac": lambda x: evaluated(x)[1][1]},
        options={"maxiter": maxiter, "ftol": 1e-10},
    )
    out = np.clip(res.x, np.tile(design.limits[:, 0], m), np.tile(design.limits[:, 1], m)).reshape(m, n)
    # a pose the solver left infeasible (a pair it did not constrain entered a station's cone edge, or its last step
    # crossed a constraint) goes back to its start: each pose's feasibility is its own, so the plan stays feasible
    # and keeps what the others gained (at 24 configurations, dropping the whole result lost most refinements)
    out = np.where(design.feasible(out)[:, None], out, q)
    start, end = design.criterion_values(np.stack([design.information(p) for p in (q, out)]), criterion)
    return out if end < start else q


def _exchanged_refined(args):
    """One start: its Fedorov exchange over the pool, then the continuous refinement of the exchanged plan."""
    design, pool, infos, factors, plan, criterion = args
    q = pool[exchange(design, infos, plan, criterion, factors=factors)]
    return q, refine(design, q, criterion)


def _refined(args):
    design, q, criterion = args
    return refine(design, q, criterion)


# plans screened at once: their poses' information matrices are held together (chunk x configs x K x K float64)
SCREEN_CHUNK = 50


def optimize_plan(
    design: Design,
    m: int,
    repeat: int = 1,
    criterion: str = "rho0",
    starts: int = 1000,
    refined: int = 4,
    seed: int = 0,
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
    initial: list[np.ndarray] | None = None,
    pool_size: int = 2000,
) -> Plan:
    """Screening, exchange, refinement: `pool_size` random feasible poses form the candidate pool, `starts`
    random plans of m distinct pool poses are scored, the best `refined` improved by Fedorov exchange over
    the pool and each then refined continuously (`refine`; one task per start in `executor` when given); the best
    feasible result is evaluated exactly. `initial` plans (m, n) rad are refined too (e.g. a repeated smaller plan).
    Every exchanged plan is refined: the refinement takes rho0 15-20 % below the exchange's (KR-270, 13 and 24
    configurations) while the exchanged starts differ by 1-3 %, so a start is worth its refinement, and 4 starts
    find the plan 16 exchanged starts of which the best 2 were refined found (docs/doe.md)."""
    if criterion not in CRITERIA:
        raise DesignError(f"unknown criterion {criterion!r}; choose from {', '.join(CRITERIA)}")
    rng = np.random.default_rng(seed)
    pool = random_feasible_poses(design, max(pool_size, m + 1), rng)
    infos = design.pose_information(pool)
    screened = np.array([rng.choice(len(pool), m, replace=False) for _ in range(starts)])
    # the screened plans' sums, SCREEN_CHUNK plans at a time (each sum is K x K: 39 unknowns on the KR-270)
    scores = np.concatenate(
        [
            design.criterion_values(infos[screened[i : i + SCREEN_CHUNK]].sum(axis=1), criterion)
            for i in range(0, starts, SCREEN_CHUNK)
        ]
    )
    best = screened[np.argsort(scores)[:refined]]
    total = len(best) + len(initial or [])

    def run(fn, tasks, done):
        out = []
        for i, r in enumerate(executor.map(fn, tasks) if executor is not None else map(fn, tasks)):
            out.append(r)
            if progress:
                progress(done + i + 1, total)
        return out

    factors = design.pose_factors(pool) if criterion == "rho0" else None
    pairs = run(_exchanged_refined, [(design, pool, infos, factors, plan, criterion) for plan in best], 0)
    starts_q = [np.asarray(q, dtype=float) for q in initial or []]
    refined_q = run(_refined, [(design, q, criterion) for q in starts_q], len(best))
    candidates = [q for q in [*(q for pair in pairs for q in pair), *starts_q, *refined_q] if design.feasible(q).all()]
    key = CRITERION_KEY[criterion]
    crit = [design.criteria(q, repeat).get(key, np.inf) for q in candidates]
    q_best = candidates[int(np.argmin(crit))]
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
    known: tuple[str, ...] = (),
    visibility_margin_deg: float = 0.0,
) -> Design:
    """A Design from a `calib.model.cell.Cell`: its tool, TCP, test pose, box and (optionally) stations; the
    unknowns those of a campaign (calib.identify.unknowns) with the robot parameters `params`, `known` the groups
    held at nominal (the paper's planning assumption: ("stations", "points"))."""
    if q0 is None:
        if cell.test_pose is None:
            raise DesignError(f"cell {cell.name} has no test_pose_deg: give the test pose")
        q0 = cell.test_pose
    pids = sorted(cell.tool_points)
    trackers = [Tracker(s.rotation, s.position) for s in cell.stations.values()] if visibility else []
    return Design(
        chain=cell.chain,
        params=params,
        tool=np.array([cell.tool_points[p] for p in pids]),
        q0=np.asarray(q0),
        tcp=cell.tcp,
        sigma_mm=sigma_mm,
        noise=noise,
        trackers=trackers,
        normals=np.array([cell.tool_normals[p] for p in pids]),
        acceptance_deg=cell.acceptance_deg,
        box_min=None if cell.box_min is None else cell.box_min + PLAN_BOX_MARGIN_MM,
        box_max=None if cell.box_max is None else cell.box_max - PLAN_BOX_MARGIN_MM,
        joint_bounds=plan_joint_bounds(cell),
        known=tuple(known),
        visibility_margin_deg=visibility_margin_deg,
    )


def plan_rows(design: Design, q: np.ndarray, repeat: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pose, point, station) index of every measurement a campaign of the plan q (m, n) rad makes: each pose
    `repeat` times, every reference point from every station that sees it (by the design's nominal visibility)."""
    q = np.atleast_2d(q)
    n_pt = len(design.tool)
    vis = np.tile(design.visibility_margins(q) >= 0.0, (repeat, 1))  # (repeat*m*P, S)
    row, station = np.nonzero(vis)
    return (row // n_pt) % len(q), row % n_pt, station


def monte_carlo_rho0(
    design: Design, q: np.ndarray, repeat: int, runs: int, rng: np.random.Generator | list[np.random.Generator]
) -> np.ndarray:
    """Simulate `runs` campaigns of the plan (truth at nominal: robot, stations and points; the design's noise),
    identify each as a campaign does (calib.identify.solver: the robot parameters, every station and every point,
    jointly), and return the error (mm) of the test-pose quantity of each run: the reference points' centroid at
    the test pose in the first station's frame. `rng`: one generator for all runs, or one per run (a run's result
    then does not depend on the runs computed with it). Needs the campaign's unknowns (no `known` group)."""
    rngs = rng if isinstance(rng, list) else [rng] * runs
    if len(rngs) != runs:
        raise DesignError(f"{len(rngs)} generators for {runs} runs")
    if design.known:
        raise DesignError(f"a Monte-Carlo campaign identifies every station and point: known {design.known}")
    q = np.atleast_2d(q)
    pose, point, station = plan_rows(design, q, repeat)
    pids = [f"P{j + 1}" for j in range(len(design.tool))]
    sids = [f"S{s + 1}" for s in range(len(design.r_st))]
    exact = design.kin.points(q[pose], design.tool[point])
    exact = np.einsum("nab,nb->na", design.r_st[station], exact) + design.t_st[station]
    noise = design.noise or TrackerNoise.isotropic(design.sigma_mm)
    n = len(pose)
    q0 = np.repeat(design.q0[None], len(pids), axis=0)
    truth = design.r_st[0] @ design.kin.points(q0, design.tool).mean(axis=0) + design.t_st[0]
    errors = np.empty(runs)
    for k in range(runs):
        table = MeasurementTable(
            np.arange(1, n + 1),
            np.zeros(n),
            [f"Q{i + 1}" for i in pose],
            [sids[s] for s in station],
            [pids[j] for j in point],
            np.degrees(q[pose]),
            exact + noise.sample(exact, rngs[k]),
            source="monte carlo",
        )
        res = identify(design.chain, table, dict(zip(pids, design.tool, strict=True)), design.params, design.noise)
        tool = np.array([res.points[p] for p in pids])
        est = res.stations[sids[0]].apply(design.kin.points(q0, tool, res.dev).mean(axis=0))
        errors[k] = np.linalg.norm(est - truth)
    return errors
