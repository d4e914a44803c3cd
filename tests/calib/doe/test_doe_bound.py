"""The approximate-design lower bound on rho0: the two-link arm's closed form, below every plan, its derivative."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackcal.calib.doe.bound import derivative, multiplicative_weights, rho0_lower_bound
from trackcal.calib.doe.design import design_for_cell, optimize_plan, random_feasible_poses
from trackcal.calib.identify.unknowns import PAPER_KNOWN
from trackcal.calib.model.cell import load_cell
from trackcal.calib.model.params import param_by_name


def design(name: str, q0_deg=None, sigma_mm: float = 0.01):
    cell = load_cell(name)
    params = [param_by_name(cell.chain, n) for n in cell.plan_params]
    # the paper's planning assumption (section 7.2: base and tool known), as in its tables
    return design_for_cell(
        cell, params, None if q0_deg is None else np.radians(q0_deg), sigma_mm=sigma_mm, known=PAPER_KNOWN
    )


@pytest.fixture(scope="module")
def kr():
    return design("kr270")


@pytest.fixture(scope="module")
def kr_bound(kr):
    return rho0_lower_bound(kr, 18, np.random.default_rng(1), pool_size=1000, rounds=2, local_starts=8, iterations=500)


@pytest.mark.parametrize("q20_deg", [20.0, 60.0, 150.0])
@pytest.mark.parametrize("n", [2, 5])
def test_the_two_link_arm_bound_is_eq41(q20_deg, n):
    """Two-link arm, dl1 and dl2 (paper section 6.2): I(q) = [[1, cos q2], [cos q2, 1]] / sigma^2, so every
    measure of mass n has the information of n measurements at the mean cos q2, and the approximate optimum is
    the exact one, eq. (41): cos^2 q20 / (1 - |sin q20|) / n (sigma = 1 mm). The bound lies below it, the
    approximate design found above it, and the two meet."""
    d = design("planar2r", [-45.0, q20_deg], sigma_mm=1.0)
    b = rho0_lower_bound(d, n, np.random.default_rng(2), pool_size=400, rounds=2, local_starts=8)
    q20 = np.radians(q20_deg)
    eq41 = np.cos(q20) ** 2 / (1 - abs(np.sin(q20))) / n
    assert b.rho0_mm**2 <= eq41 * (1 + 1e-9) and b.design_rho0_mm**2 >= eq41 * (1 - 1e-9)
    assert b.rho0_mm / b.design_rho0_mm > 0.99
    assert np.sum(b.weights) <= 1 + 1e-12 and b.support.shape == (len(b.weights), 2)


@settings(max_examples=25, deadline=None)
@given(m=st.integers(6, 12), repeat=st.integers(1, 3), seed=st.integers(0, 2**31))
def test_no_random_plan_beats_the_bound(kr, kr_bound, m, repeat, seed):
    """Every plan of N = m * repeat measurements is a measure of mass N, so rho0 >= bound(18) sqrt(18 / N); the
    bound relaxes the stations' visibility, under which the plan's information can only grow."""
    q = random_feasible_poses(kr, m, np.random.default_rng(seed))
    assert kr.rho0(q, repeat) >= kr_bound.rho0_mm * np.sqrt(18 / (m * repeat))


def test_no_optimised_plan_beats_the_bound(kr, kr_bound):
    plan = optimize_plan(kr, 6, 3, starts=200, refined=2, seed=3)
    assert kr_bound.rho0_mm <= plan.criteria["rho0_mm"] <= 2 * kr_bound.rho0_mm
    assert kr_bound.rho0_mm <= kr_bound.design_rho0_mm


def test_derivative_is_the_direct_trace_and_its_gradient_matches_finite_differences(kr):
    """d(x) = trace(I(x) A) for a symmetric A, against `pose_information`, and its gradient against central
    differences (row weights held fixed, as in the local search)."""
    rng = np.random.default_rng(4)
    x = random_feasible_poses(kr, 1, rng)[0]
    b = rng.normal(size=(9, 9))
    a = b @ b.T
    p, nw = kr._points_and_normals(x[None])
    w_rows = kr._weights(p, nw)
    value, grad = derivative(kr, x, a, w_rows)
    assert value == pytest.approx(np.trace(kr.pose_information(x)[0] @ a), rel=1e-10)
    h = 1e-6
    fd = np.array(
        [
            (derivative(kr, x + h * e, a, w_rows)[0] - derivative(kr, x - h * e, a, w_rows)[0]) / (2 * h)
            for e in np.eye(len(x))
        ]
    )
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd)))


def test_multiplicative_weights_lower_the_criterion_from_uniform(kr):
    """A fixed point of w_i <- w_i sqrt(d_i / phi) has d_i = phi on its support; from uniform weights the
    iterations lower phi = trace(L M^-1) and keep the weights a probability vector."""
    pool = random_feasible_poses(kr, 300, np.random.default_rng(5))
    infos = kr.pose_information(pool)
    lmat = kr.j0.T @ kr.j0

    def phi(w):
        return np.trace(lmat @ np.linalg.inv(np.einsum("i,ikl->kl", w, infos)))

    w0 = np.full(len(pool), 1 / len(pool))
    w = multiplicative_weights(kr, infos, w0, 200)
    assert np.all(w > 0) and np.sum(w) == pytest.approx(1.0, rel=1e-12)
    assert phi(w) < phi(w0)
