"""A lower bound on rho0 for every plan of N measurements, from the approximate (continuous) design.

A plan of N pose measurements is a measure of mass N on the feasible poses; relaxed to any such measure xi,
phi(xi) = trace(L M(xi)^-1), L = J0^T J0, M(xi) = N sum_i w_i I(x_i), is convex in the weights, so its minimum
phi* bounds rho0^2 of every plan of N measurements from below (an exact plan, repeated or not, is one such
measure). For any xi, convexity gives (the general equivalence theorem of Kiefer and Wolfowitz 1960; for a
linear criterion see Atkinson, Donev and Tobias, Optimum Experimental Designs, 2007, sections 9.2 and 10.5):

    phi* >= 2 phi(xi) - N max_x d(x),     d(x) = trace(I(x) M(xi)^-1 L M(xi)^-1),

with the maximum over every feasible pose x. The weights come from the multiplicative algorithm (Silvey,
Titterington and Torsney 1978, exponent 1/2 as for A-optimality); the support moves continuously, each round
adding the local maxima of d(x) (joint limits and box as constraints, as in `calib.doe.design.refine`). The bound is
as sure as that maximum: it is taken over the pool and every local maximum found.

Visibility is relaxed: every station sees every point (acceptance 180 deg). A pose's information can only
grow and the feasible set only widen, so the relaxed bound holds for the real cell, and d(x) stays smooth: with
visibility it jumps where a point leaves a station's cone, and a local search misses maxima behind the jumps.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize

from trackcal.calib.doe.design import Design, random_feasible_poses


@dataclass
class Bound:
    rho0_mm: float  # lower bound on rho0 of every plan of n_measurements
    design_rho0_mm: float  # rho0 of the approximate design found (an upper bound on the approximate optimum)
    n_measurements: int
    support: np.ndarray  # (s, n) rad, poses of the approximate design, heaviest first
    weights: np.ndarray  # (s,) their weights, summing to 1 over the whole design


def multiplicative_weights(design: Design, infos: np.ndarray, w: np.ndarray, iterations: int) -> np.ndarray:
    """Weights (summing to 1) on the poses with information `infos` (N, k, k) that lower trace(L M^-1):
    w_i <- w_i sqrt(d_i / phi), which leaves sum_i w_i d_i = phi and keeps every weight positive."""
    lmat = design.j0.T @ design.j0
    w = w / w.sum()
    for _ in range(iterations):
        mi = np.linalg.inv(np.einsum("i,ikl->kl", w, infos))
        dv = np.einsum("ikl,lk->i", infos, mi @ lmat @ mi)
        w = w * np.sqrt(np.maximum(dv, 0.0) / np.trace(lmat @ mi))
        w /= w.sum()
    return w


def _direction(design: Design, infos: np.ndarray, w: np.ndarray) -> tuple[float, np.ndarray]:
    """phi = trace(L M^-1) of the unit-mass design and A = M^-1 L M^-1, so that d(x) = trace(I(x) A)."""
    lmat = design.j0.T @ design.j0
    mi = np.linalg.inv(np.einsum("i,ikl->kl", w, infos))
    return float(np.trace(lmat @ mi)), mi @ lmat @ mi


def derivative(design: Design, x: np.ndarray, a: np.ndarray, w_rows: np.ndarray) -> tuple[float, np.ndarray]:
    """d(x) = trace(I(x) A) of one pose x (n,) with the row weights w_rows (P, S, 3, 3) held fixed, and its
    gradient: d d / d x_j = 2 sum_rows <W_r J_r A, dJ_r/dx_j> (J_r the row's Jacobian over every unknown)."""
    jac = design._rows(x[None])
    rows, _ = design.row_jacobian(jac)
    wj = np.einsum("nsab,nsbk->nsak", w_rows, rows)
    value = float(np.einsum("nsak,kl,nsal->", wj, a, rows))
    return value, 2.0 * np.einsum("nsak,kl,nsalj->j", wj, a, design.row_jacobian_dq(jac), optimize=True)


def _local_max(design: Design, x0: np.ndarray, a: np.ndarray) -> tuple[float, np.ndarray] | None:
    w_rows = design._weights(*design._points_and_normals(x0[None]))
    seen = np.zeros((len(design.tool), len(design.trackers)), dtype=bool)  # visibility relaxed: no constraint

    def cons(x):
        return design.constraints(x, 1, seen)

    res = minimize(
        lambda x: tuple(-v for v in derivative(design, x, a, w_rows)),
        x0,
        jac=True,
        method="SLSQP",
        bounds=design.limits,
        options={"maxiter": 300, "ftol": 1e-14},
        constraints={"type": "ineq", "fun": lambda x: cons(x)[0], "jac": lambda x: cons(x)[1]},
    )
    x = np.clip(res.x, design.limits[:, 0], design.limits[:, 1])
    if not design.feasible(x)[0]:
        return None
    return float(np.einsum("kl,lk->", design.pose_information(x)[0], a)), x


def rho0_lower_bound(
    design: Design,
    n_measurements: int,
    rng: np.random.Generator,
    pool_size: int = 5000,
    rounds: int = 8,
    local_starts: int = 40,
    iterations: int = 1500,
) -> Bound:
    """The bound on rho0 of every plan of `n_measurements` pose measurements (module docstring), visibility
    relaxed: weights on a pool of random feasible poses, then `rounds` of support moves from the `local_starts`
    poses of largest d(x), re-weighting after each."""
    design = replace(design, acceptance_deg=180.0)
    pool = random_feasible_poses(design, pool_size, rng)
    infos = design.pose_information(pool)
    w = multiplicative_weights(design, infos, np.ones(len(pool)), iterations)
    bound = 0.0
    for r in range(rounds + 1):
        phi, a = _direction(design, infos, w)
        dv = np.einsum("ikl,lk->i", infos, a)
        starts = np.union1d(np.argsort(-dv)[:local_starts], np.argsort(-w)[: local_starts // 4])
        found = [r for r in (_local_max(design, pool[i], a) for i in starts) if r is not None]
        d_max = max([dv.max(), *(v for v, _ in found)])
        bound = max(bound, 2 * phi - d_max)
        if r == rounds:
            break
        new = np.array([x for _, x in found])
        pool, infos = np.r_[pool, new], np.r_[infos, design.pose_information(new)]
        w = multiplicative_weights(design, infos, np.r_[0.9 * w, np.full(len(new), 0.1 / len(new))], iterations)
    order = np.argsort(-w)
    keep = order[w[order] > 1e-4]
    return Bound(
        rho0_mm=float(np.sqrt(bound / n_measurements)),
        design_rho0_mm=float(np.sqrt(phi / n_measurements)),
        n_measurements=n_measurements,
        support=pool[keep],
        weights=w[keep],
    )
